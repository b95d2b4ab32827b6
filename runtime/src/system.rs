//! Well-known system channels: how the supervisor (watchdog), the resource manager, the
//! modules and the `hng` command talk to each other.
//!
//! | channel | type | from | to |
//! |---|---|---|---|
//! | [`crate::module::REPORT_CHANNEL`] `hng/report` | [`crate::msg::ModuleReport`] | every module | supervisor (heartbeat), RM |
//! | [`SUPERVISOR_COMMAND`] | [`SupervisorCommand`] | `hng kill/restart`, RM (over limit) | supervisor |
//! | [`SUPERVISOR_EVENTS`] | [`ModuleEvent`] | supervisor | modules (contracts route around the dead at once), tools |
//! | [`SUPERVISOR_STATUS`] | JSON document ([`JsonInfo`]) | supervisor | `hng ps`, `hng top` |
//! | [`RM_COSTS`] | [`ResourceCosts`] | RM | modules (value V), supervisor |
//! | [`RM_STATUS`] | JSON document ([`JsonInfo`]) | RM | `hng ps`, `hng top` |
//! | [`RM_EFFECTIVE_COSTS`] | [`EffectiveCosts`] | RM | modules (R_eff of eq. 4 for their value V) |
//! | [`CONTRACTS`] | [`ContractTable`] | every module | RM (eq. 4 needs the tree), `hng contracts` |
//!
//! Status views are JSON documents on state channels (the latest is kept for late joiners),
//! so every view has a terminal and a `--json` form without a second encoding.

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;

use crate::msg::{Header, MODULE_NAME_LEN, get_str, put_str};
use crate::qos::ChannelKind;

pub mod status;

/// Commands to the supervisor.
pub const SUPERVISOR_COMMAND: &str = "hng/supervisor/command";
/// Module life-cycle events from the supervisor.
pub const SUPERVISOR_EVENTS: &str = "hng/supervisor/events";
/// The supervisor's status document (`hng ps`).
pub const SUPERVISOR_STATUS: &str = "hng/supervisor/status";
/// Resource costs and degraded mode from the resource manager.
pub const RM_COSTS: &str = "hng/rm/costs";
/// The resource manager's per-module figures (JSON).
pub const RM_STATUS: &str = "hng/rm/status";

/// Effective resource cost R_eff of every module, from the resource manager.
pub const RM_EFFECTIVE_COSTS: &str = "hng/rm/effective_costs";
/// Every module's contract table, published periodically.
pub const CONTRACTS: &str = "hng/contracts";

/// Largest number of modules in one [`EffectiveCosts`] message.
pub const MAX_MODULES: usize = 64;
/// Largest number of contracts in one [`ContractTable`].
pub const MAX_CONTRACTS: usize = 16;
/// Length of a service name in system messages.
pub const SERVICE_LEN: usize = 32;
/// Length of a data channel name in a [`ContractEntry`].
pub const CHANNEL_LEN: usize = 64;

/// Largest depth of a priority carried in system messages.
pub const MAX_PRIORITY_DEPTH: usize = 24;
/// Length of a reason text.
pub const REASON_LEN: usize = 64;

/// What a [`SupervisorCommand`] asks.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, strum::FromRepr)]
pub enum CommandOp {
    /// Send `signal` to the module (fault injection).
    Kill = 1,
    /// Restart the module (maintenance; not counted as a failure).
    Restart = 2,
    /// Stop the module for good.
    Stop = 3,
    /// Start a stopped or deactivated module.
    Start = 4,
    /// Kill and restart the module with exit cause "over limit" (`reason` says which).
    OverLimit = 5,
    /// Stop the whole system.
    Shutdown = 6,
}

/// A command to the supervisor.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hng/SupervisorCommand/v1")]
pub struct SupervisorCommand {
    /// Header.
    pub header: Header,
    /// [`CommandOp`] as a byte.
    pub op: u8,
    /// Target module (NUL-padded).
    pub module: [u8; MODULE_NAME_LEN],
    /// Signal number for [`CommandOp::Kill`].
    pub signal: i32,
    /// Free text (for [`CommandOp::OverLimit`]: which limit).
    pub reason: [u8; REASON_LEN],
}

impl Default for SupervisorCommand {
    fn default() -> Self {
        SupervisorCommand {
            header: Header::default(),
            op: 0,
            module: [0; MODULE_NAME_LEN],
            signal: 0,
            reason: [0; REASON_LEN],
        }
    }
}

impl SupervisorCommand {
    /// A command `op` for `module`.
    pub fn new(op: CommandOp, module: &str) -> SupervisorCommand {
        let mut c = SupervisorCommand {
            op: op as u8,
            ..Default::default()
        };
        put_str(&mut c.module, module);
        c
    }

