//! The contract control plane: the transport-free [`crate::contract`] logic carried over
//! iceoryx2 between module processes, and the SDK pieces built on it.
//!
//! A module that declares services or needs in [`crate::Module::configure`]
//! ([`crate::Context::provide`], [`crate::Context::need`], [`crate::Context::manager`]) gets a
//! [`ContractAgent`] that the executor runs for it:
//!
//! | channel | payload | subscribers | publishers |
//! |---|---|---|---|
//! | [`inbox_channel`] `hng/ctl/m<id>` | encoded [`Envelope`]s addressed to module `id` | that module | its peers |
//! | [`service_channel`] `hng/ctl/svc/<service>` | queries to every provider of a service | the providers | the clients |
//! | [`crate::system::SUPERVISOR_EVENTS`] | [`ModuleEvent`] | every contract module | the supervisor |
//! | [`crate::system::RM_COSTS`], [`crate::system::RM_EFFECTIVE_COSTS`] | `C_R`, degraded mode, `R_eff` | every contract module | the RM |
//! | [`crate::system::CONTRACTS`] | the module's [`ContractTable`] | RM, `hng contracts` | every contract module |
//!
//! Messages are [`contract::encode`]d bytes (at most [`MAX_MESSAGE_LEN`]) in a slice channel
//! with the [`ControlInfo`] header. What cannot be decoded (truncated, oversized, malformed,
//! wrong magic or version, out-of-range fields) or whose envelope names another sender than
//! the module that published it is dropped and counted, never acted upon; the counts appear in
//! the module's [`ContractTable`] (`control_drops`).

use std::collections::HashMap;
use std::fmt::Write as _;
use std::time::Duration;

use iceoryx2::prelude::{PortFactory as _, ServiceName, ZeroCopySend};
use serde::Serialize;

use crate::channel::{
    InputId, Node, Publisher, Sample, SlicePublisher, SliceSubscriber, Subscriber,
};
use crate::contract::{
    self, AgentConfig, AgentEvent, CommandArbiter, ContractAgent, Destination, DropCounters,
    DropReason, MAX_MESSAGE_LEN, ModuleId, NeedSpec, Outgoing, Priority, ResourceVec, ServiceOffer,
    Timing, Verdict,
};
use crate::error::Error;
use crate::msg::{Header, SliceMessage};
use crate::qos::ChannelKind;
use crate::system::{
    CONTRACTS, ContractEntry, ContractRole, ContractTable, EffectiveCosts, EventKind, ModuleEvent,
    RM_COSTS, RM_EFFECTIVE_COSTS, ResourceCosts, SUPERVISOR_EVENTS,
};
use crate::wait::Waiter;

mod follow;
mod repeats;
mod transport;

use transport::open_service_out;

pub use follow::{
    FollowProvider, PROVIDER_INPUT_CACHE, ProviderInput, ProviderOutput, ProviderReceiver,
    SliceProviderInput,
};

/// Root of the control channels.
pub const CONTROL_ROOT: &str = "hng/ctl";

/// The inbox of module `id`: every message addressed to it ([`Destination::Module`]).
pub fn inbox_channel(id: ModuleId) -> String {
    format!("{CONTROL_ROOT}/m{}", id.0)
}

/// The query channel of `service` ([`Destination::Providers`]). Bytes other than ASCII
/// letters, digits, `-`, `_` and `.` are written `%XX`, so every service name maps to a
/// distinct, valid channel name (`Robot control` → `hng/ctl/svc/Robot%20control`).
pub fn service_channel(service: &str) -> String {
    let mut s = format!("{CONTROL_ROOT}/svc/");
    for b in service.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.".contains(&b) {
            s.push(char::from(b));
        } else {
            let _ = write!(s, "%{b:02X}");
        }
    }
    s
}

/// The user header of control messages; the payload is one encoded [`contract::Envelope`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/ControlInfo/v1")]
pub struct ControlInfo {
    /// Header; `source` identifies the publishing module (checked against the envelope).
    pub header: Header,
}

impl SliceMessage for ControlInfo {
    type Elem = u8;
    const KIND: ChannelKind = ChannelKind::Contract;
    fn header(&self) -> &Header {
        &self.header
    }
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

/// The provider serving one of the module's needs, and where its data comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProviderInfo {
    /// The provider (its messages carry `header.source == module.0`).
    pub module: ModuleId,
    /// The data channel the provider named in its proposal.
    pub channel: String,
}