    /// Sets the reason text (cut to [`REASON_LEN`] bytes).
    #[must_use]
    pub fn with_reason(mut self, reason: &str) -> SupervisorCommand {
        put_str(&mut self.reason, reason);
        self
    }

    /// The operation, if valid.
    pub fn op(&self) -> Option<CommandOp> {
        CommandOp::from_repr(self.op)
    }

    /// The target module.
    pub fn module(&self) -> &str {
        get_str(&self.module)
    }

    /// The reason text.
    pub fn reason(&self) -> &str {
        get_str(&self.reason)
    }
}

impl Serialize for SupervisorCommand {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("SupervisorCommand", 5)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("op", &self.op())?;
        st.serialize_field("module", self.module())?;
        st.serialize_field("signal", &self.signal)?;
        st.serialize_field("reason", self.reason())?;
        st.end()
    }
}

crate::impl_message!(SupervisorCommand, ChannelKind::Control);

/// What happened to a module.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, strum::FromRepr)]
pub enum EventKind {
    /// A process was started (`pid`).
    Started = 1,
    /// The process died (`pid`); it may be restarted.
    Died = 2,
    /// The module failed too often and is deactivated.
    Deactivated = 3,
    /// The module was stopped on purpose.
    Stopped = 4,
}

/// A module life-cycle event from the supervisor.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("hng/ModuleEvent/v1")]
pub struct ModuleEvent {
    /// Header.
    pub header: Header,
    /// [`EventKind`] as a byte.
    pub kind: u8,
    /// The module's id ([`crate::msg::module_id`] of its name).
    pub module_id: u32,
    /// The process concerned.
    pub pid: u32,
    /// The module's name (NUL-padded).
    pub module: [u8; MODULE_NAME_LEN],
}

impl ModuleEvent {
    /// An event for `module`.
    pub fn new(kind: EventKind, module: &str, pid: u32) -> ModuleEvent {
        let mut e = ModuleEvent {
            kind: kind as u8,
            module_id: crate::msg::module_id(module),
            pid,
            ..Default::default()
        };
        put_str(&mut e.module, module);
        e
    }

    /// The kind, if valid.
    pub fn kind(&self) -> Option<EventKind> {
        EventKind::from_repr(self.kind)
    }

    /// The module's name.
    pub fn module(&self) -> &str {
        get_str(&self.module)
    }
}

impl Serialize for ModuleEvent {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("ModuleEvent", 5)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("kind", &self.kind())?;
        st.serialize_field("module", self.module())?;
        st.serialize_field("module_id", &self.module_id)?;
        st.serialize_field("pid", &self.pid)?;
        st.end()
    }
}

crate::impl_message!(ModuleEvent, ChannelKind::Control);

/// The cost vector C_R(t) and the degraded-mode bar, published by the resource manager.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/ResourceCosts/v1")]
pub struct ResourceCosts {
    /// Header.
    pub header: Header,
    /// Cost of CPU.
    pub cpu: f64,
    /// Cost of memory.
    pub mem: f64,
    /// Cost of communication.
    pub comm: f64,
    /// 1 while degraded mode is active.
    pub degraded: u8,
    /// 1 if nothing may be served at all (the most severe degraded mode).
    pub serve_nothing: u8,
    /// Depth of `min_priority` (0: every query is served).
    pub min_priority_len: u8,
    /// The least important priority still served, as integers (see `contract::Priority`).
    pub min_priority: [u16; MAX_PRIORITY_DEPTH],
}

impl ResourceCosts {
    /// The minimum priority's components, if degraded mode sets one.
    pub fn min_priority(&self) -> Option<&[u16]> {
        let p = priority_parts(self.min_priority_len, &self.min_priority);
        (!p.is_empty()).then_some(p)
    }
}

/// The first `len` components of a priority as the wire tables hold it.
fn priority_parts(len: u8, parts: &[u16; MAX_PRIORITY_DEPTH]) -> &[u16] {
    &parts[..usize::from(len).min(MAX_PRIORITY_DEPTH)]
}

/// Stores `parts` (cut to [`MAX_PRIORITY_DEPTH`] components, the rest zeroed) in a wire
/// table's priority; returns its length.
fn store_priority(dst: &mut [u16; MAX_PRIORITY_DEPTH], parts: &[u16]) -> u8 {
    let n = parts.len().min(MAX_PRIORITY_DEPTH);
    *dst = [0; MAX_PRIORITY_DEPTH];
    dst[..n].copy_from_slice(&parts[..n]);
    n as u8
}

crate::impl_message!(ResourceCosts, ChannelKind::State);

/// R_eff (eq. 4) of one module: (cpu, memory, communication).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
pub struct ModuleCost {
    /// The module's id.
    pub module_id: u32,
    /// Its own measured consumption R.
    pub own: [f64; 3],
    /// Its effective cost R_eff.
    pub effective: [f64; 3],
}