/// What a module declared in `configure` (collected by the [`crate::Context`]).
#[derive(Debug, Clone, Default)]
pub(crate) struct ContractSpec {
    pub(crate) manager: Option<Vec<String>>,
    pub(crate) provides: Vec<ServiceOffer>,
    pub(crate) needs: Vec<NeedSpec>,
    pub(crate) timing: Option<Timing>,
    pub(crate) hysteresis: Option<f64>,
    pub(crate) tau: Option<Duration>,
    pub(crate) drives: Vec<(String, Duration)>,
    /// Optional needs switched off before the agent existed (`Context::set_need_enabled`).
    pub(crate) disabled: Vec<u16>,
}

impl ContractSpec {
    pub(crate) fn declared(&self) -> bool {
        self.manager.is_some() || !self.provides.is_empty() || !self.needs.is_empty()
    }
}

/// What the executor tells the module after a contract change.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum PlaneEvent {
    Activation(bool),
    Provider(u16, Option<ProviderInfo>),
    ContractsChanged,
}

/// While a need waits for a provider to appear, how often the plane looks at the number of
/// providers listening on the service's query channel (a provider that starts is then called
/// at once rather than at the next retry): the reply window, within 10..=100 ms.
fn provider_poll_period(t: &Timing) -> Duration {
    t.reply_window
        .clamp(Duration::from_millis(10), Duration::from_millis(100))
}

/// Period of the [`ContractTable`] publication. The table is also published on every change;
/// the periodic one goes out with the module's first wake-up after the period (its heartbeat
/// report at the latest): it never wakes the module by itself.
pub const TABLE_PERIOD: Duration = Duration::from_millis(200);

/// Freshness of a driver's commands when [`crate::Context::drive`] was not called.
pub const DEFAULT_COMMAND_FRESHNESS: Duration = Duration::from_millis(300);

/// The providers of `service` that listen now: the subscribers of its query channel, this
/// module excluded (for the early close of calls and the retry when one appears).
fn provider_count(agent: &ContractAgent, service: &str, s: &ServiceOut) -> usize {
    let n = s.factory.dynamic_config().number_of_subscribers();
    if agent.config().provides.iter().any(|p| p.service == service) {
        n.saturating_sub(1)
    } else {
        n
    }
}

struct ServiceOut {
    publisher: SlicePublisher<ControlInfo>,
    factory: iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        crate::channel::Service,
        [u8],
        ControlInfo,
    >,
}

/// The running contract machinery of one module (owned by its [`crate::Context`]).
pub(crate) struct ControlPlane {
    agent: ContractAgent,
    name: String,
    inbox: SliceSubscriber<ControlInfo>,
    queries: Vec<SliceSubscriber<ControlInfo>>,
    events: Subscriber<ModuleEvent>,
    costs: Subscriber<ResourceCosts>,
    effective: Subscriber<EffectiveCosts>,
    table: Publisher<ContractTable>,
    to_modules: HashMap<ModuleId, SlicePublisher<ControlInfo>>,
    to_services: HashMap<String, ServiceOut>,
    /// Heartbeats that say nothing new go out unannounced (control/repeats.rs).
    repeats: repeats::Repeats,
    drops: DropCounters,
    send_failures: u64,
    arbiters: Vec<(String, CommandArbiter)>,
    commands_accepted: u64,
    inputs: Vec<InputId>,
    /// See [`provider_poll_period`].
    provider_poll: Duration,
    /// The agent's next deadline (see [`ContractAgent::next_deadline`]).
    next_tick: Duration,
    next_provider_poll: Duration,
    /// Aptitude and quality last given to the agent (a change ticks it).
    self_eval: Option<(bool, f64)>,
    next_table: Duration,
    r_eff: ResourceVec,
    cost: ResourceVec,
    pending: Vec<PlaneEvent>,
    /// Provider changes held back while a call is open (see [`ControlPlane::take_events`]).
    held: Vec<PlaneEvent>,
    held_since: Option<Duration>,
    hold_limit: Duration,
    changed: bool,
}

impl std::fmt::Debug for ControlPlane {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ControlPlane")
            .field("module", &self.name)
            .field("agent", &self.agent.id())
            .finish_non_exhaustive()
    }
}

impl ControlPlane {
    /// Builds the agent from `spec` and opens the control channels.
    pub(crate) fn new(
        node: &Node,
        waiter: &mut Waiter,
        spec: &ContractSpec,
    ) -> Result<Self, Error> {
        let id = ModuleId(node.id());
        let mut cfg = match &spec.manager {
            Some(objectives) => {
                let o: Vec<&str> = objectives.iter().map(String::as_str).collect();
                AgentConfig::manager(id, &o)
            }
            None => AgentConfig::new(id),
        };
        cfg.provides.extend(spec.provides.iter().cloned());
        cfg.needs.extend(spec.needs.iter().cloned());
        if let Some(t) = spec.timing {
            cfg.timing = t;
        }
        if let Some(h) = spec.hysteresis {
            cfg.hysteresis = h;
        }
        if let Some(tau) = spec.tau {
            cfg.tau = tau;
        }
        let provider_poll = provider_poll_period(&cfg.timing);
        let cfg_reply_window = cfg.timing.reply_window;
        let mut agent = ContractAgent::new(cfg).map_err(|e| Error::Config(e.to_string()))?;
        for &need in &spec.disabled {
            agent.set_need_enabled(need, false);
        }

        let inbox = node.slice_subscriber::<ControlInfo>(&inbox_channel(id))?;
        waiter.attach(&inbox)?;
        let mut inputs = vec![inbox.id()];
        let mut queries = Vec::new();
        for offer in &agent.config().provides {
            let q = node.slice_subscriber::<ControlInfo>(&service_channel(&offer.service))?;
            waiter.attach(&q)?;
            inputs.push(q.id());
            queries.push(q);
        }
        let events = node.subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)?;
        waiter.attach(&events)?;
        inputs.push(events.id());
        let costs = node.subscriber::<ResourceCosts>(RM_COSTS)?;
        waiter.attach(&costs)?;
        inputs.push(costs.id());
        let effective = node.subscriber::<EffectiveCosts>(RM_EFFECTIVE_COSTS)?;
        waiter.attach(&effective)?;
        inputs.push(effective.id());
        let table = node.publisher::<ContractTable>(CONTRACTS)?;
        // Open the query channels of the needs now: the first call then costs no set-up.
        let mut to_services = HashMap::new();
        for n in &agent.config().needs {
            if !to_services.contains_key(&n.service) {
                to_services.insert(n.service.clone(), open_service_out(node, &n.service)?);
            }
        }
        let arbiters = spec
            .drives
            .iter()
            .map(|(s, f)| (s.clone(), CommandArbiter::new(*f)))
            .collect();
        let mut plane = ControlPlane {
            agent,
            name: node.name().to_string(),
            inbox,
            queries,
            events,
            costs,
            effective,
            table,
            to_modules: HashMap::new(),
            to_services,
            repeats: repeats::Repeats::default(),
            drops: DropCounters::default(),
            send_failures: 0,
            arbiters,
            commands_accepted: 0,
            inputs,
            provider_poll,
            next_tick: Duration::ZERO,
            next_provider_poll: Duration::ZERO,
            self_eval: None,
            next_table: Duration::ZERO,
            r_eff: ResourceVec::default(),
            cost: ResourceVec::default(),
            pending: Vec::new(),
            held: Vec::new(),
            held_since: None,
            hold_limit: cfg_reply_window,
            changed: true,
        };
        // On the simulation clock, contracts are negotiated from the first simulated instant
        // on, once every module is up (the simulator's paused start), and a channel opened on
        // first use costs wall time, not simulated time (none in lockstep). Listing the
        // prefix's services there only made every module's start slower, the later ones the
        // most (the list grows with every module up): 0.3-2 s of a 14-module system's start.
        if !node.clock().is_sim() {
            plane.discover_peers(node);
        }
        Ok(plane)
    }

    pub(crate) fn agent(&self) -> &ContractAgent {
        &self.agent
    }

    pub(crate) fn agent_mut(&mut self) -> &mut ContractAgent {
        &mut self.agent
    }

    /// True for the plane's own inputs (the module's `on_input` never sees them).
    pub(crate) fn owns(&self, input: InputId) -> bool {
        self.inputs.contains(&input)
    }

    /// When the plane wants to run next (clock time): the agent's next deadline, the end of
    /// a hold of provider changes, and, while a need waits for a provider, the next look at
    /// the number of providers. Messages wake the module anyway; nothing else is scheduled,
    /// so a module whose contracts are settled wakes only for heartbeats and refreshes.
    pub(crate) fn next_wake(&self) -> Duration {
        let mut at = self.next_tick;
        if self.agent.waiting_for_providers() {
            at = at.min(self.next_provider_poll);
        }
        if let Some(since) = self.held_since {
            at = at.min(since + self.hold_limit);
        }
        at
    }

    /// Transport-level drops (decode failures, spoofed senders).
    pub(crate) fn drops(&self) -> &DropCounters {
        &self.drops
    }

    /// Takes the events for the module's callbacks.
    ///
    /// Provider changes are held back while one of the module's calls is still collecting
    /// proposals (at most one reply window): `on_provider_changed` typically opens the new
    /// provider's data channel, which takes milliseconds (tens on a loaded machine) and
    /// would keep the module from answering, accepting and activating its other providers
    /// meanwhile, delaying the whole tree below it. Activation and contract-table changes
    /// are not held: a provider starts serving a new client at once.
    pub(crate) fn take_events(&mut self, now: Duration) -> Vec<PlaneEvent> {
        let mut out = Vec::with_capacity(self.pending.len());
        for ev in self.pending.drain(..) {
            match ev {
                PlaneEvent::Provider(..) => self.held.push(ev),
                other => out.push(other),
            }
        }
        if !self.held.is_empty() {
            let since = *self.held_since.get_or_insert(now);
            if !self.agent.calling() || now >= since + self.hold_limit {
                out.append(&mut self.held);
                self.held_since = None;
            }
        }
        out
    }

    /// Reads every control input, feeds the agent, ticks it when due (its next deadline, or a
    /// change of aptitude or quality), sends what it says and publishes the contract table
    /// when due or changed.
    pub(crate) fn poll(&mut self, node: &Node, aptitude: bool, quality: f64, now: Duration) {
        let inputs_changed = self.self_eval != Some((aptitude, quality));
        self.self_eval = Some((aptitude, quality));
        self.agent.set_aptitude(aptitude);
        self.agent.set_quality(quality);
        let mut out = Vec::new();
        let system_changed = self.read_system(now, &mut out);
        // Handling messages also does what is due (ContractAgent::handle_all).
        let ticked = self.read_control(now, &mut out);
        let mut due = now >= self.next_tick || inputs_changed || system_changed;
        if self.agent.waiting_for_providers() && now >= self.next_provider_poll {
            self.next_provider_poll = now + self.provider_poll;
            // A provider that started since the last call is called at once.
            for (service, s) in &self.to_services {
                let n = provider_count(&self.agent, service, s);
                self.agent.set_provider_count(service, n);
            }
            due = true;
        }
        if due && !ticked {
            out.extend(self.agent.tick(now));
        }
        self.dispatch(node, out, now);
        self.next_tick = self.agent.next_deadline().unwrap_or(Duration::MAX);
        if self.changed || now >= self.next_table {
            self.changed = false;
            self.next_table = now + TABLE_PERIOD;
            self.publish_table(now);
        }
    }

    fn collect_events(&mut self) {
        let events = self.agent.drain_events();
        if events.is_empty() {
            return;
        }
        self.changed = true;
        // A loss followed by a selection for the same need is one change of provider.
        for (k, ev) in events.iter().enumerate() {
            match ev {
                AgentEvent::Activated { .. } => self.pending.push(PlaneEvent::Activation(true)),
                AgentEvent::Deactivated => self.pending.push(PlaneEvent::Activation(false)),
                AgentEvent::ProviderSelected {
                    need,
                    provider,
                    channel,
                } => self.pending.push(PlaneEvent::Provider(
                    *need,
                    Some(ProviderInfo {
                        module: *provider,
                        channel: channel.clone(),
                    }),
                )),
                AgentEvent::ProviderLost { need, .. } => {
                    let reselected = events[k + 1..].iter().any(
                        |e| matches!(e, AgentEvent::ProviderSelected { need: n, .. } if n == need),
                    );
                    if !reselected {
                        self.pending.push(PlaneEvent::Provider(*need, None));
                    }
                }
                _ => {}
            }
        }
        self.pending.push(PlaneEvent::ContractsChanged);
    }

    /// The module is stopping: end every contract now and say so in the table.
    pub(crate) fn shutdown(&mut self, node: &Node, now: Duration) {
        let out = self.agent.shutdown(now);
        for o in &out {
            self.send(node, o);
        }
        let _ = self.agent.drain_events();
        self.publish_table(now);
    }

    /// A driver's verdict on a command whose header is `header`, for service `service`.
    pub(crate) fn command_verdict(
        &mut self,
        service: &str,
        header: &Header,
        now: Duration,
    ) -> Verdict {
        let holders: Vec<(ModuleId, Priority)> = self
            .agent
            .client_contracts()
            .filter(|c| c.service == service)
            .map(|c| (c.client, c.priority))
            .collect();
        let idx = match self.arbiters.iter().position(|(s, _)| s == service) {
            Some(i) => i,
            None => {
                self.arbiters.push((
                    service.to_string(),
                    CommandArbiter::new(DEFAULT_COMMAND_FRESHNESS),
                ));
                self.arbiters.len() - 1
            }
        };
        let arbiter = &mut self.arbiters[idx].1;
        arbiter.sync(holders);
        let v = arbiter.on_command(ModuleId(header.source), now);
        if v == Verdict::Accept {
            self.commands_accepted += 1;
        }
        v
    }

    /// Driver drops summed over the module's arbiters.
    pub(crate) fn command_drops(&self) -> DropCounters {
        let mut d = DropCounters::default();
        for (_, a) in &self.arbiters {
            d.merge(a.drops());
        }
        d
    }

    fn publish_table(&mut self, now: Duration) {
        let mut t = ContractTable {
            module_id: self.agent.id().0,
            active: u8::from(self.agent.is_active()),
            value: self.agent.value(now).map_or(f32::NAN, |v| v as f32),
            ..Default::default()
        };
        t.set_module(&self.name);
        if let Some(p) = self.agent.priority() {
            t.set_priority(p.parts());
        }
        let own_value = t.value;
        for c in self.agent.provider_contracts() {
            let mut e = ContractEntry {
                role: ContractRole::Client as u8,
                peer: c.provider.0,
                value: c.value as f32,
                need: c.need,
                ..Default::default()
            };
            if let Some(spec) = self.agent.needs().find(|n| n.rank == c.need) {
                e.set_service(&spec.service);
            }
            e.set_channel(c.channel);
            e.set_priority(c.priority.parts());
            t.push(e);
        }
        for c in self.agent.client_contracts() {
            let mut e = ContractEntry {
                role: ContractRole::Provider as u8,
                peer: c.client.0,
                value: own_value,
                need: c.need,
                ..Default::default()
            };
            e.set_service(c.service);
            if let Some(o) = self
                .agent
                .config()
                .provides
                .iter()
                .find(|o| o.service == c.service)
            {
                e.set_channel(&o.channel_for(self.agent.id()));
            }
            e.set_priority(c.priority.parts());
            t.push(e);
        }
        t.control_drops = self.drops.total() + self.send_failures;
        t.protocol_drops = self.agent.drops().total();
        let cd = self.command_drops();
        t.commands_accepted = self.commands_accepted;
        t.commands_preempted = cd.get(DropReason::Preempted);
        t.commands_no_contract = cd.get(DropReason::NoContract);
        if let Err(e) = self.table.publish(t) {
            tracing::debug!(module = %self.name, "contract table: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_channel_names_are_distinct_and_valid() {
        assert_eq!(inbox_channel(ModuleId(7)), "hng/ctl/m7");
        assert_eq!(
            service_channel("Robot control"),
            "hng/ctl/svc/Robot%20control"
        );
        assert_ne!(service_channel("a b"), service_channel("a_b"));
        assert_ne!(service_channel("a/b"), service_channel("a%2Fb"));
        for s in ["LIDAR data", "Localization", "é/ü %"] {
            assert!(ServiceName::new(&service_channel(s)).is_ok(), "{s}");
        }
    }

    #[test]
    fn control_provider_poll_period_is_bounded() {
        let mut t = Timing::default();
        assert_eq!(provider_poll_period(&t), Duration::from_millis(50));
        t.reply_window = Duration::from_millis(2);
        assert_eq!(provider_poll_period(&t), Duration::from_millis(10));
        t.reply_window = Duration::from_secs(2);
        assert_eq!(provider_poll_period(&t), Duration::from_millis(100));
    }
}