/// R_eff of every module, published by the resource manager; a module picks its own entry.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hng/EffectiveCosts/v1")]
pub struct EffectiveCosts {
    /// Header.
    pub header: Header,
    /// Valid entries.
    pub count: u32,
    /// The entries; only the first `count` are meaningful.
    pub modules: [ModuleCost; MAX_MODULES],
}

impl Default for EffectiveCosts {
    fn default() -> Self {
        EffectiveCosts {
            header: Header::default(),
            count: 0,
            modules: [ModuleCost::default(); MAX_MODULES],
        }
    }
}

impl EffectiveCosts {
    /// The valid entries.
    pub fn modules(&self) -> &[ModuleCost] {
        &self.modules[..(self.count as usize).min(MAX_MODULES)]
    }

    /// The entry of `module_id`.
    pub fn of(&self, module_id: u32) -> Option<&ModuleCost> {
        self.modules().iter().find(|m| m.module_id == module_id)
    }
}

impl Serialize for EffectiveCosts {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("EffectiveCosts", 2)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("modules", self.modules())?;
        st.end()
    }
}

crate::impl_message!(EffectiveCosts, ChannelKind::State);

/// The role a module plays in one contract of its [`ContractTable`].
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum ContractRole {
    /// This module is the client; `peer` provides.
    Client = 1,
    /// This module provides; `peer` is the client.
    Provider = 2,
}

/// One contract as a module sees it.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
pub struct ContractEntry {
    /// [`ContractRole`] as a byte.
    pub role: u8,
    /// The other module's id.
    pub peer: u32,
    /// The service (NUL-padded).
    pub service: [u8; SERVICE_LEN],
    /// The provider's value V when last heard.
    pub value: f32,
    /// The contract's priority depth.
    pub priority_len: u8,
    /// The contract's priority.
    pub priority: [u16; MAX_PRIORITY_DEPTH],
    /// The client's need rank.
    pub need: u16,
    /// The data channel the provider named (NUL-padded).
    pub channel: [u8; CHANNEL_LEN],
}

impl Default for ContractEntry {
    fn default() -> Self {
        ContractEntry {
            role: 0,
            peer: 0,
            service: [0; SERVICE_LEN],
            value: 0.0,
            priority_len: 0,
            priority: [0; MAX_PRIORITY_DEPTH],
            need: 0,
            channel: [0; CHANNEL_LEN],
        }
    }
}

impl ContractEntry {
    /// The role, if valid.
    pub fn role(&self) -> Option<ContractRole> {
        match self.role {
            1 => Some(ContractRole::Client),
            2 => Some(ContractRole::Provider),
            _ => None,
        }
    }

    /// The service.
    pub fn service(&self) -> &str {
        get_str(&self.service)
    }

    /// Sets the service (cut to [`SERVICE_LEN`] bytes).
    pub fn set_service(&mut self, s: &str) {
        put_str(&mut self.service, s);
    }

    /// The priority's components.
    pub fn priority(&self) -> &[u16] {
        priority_parts(self.priority_len, &self.priority)
    }

    /// Sets the priority (cut to [`MAX_PRIORITY_DEPTH`] components).
    pub fn set_priority(&mut self, parts: &[u16]) {
        self.priority_len = store_priority(&mut self.priority, parts);
    }

    /// The data channel.
    pub fn channel(&self) -> &str {
        get_str(&self.channel)
    }

    /// Sets the data channel (cut to [`CHANNEL_LEN`] bytes).
    pub fn set_channel(&mut self, s: &str) {
        put_str(&mut self.channel, s);
    }
}

impl Serialize for ContractEntry {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("ContractEntry", 7)?;
        st.serialize_field("role", &self.role())?;
        st.serialize_field("peer", &self.peer)?;
        st.serialize_field("service", self.service())?;
        st.serialize_field("need", &self.need)?;
        st.serialize_field("channel", self.channel())?;
        st.serialize_field("value", &self.value)?;
        st.serialize_field("priority", self.priority())?;
        st.end()
    }
}

/// A module's contracts, published periodically on [`CONTRACTS`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hng/ContractTable/v2")]
pub struct ContractTable {
    /// Header.
    pub header: Header,
    /// The module's id.
    pub module_id: u32,
    /// The module's name (NUL-padded).
    pub module: [u8; MODULE_NAME_LEN],
    /// 1 if the module is active (holds a contract or is the Manager).
    pub active: u8,
    /// The module's priority depth (0: none).
    pub priority_len: u8,
    /// The module's priority P(m).
    pub priority: [u16; MAX_PRIORITY_DEPTH],
    /// Valid entries.
    pub count: u32,
    /// The contracts; only the first `count` are meaningful.
    pub entries: [ContractEntry; MAX_CONTRACTS],
    /// The module's own value V (eq. 3); NaN when it cannot propose (f = 0).
    pub value: f32,
    /// Control messages dropped by the transport: malformed, truncated, wrong version,
    /// oversized, bad magic, out-of-range fields, spoofed sender.
    pub control_drops: u64,
    /// Control messages the protocol ignored (stale replies, unknown contracts, ...).
    pub protocol_drops: u64,
    /// Driver: commands obeyed.
    pub commands_accepted: u64,
    /// Driver: commands ignored because a more important client has control.
    pub commands_preempted: u64,
    /// Driver: commands ignored because their publisher holds no contract.
    pub commands_no_contract: u64,
}

impl Default for ContractTable {
    fn default() -> Self {
        ContractTable {
            header: Header::default(),
            module_id: 0,
            module: [0; MODULE_NAME_LEN],
            active: 0,
            priority_len: 0,
            priority: [0; MAX_PRIORITY_DEPTH],
            count: 0,
            entries: [ContractEntry::default(); MAX_CONTRACTS],
            value: f32::NAN,
            control_drops: 0,
            protocol_drops: 0,
            commands_accepted: 0,
            commands_preempted: 0,
            commands_no_contract: 0,
        }
    }
}

impl ContractTable {
    /// The module's name.
    pub fn module(&self) -> &str {
        get_str(&self.module)
    }

    /// Sets the module's name.
    pub fn set_module(&mut self, name: &str) {
        put_str(&mut self.module, name);
    }

    /// The valid entries.
    pub fn entries(&self) -> &[ContractEntry] {
        &self.entries[..(self.count as usize).min(MAX_CONTRACTS)]
    }

    /// The module's priority components.
    pub fn priority(&self) -> &[u16] {
        priority_parts(self.priority_len, &self.priority)
    }

    /// Sets the module's priority (cut to [`MAX_PRIORITY_DEPTH`] components).
    pub fn set_priority(&mut self, parts: &[u16]) {
        self.priority_len = store_priority(&mut self.priority, parts);
    }

    /// The module's contract as the client of `service`, if it holds one.
    pub fn client_entry(&self, service: &str) -> Option<&ContractEntry> {
        self.entries()
            .iter()
            .find(|e| e.role() == Some(ContractRole::Client) && e.service() == service)
    }

    /// Appends an entry; false when the table is full.
    pub fn push(&mut self, entry: ContractEntry) -> bool {
        let n = self.count as usize;
        if n >= MAX_CONTRACTS {
            return false;
        }
        self.entries[n] = entry;
        self.count += 1;
        true
    }
}

impl Serialize for ContractTable {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("ContractTable", 12)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("module", self.module())?;
        st.serialize_field("module_id", &self.module_id)?;
        st.serialize_field("active", &(self.active != 0))?;
        st.serialize_field("priority", self.priority())?;
        st.serialize_field("value", &self.value.is_finite().then_some(self.value))?;
        st.serialize_field("contracts", self.entries())?;
        st.serialize_field("control_drops", &self.control_drops)?;
        st.serialize_field("protocol_drops", &self.protocol_drops)?;
        st.serialize_field("commands_accepted", &self.commands_accepted)?;
        st.serialize_field("commands_preempted", &self.commands_preempted)?;
        st.serialize_field("commands_no_contract", &self.commands_no_contract)?;
        st.end()
    }
}

crate::impl_message!(ContractTable, ChannelKind::Report);

/// Header of a JSON document on a state channel (the payload is UTF-8 JSON).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/JsonInfo/v1")]
pub struct JsonInfo {
    /// Header.
    pub header: Header,
}

crate::impl_slice_message!(JsonInfo, u8, ChannelKind::State);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_carry_names_and_reasons() {
        let c = SupervisorCommand::new(CommandOp::OverLimit, "slam")
            .with_reason("memory 600 MiB > 512 MiB");
        assert_eq!(c.op(), Some(CommandOp::OverLimit));
        assert_eq!(c.module(), "slam");
        assert_eq!(c.reason(), "memory 600 MiB > 512 MiB");
        let long = "é".repeat(40);
        let c = SupervisorCommand::new(CommandOp::Kill, &long);
        assert!(
            c.module().chars().all(|ch| ch == 'é'),
            "cut on a character boundary"
        );
    }

    #[test]
    fn costs_expose_the_min_priority_only_when_set() {
        let mut c = ResourceCosts::default();
        assert_eq!(c.min_priority(), None);
        c.min_priority_len = 2;
        c.min_priority[..2].copy_from_slice(&[2, 1]);
        assert_eq!(c.min_priority(), Some(&[2u16, 1][..]));
    }
}
