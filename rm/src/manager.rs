//! The resource manager's state, without I/O on channels: fed with reports, contract
//! tables and the supervisor's status, it samples the modules (procfs, cgroups) once per
//! period and returns what to publish. [`crate::module::RmModule`] wires it to iceoryx2.
//!
//! Per period ([`ResourceManager::tick`]):
//! 1. one sampling pass over every known module ([`Sampler`]), and a machine-wide sample
//!    ([`SystemSampler`]);
//! 2. the software check of the limits the kernel does not enforce
//!    ([`SoftwareEnforcer`]): a module over its CPU or memory limit yields an
//!    [`OverLimitCommand`] for the supervisor (once per process and
//!    [`RmConfig::over_limit_repeat_s`]);
//! 3. C_R(t) and the degraded mode ([`RmCore`]) from the free resources, the
//!    wait-for-resources flags and the largest report delay, over the priorities of the
//!    active contracts of the CONTRACTS tables;
//! 4. R of every module (normalised: cores / online cores, bytes / total memory, message
//!    rate / [`RmConfig::comm_budget_msgs_per_s`]) and R_eff (eq. 4) over the contract
//!    graph of the tables (R_eff = R while no table is published).

use std::collections::{BTreeMap, HashMap, HashSet};
use std::time::{Duration, Instant};

use hng_runtime::contract::Priority;
use hng_runtime::msg::{ModuleReport, ModuleState, module_id};
use hng_runtime::system::{
    ContractRole, ContractTable, EffectiveCosts, MAX_MODULES, MAX_PRIORITY_DEPTH, ModuleCost,
    ResourceCosts,
};
use serde::Deserialize;
use serde_json::{Value, json};

pub use self::config::{Bytes, LimitConfig, RmConfig, parse_bytes};
pub use self::status::bar_text;
use self::status::short_reason;
use crate::cgroup::{CgroupRun, CgroupSupport, ModuleCgroup};
use crate::cost::{
    CostConfig, ModuleNode, ReportDelays, ResourceObservation, ResourceVec, WaitingFor,
    effective_costs,
};
use crate::degraded::{DegradedConfig, RmCore, ServeBar};
use crate::error::{Result, RmError};
use crate::limits::{ResourceLimits, SoftwareEnforcer, SoftwareEnforcerConfig};

mod config;
mod status;

use crate::sampler::{
    CpuSource, Liveness, ModuleSample, ModuleTarget, Sampler, SamplerConfig, SystemSample,
    SystemSampler, process_starttime,
};

/// A request to the supervisor: kill and restart `module` with exit cause "over limit".
#[derive(Debug, Clone, PartialEq)]
pub struct OverLimitCommand {
    /// The module.
    pub module: String,
    /// Its pid when measured.
    pub pid: i32,
    /// Which limit, e.g. "memory 80.0 MiB > 64.0 MiB".
    pub reason: String,
}

/// What one period produced: the messages to publish.
#[derive(Debug, Clone)]
pub struct TickOutput {
    /// C_R(t) and the degraded-mode bar.
    pub costs: ResourceCosts,
    /// R and R_eff of every module.
    pub effective: EffectiveCosts,
    /// The RM_STATUS document.
    pub status: Value,
    /// Modules to stop over their limit.
    pub over_limit: Vec<OverLimitCommand>,
}

/// How a cap is enforced, for the status.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Enforced {
    Kernel,
    Software,
}

impl Enforced {
    fn as_str(self) -> &'static str {
        match self {
            Enforced::Kernel => "kernel",
            Enforced::Software => "software",
        }
    }
}

#[derive(Debug)]
struct Tracked {
    id: u32,
    /// The process being sampled (reported pid, verified).
    pid: Option<i32>,
    /// The last pid refused (so a stale pid is not re-checked on every report).
    refused_pid: Option<u32>,
    last_report: Option<Instant>,
    state: Option<ModuleState>,
    quality: f32,
    waiting: bool,
    report_period: Duration,
    msgs: Option<(Instant, u64)>,
    msg_rate: f64,
    gone_since: Option<Instant>,
    requested: ResourceLimits,
    kernel: ResourceLimits,
    cpu_enforced: Option<Enforced>,
    mem_enforced: Option<Enforced>,
    cgroup: Option<ModuleCgroup>,
    last_over: Option<(i32, Instant, String)>,
    restarts: Option<u64>,
    supervisor_state: Option<String>,
}

impl Tracked {
    fn new(name: &str) -> Self {
        Tracked {
            id: module_id(name),
            pid: None,
            refused_pid: None,
            last_report: None,
            state: None,
            quality: 0.0,
            waiting: false,
            report_period: Duration::from_millis(100),
            msgs: None,
            msg_rate: 0.0,
            gone_since: None,
            requested: ResourceLimits::default(),
            kernel: ResourceLimits::default(),
            cpu_enforced: None,
            mem_enforced: None,
            cgroup: None,
            last_over: None,
            restarts: None,
            supervisor_state: None,
        }
    }
}

#[derive(Debug, Clone)]
struct Table {
    at: Instant,
    table: ContractTable,
}

/// The resource manager (see the module documentation).
#[derive(Debug)]
pub struct ResourceManager {
    config: RmConfig,
    sampler: Sampler,
    system: SystemSampler,
    last_system: Option<SystemSample>,
    enforcer: SoftwareEnforcer,
    core: RmCore<Priority>,
    delays: ReportDelays,
    last_delay: Option<Duration>,
    waiting_reports: u64,
    modules: BTreeMap<String, Tracked>,
    tables: HashMap<u32, Table>,
    cgroup_run: Option<CgroupRun>,
    cgroup_note: String,
    warned: HashSet<String>,
    ns_per_tick: u64,
    supervisor_limits: BTreeMap<String, ResourceLimits>,
    passes: u64,
}

/// Delays above this are not measured on the monotonic clock (simulated time).
const MAX_PLAUSIBLE_DELAY: Duration = Duration::from_secs(10);

impl ResourceManager {
    /// A manager with `config`; `cgroup_run` is the run to attach to (`HNG_CGROUP_RUN`),
    /// if any. Fails only on an invalid configuration or without /proc.
    pub fn new(config: RmConfig, cgroup_run: Option<&str>) -> Result<Self> {
        let sampler = Sampler::new(SamplerConfig {
            rate_hz: config.rate_hz,
            pss_every: config.pss_every,
            ..SamplerConfig::default()
        })?;
        let core = RmCore::new(
            config.cost_config()?,
            DegradedConfig {
                enter_after: config.degraded_enter_after,
                step_after: config.degraded_step_after,
                recover_after: config.degraded_recover_after,
                allow_full_stop: config.allow_full_stop,
            },
        )?;
        if !(config.comm_budget_msgs_per_s.is_finite() && config.comm_budget_msgs_per_s > 0.0) {
            return Err(RmError::Config(format!(
                "comm_budget_msgs_per_s must be > 0, got {}",
                config.comm_budget_msgs_per_s
            )));
        }
        let (run, note) = match cgroup_run.filter(|_| config.cgroups) {
            None => (
                None,
                "no cgroup run (HNG_CGROUP_RUN unset): measuring from /proc, limits in software"
                    .to_owned(),
            ),
            Some(name) => {
                let support = CgroupSupport::detect();
                match CgroupRun::open(&support, name) {
                    Ok(run) => {
                        let version = match support.version() {
                            Some(crate::cgroup::CgroupVersion::V1) => "v1",
                            Some(crate::cgroup::CgroupVersion::V2) => "v2",
                            None => "none",
                        };
                        let note = format!("cgroup {version}, run {name}");
                        (Some(run), note)
                    }
                    Err(e) => {
                        tracing::warn!(
                            "cannot attach to the cgroups of run {name}: {e}; measuring from /proc, limits in software"
                        );
                        (None, format!("cannot attach to run {name}: {e}"))
                    }
                }
            }
        };
        let tps = procfs::ticks_per_second().max(1);
        Ok(ResourceManager {
            enforcer: SoftwareEnforcer::new(SoftwareEnforcerConfig {
                cpu_window: Duration::from_secs_f64(config.cpu_window_s),
            }),
            config,
            sampler,
            system: SystemSampler::new()?,
            last_system: None,
            core,
            delays: ReportDelays::default(),
            last_delay: None,
            waiting_reports: 0,
            modules: BTreeMap::new(),
            tables: HashMap::new(),
            cgroup_run: run,
            cgroup_note: note,
            warned: HashSet::new(),
            ns_per_tick: 1_000_000_000 / tps,
            supervisor_limits: BTreeMap::new(),
            passes: 0,
        })
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &RmConfig {
        &self.config
    }

    fn warn_once(&mut self, key: String, msg: impl FnOnce() -> String) {
        if self.warned.insert(key) {
            tracing::warn!("{}", msg());
        }
    }

    /// One module report, received at `received_ns` (CLOCK_MONOTONIC) and `now`.
    pub fn on_report(&mut self, r: &ModuleReport, received_ns: u64, now: Instant) {
        let name = r.name();
        if name.is_empty() || name == "?" {
            self.warn_once("bad-report-name".into(), || {
                "ignoring a report without a valid module name".into()
            });
            return;
        }
        let delay = Duration::from_nanos(received_ns.saturating_sub(r.header.stamp_ns));
        let plausible = delay <= MAX_PLAUSIBLE_DELAY && r.header.stamp_ns <= received_ns;
        if plausible {
            self.delays.record(r.header.stamp_ns, received_ns);
        }
        if r.waiting_for_resources != 0 {
            self.waiting_reports += 1;
        }
        let name = name.to_owned();
        let t = self
            .modules
            .entry(name.clone())
            .or_insert_with(|| Tracked::new(&name));
        t.last_report = Some(now);
        t.state = ModuleState::from_repr(r.state);
        t.quality = r.quality;
        t.waiting = r.waiting_for_resources != 0;
        if r.period_ns > 0 {
            t.report_period = Duration::from_nanos(r.period_ns);
        }
        let msgs = r.msgs_in.saturating_add(r.msgs_out);
        if let Some((at, prev)) = t.msgs {
            let dt = now.saturating_duration_since(at).as_secs_f64();
            if dt >= 0.05 {
                t.msg_rate = msgs.saturating_sub(prev) as f64 / dt;
                t.msgs = Some((now, msgs));
            }
        } else {
            t.msgs = Some((now, msgs));
        }
        let Ok(pid) = i32::try_from(r.pid) else {
            return;
        };
        if pid <= 0 || t.pid == Some(pid) || t.refused_pid == Some(r.pid) {
            return;
        }
        // A new process for this module: check that the pid still is the sender (born
        // before the report was sent), then sample it.
        let stamp = plausible.then_some(r.header.stamp_ns);
        self.adopt(&name, pid, stamp, now);
    }

    /// Starts sampling `pid` as module `name`, if it is a live process born before
    /// `sent_ns` (monotonic; `None` = unknown, not checked).
    fn adopt(&mut self, name: &str, pid: i32, sent_ns: Option<u64>, now: Instant) {
        let starttime = match process_starttime(pid) {
            Ok(s) => s,
            Err(e) => {
                tracing::debug!(module = name, pid, "not sampled: {e}");
                if let Some(t) = self.modules.get_mut(name) {
                    t.refused_pid = u32::try_from(pid).ok();
                }
                return;
            }
        };
        if let Some(sent) = sent_ns {
            let start_mono = starttime
                .saturating_mul(self.ns_per_tick)
                .saturating_sub(boottime_minus_monotonic_ns());
            // One tick of rounding either way.
            if start_mono > sent.saturating_add(2 * self.ns_per_tick) {
                tracing::warn!(
                    module = name,
                    pid,
                    "pid {pid} belongs to a process started after the module's report: pid reused, not sampled"
                );
                if let Some(t) = self.modules.get_mut(name) {
                    t.refused_pid = u32::try_from(pid).ok();
                }
                return;
            }
        }
        self.sampler.remove(name);
        self.enforcer.remove(name);
        let cgroup = self.module_cgroup(name, pid);
        let counter = cgroup.as_ref().and_then(ModuleCgroup::cpu_counter);
        let target = ModuleTarget::new(name, pid)
            .with_starttime(starttime)
            .with_cgroup_cpu(counter);
        if let Err(e) = self.sampler.add(target) {
            tracing::debug!(module = name, pid, "not sampled: {e}");
            if let Some(t) = self.modules.get_mut(name) {
                t.refused_pid = u32::try_from(pid).ok();
            }
            return;
        }
        let kernel = cgroup
            .as_ref()
            .map(ModuleCgroup::kernel_caps)
            .unwrap_or_default();
        let requested = self.requested_limits(name);
        let Some(t) = self.modules.get_mut(name) else {
            return;
        };
        t.pid = Some(pid);
        t.refused_pid = None;
        t.gone_since = None;
        t.cgroup = cgroup;
        t.kernel = kernel;
        tracing::info!(module = name, pid, "sampling");
        let _ = now;
        self.apply_limits(name, requested);
    }

    /// The module's cgroup in the attached run, if the process is in it.
    fn module_cgroup(&mut self, name: &str, pid: i32) -> Option<ModuleCgroup> {
        let run = self.cgroup_run.as_ref()?;
        match run.existing_module(name) {
            Ok(Some(cg)) => match cg.pids() {
                Ok(pids) if pids.contains(&pid) => Some(cg),
                _ => None,
            },
            Ok(None) => None,
            Err(e) => {
                let msg = format!("module {name}: {e}");
                self.warn_once(format!("cg-{name}"), || msg);
                None
            }
        }
    }

    fn requested_limits(&self, name: &str) -> ResourceLimits {
        match self.config.limits.get(name) {
            Some(l) => l.to_limits(),
            None => self
                .supervisor_limits
                .get(name)
                .cloned()
                .unwrap_or_default(),
        }
    }

    /// Splits the requested limits into what the kernel enforces (its caps read back
    /// from the module's cgroup are at most the request) and what the software check
    /// must enforce.
    fn apply_limits(&mut self, name: &str, requested: ResourceLimits) {
        let Some(t) = self.modules.get_mut(name) else {
            return;
        };
        let kernel_cpu = matches!((requested.cpu_percent, t.kernel.cpu_percent),
            (Some(r), Some(k)) if k <= r * 1.001);
        let kernel_mem = matches!((requested.memory_bytes, t.kernel.memory_bytes),
            (Some(r), Some(k)) if k <= r);
        t.cpu_enforced = requested.cpu_percent.map(|_| {
            if kernel_cpu {
                Enforced::Kernel
            } else {
                Enforced::Software
            }
        });
        t.mem_enforced = requested.memory_bytes.map(|_| {
            if kernel_mem {
                Enforced::Kernel
            } else {
                Enforced::Software
            }
        });
        let software = ResourceLimits {
            cpu_percent: requested.cpu_percent.filter(|_| !kernel_cpu),
            memory_bytes: requested.memory_bytes.filter(|_| !kernel_mem),
            ..Default::default()
        };
        t.requested = requested;
        if software.cpu_percent.is_some() || software.memory_bytes.is_some() {
            self.enforcer.set_limits(name, software);
        } else {
            self.enforcer.remove(name);
        }
    }

    /// One contract table from the CONTRACTS channel.
    pub fn on_contract_table(&mut self, table: &ContractTable, now: Instant) {
        if table.module_id == 0 && table.module().is_empty() {
            self.warn_once("bad-table".into(), || {
                "ignoring a contract table without module id or name".into()
            });
            return;
        }
        // Peers name each other by module id (the node id, a hash of the name).
        let id = if table.module_id != 0 {
            table.module_id
        } else {
            module_id(table.module())
        };
        self.tables.insert(
            id,
            Table {
                at: now,
                table: *table,
            },
        );
    }

    /// One period: sample, check limits, update costs and the degraded mode, compute
    /// R and R_eff. `stamp_ns`: now on CLOCK_MONOTONIC (for the status).
    pub fn tick(&mut self, now: Instant) -> TickOutput {
        self.passes += 1;
        let samples: Vec<ModuleSample> = self.sampler.sample(now).to_vec();
        let mut over_limit = Vec::new();
        let repeat = Duration::from_secs_f64(self.config.over_limit_repeat_s);
        for s in &samples {
            match s.liveness {
                Liveness::Alive => {}
                Liveness::Exited | Liveness::PidReused => {
                    self.sampler.remove(&s.name);
                    self.enforcer.remove(&s.name);
                    if let Some(t) = self.modules.get_mut(&s.name) {
                        t.pid = None;
                        t.gone_since = Some(now);
                        t.cgroup = None;
                    }
                    continue;
                }
                Liveness::ReadError(_) => continue,
            }
            let Some(v) = self.enforcer.check(s) else {
                continue;
            };
            let Some(t) = self.modules.get_mut(&s.name) else {
                continue;
            };
            let reason = short_reason(&v);
            let due = match &t.last_over {
                Some((pid, at, _)) => *pid != s.pid || now.saturating_duration_since(*at) >= repeat,
                None => true,
            };
            if due {
                tracing::warn!(module = %s.name, pid = s.pid, "{v}: asking the supervisor to restart it");
                t.last_over = Some((s.pid, now, reason.clone()));
                over_limit.push(OverLimitCommand {
                    module: s.name.clone(),
                    pid: s.pid,
                    reason,
                });
            }
        }
        // Forget modules gone for long.
        let forget = Duration::from_secs_f64(self.config.forget_after_s);
        self.modules.retain(|_, t| {
            let silent = t
                .last_report
                .is_none_or(|r| now.saturating_duration_since(r) >= forget);
            !(t.pid.is_none()
                && t.gone_since
                    .is_some_and(|g| now.saturating_duration_since(g) >= forget)
                && silent)
        });
        let table_timeout = Duration::from_secs_f64(self.config.table_timeout_s);
        self.tables
            .retain(|_, t| now.saturating_duration_since(t.at) < table_timeout);

        // C_R(t) and degraded mode.
        let system = match self.system.sample() {
            Ok(s) => Some(s),
            Err(e) => {
                let msg = format!("machine-wide sample failed: {e}");
                self.warn_once("system-sample".into(), || msg);
                None
            }
        };
        if system.is_some() {
            self.last_system = system;
        }
        // A module waits for resources until a report says otherwise: its latest report
        // counts while fresh (three report periods, at least 300 ms), whatever the rates
        // of the reports and of the RM.
        let waiting_now = self.waiting_reports > 0
            || self.modules.values().any(|t| {
                t.waiting
                    && t.last_report.is_some_and(|r| {
                        now.saturating_duration_since(r)
                            <= (t.report_period * 3).max(Duration::from_millis(300))
                    })
            });
        let waiting = if waiting_now {
            WaitingFor::CPU_AND_MEMORY
        } else {
            WaitingFor::NONE
        };
        let waiting_reports = std::mem::take(&mut self.waiting_reports);
        let max_delay = self.delays.take_max();
        if max_delay.is_some() {
            self.last_delay = max_delay;
        }
        // Share of the busy CPU that the system's own modules use.
        let own_cpu_share = system.and_then(|s| {
            let busy = (1.0 - s.cpu_free?) * f64::from(s.cpus.max(1)) * 100.0;
            let ours: f64 = samples
                .iter()
                .filter(|m| m.liveness == Liveness::Alive)
                .filter_map(|m| m.cpu_percent)
                .sum();
            Some(if busy > 1.0 { ours / busy } else { 1.0 })
        });
        let obs = match &system {
            Some(s) => ResourceObservation::from_system(s, waiting, max_delay)
                .with_own_cpu_share(own_cpu_share),
            None => ResourceObservation {
                waiting_for: waiting,
                max_report_delay: max_delay,
                ..Default::default()
            },
        };
        let active = self.active_priorities();
        let decision = self.core.update(&obs, &active);
        if decision.change != crate::degraded::BarChange::Unchanged {
            tracing::info!(
                bar = %bar_text(&decision.bar),
                change = ?decision.change,
                "degraded mode"
            );
        }

        // R and R_eff.
        let (cpus, mem_total) = self
            .last_system
            .map_or((1, 0), |s| (s.cpus, s.mem_total_bytes));
        let mut own: BTreeMap<u32, (String, ResourceVec)> = BTreeMap::new();
        for (name, t) in &self.modules {
            let r = match self.sampler.get(name) {
                Some(s) if t.pid.is_some() => ResourceVec::from_usage(
                    s.cpu_percent.unwrap_or(0.0),
                    cpus,
                    s.memory_bytes(),
                    mem_total,
                    t.msg_rate / self.config.comm_budget_msgs_per_s,
                ),
                _ => ResourceVec::ZERO,
            };
            own.insert(t.id, (name.clone(), r));
        }
        let eff = self.effective(&own);

        let mut costs = ResourceCosts {
            cpu: decision.costs.cpu,
            mem: decision.costs.memory,
            comm: decision.costs.comm,
            degraded: u8::from(decision.bar.is_degraded()),
            ..Default::default()
        };
        match &decision.bar {
            ServeBar::All => {}
            ServeBar::Nothing => costs.serve_nothing = 1,
            ServeBar::AtMost(p) => {
                let parts = p.parts();
                let n = parts.len().min(MAX_PRIORITY_DEPTH);
                costs.min_priority[..n].copy_from_slice(&parts[..n]);
                costs.min_priority_len = n as u8;
            }
        }
        let mut effective = EffectiveCosts::default();
        for (i, (id, (_, r))) in own.iter().take(MAX_MODULES).enumerate() {
            let e = eff.get(id).copied().unwrap_or(*r);
            effective.modules[i] = ModuleCost {
                module_id: *id,
                own: [r.cpu, r.memory, r.comm],
                effective: [e.cpu, e.memory, e.comm],
            };
            effective.count = (i + 1) as u32;
        }
        if own.len() > MAX_MODULES {
            let n = own.len();
            self.warn_once("too-many".into(), || {
                format!(
                    "{n} modules: only the first {MAX_MODULES} fit in the effective-cost message"
                )
            });
        }

        let status = self.status_json(&own, &eff, &decision, &obs, waiting_reports, &active);
        TickOutput {
            costs,
            effective,
            status,
            over_limit,
        }
    }

    /// Priorities of the active contracts of the fresh tables. Malformed priorities are
    /// skipped (one warning).
    fn active_priorities(&mut self) -> Vec<Priority> {
        let mut out = Vec::new();
        let mut bad = None;
        for t in self.tables.values() {
            if t.table.active == 0 {
                continue;
            }
            for e in t.table.entries() {
                if e.priority().is_empty() {
                    continue;
                }
                match Priority::new(e.priority()) {
                    Ok(p) => out.push(p),
                    Err(err) => bad = Some(format!("module {}: {err}", t.table.module())),
                }
            }
        }
        if let Some(msg) = bad {
            self.warn_once("bad-priority".into(), || {
                format!("ignoring a contract with an invalid priority ({msg})")
            });
        }
        out
    }

    /// R_eff by eq. (4) over the contract graph of the tables; R_eff = R for modules not
    /// in it and when the graph is unusable (a cycle: one warning).
    fn effective(
        &mut self,
        own: &BTreeMap<u32, (String, ResourceVec)>,
    ) -> HashMap<u32, ResourceVec> {
        if self.tables.is_empty() {
            return HashMap::new();
        }
        let mut nodes: BTreeMap<u32, ModuleNode<u32>> = BTreeMap::new();
        let node = |id: u32, own: &BTreeMap<u32, (String, ResourceVec)>| ModuleNode {
            id,
            own: own.get(&id).map_or(ResourceVec::ZERO, |(_, r)| *r),
            providers: Vec::new(),
            queries_answered: 0,
        };
        for (&id, t) in &self.tables {
            for e in t.table.entries() {
                match e.role() {
                    Some(ContractRole::Client) => {
                        nodes
                            .entry(id)
                            .or_insert_with(|| node(id, own))
                            .providers
                            .push(e.peer);
                        nodes.entry(e.peer).or_insert_with(|| node(e.peer, own));
                    }
                    Some(ContractRole::Provider) => {
                        let n = nodes.entry(id).or_insert_with(|| node(id, own));
                        n.queries_answered = n.queries_answered.saturating_add(1);
                    }
                    None => {}
                }
            }
        }
        let list: Vec<ModuleNode<u32>> = nodes.into_values().collect();
        match effective_costs(&list) {
            Ok(m) => m,
            Err(e) => {
                let msg = e.to_string();
                self.warn_once(format!("eq4-{msg}"), || {
                    format!("effective costs: {msg}; using R_eff = R")
                });
                HashMap::new()
            }
        }
    }
}

/// CLOCK_BOOTTIME − CLOCK_MONOTONIC (time spent suspended), ns: process start times in
/// /proc count from boot including suspend, report stamps do not.
fn boottime_minus_monotonic_ns() -> u64 {
    let get = |id| {
        nix::time::clock_gettime(id).map_or(0u64, |t| {
            u64::try_from(t.tv_sec())
                .unwrap_or(0)
                .saturating_mul(1_000_000_000)
                .saturating_add(u64::try_from(t.tv_nsec()).unwrap_or(0))
        })
    };
    let mono = get(nix::time::ClockId::CLOCK_MONOTONIC);
    let boot = get(nix::time::ClockId::CLOCK_BOOTTIME);
    boot.saturating_sub(mono)
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::system::ContractEntry;

    fn report(name: &str, pid: u32, stamp_ns: u64, waiting: bool) -> ModuleReport {
        let mut r = ModuleReport {
            pid,
            state: ModuleState::Running as u8,
            waiting_for_resources: u8::from(waiting),
            ..Default::default()
        };
        r.header.stamp_ns = stamp_ns;
        r.set_name(name);
        r
    }

    fn table(name: &str, entries: &[(ContractRole, &str, &[u16])]) -> ContractTable {
        let mut t = ContractTable {
            module_id: module_id(name),
            active: 1,
            ..Default::default()
        };
        t.set_module(name);
        for (i, (role, peer, prio)) in entries.iter().enumerate() {
            let mut e = ContractEntry {
                role: *role as u8,
                peer: module_id(peer),
                priority_len: prio.len() as u8,
                ..Default::default()
            };
            e.priority[..prio.len()].copy_from_slice(prio);
            e.set_service("svc");
            t.entries[i] = e;
        }
        t.count = entries.len() as u32;
        t
    }

    #[test]
    fn parses_byte_counts() {
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert_eq!(parse_bytes("64MiB"), Ok(64 << 20));
        assert_eq!(parse_bytes("64M"), Ok(64 << 20));
        assert_eq!(parse_bytes("1GB"), Ok(1_000_000_000));
        assert!(parse_bytes("12 parsecs").is_err());
        assert!(parse_bytes("").is_err());
        let c: RmConfig = toml::from_str(
            "rate_hz = 20\n[limits.hog]\nmemory_max = \"64MiB\"\ncpu_percent = 50\n",
        )
        .expect("valid config");
        assert_eq!(c.limits["hog"].memory_max, Some(Bytes(64 << 20)));
        assert!(
            toml::from_str::<RmConfig>("rate = 20").is_err(),
            "unknown field"
        );
    }

    #[test]
    fn bad_config_is_an_error_not_a_crash() {
        let bad = RmConfig {
            rate_hz: 0.0,
            ..Default::default()
        };
        assert!(ResourceManager::new(bad, None).is_err());
        let bad = RmConfig {
            cost_raise_factor: 0.5,
            ..Default::default()
        };
        assert!(ResourceManager::new(bad, None).is_err());
    }

    /// Reports teach the RM the modules and their pids; garbage is ignored; R_eff
    /// follows eq. (4) over the published tables.
    #[test]
    fn learns_modules_from_reports_and_computes_eq4_from_tables() {
        let mut rm = ResourceManager::new(RmConfig::default(), None).expect("rm");
        let me = std::process::id();
        let now = Instant::now();
        let sent = hng_runtime::clock::monotonic_ns();
        for name in ["client", "provider"] {
            rm.on_report(&report(name, me, sent, false), sent + 1000, now);
        }
        // Garbage: a pid that does not exist, a name-less report, a stamp in the future.
        rm.on_report(&report("ghost", i32::MAX as u32, sent, false), sent, now);
        rm.on_report(&report("", me, sent, false), sent, now);
        rm.on_report(
            &report("future", me, sent + 1_000_000_000, false),
            sent,
            now,
        );
        // client uses provider; provider serves two queries.
        rm.on_contract_table(
            &table("client", &[(ContractRole::Client, "provider", &[1])]),
            now,
        );
        rm.on_contract_table(
            &table(
                "provider",
                &[
                    (ContractRole::Provider, "client", &[1]),
                    (ContractRole::Provider, "other", &[2]),
                ],
            ),
            now,
        );
        let _ = rm.tick(Instant::now());
        std::thread::sleep(Duration::from_millis(30));
        let out = rm.tick(Instant::now());
        let get = |name: &str| {
            *out.effective
                .of(module_id(name))
                .unwrap_or_else(|| panic!("{name} in effective costs"))
        };
        let (c, p) = (get("client"), get("provider"));
        for k in 0..3 {
            let want = c.own[k] + p.effective[k] / 2.0;
            assert!((c.effective[k] - want).abs() < 1e-12, "{c:?} {p:?}");
            assert_eq!(p.effective[k], p.own[k]);
        }
        let mods = out.status["modules"].as_array().expect("modules");
        let names: Vec<&str> = mods.iter().filter_map(|m| m["name"].as_str()).collect();
        assert!(
            names.contains(&"client") && names.contains(&"ghost"),
            "{names:?}"
        );
        let ghost = mods.iter().find(|m| m["name"] == "ghost").expect("ghost");
        assert!(
            ghost["pid"].is_null(),
            "a pid that does not exist is not sampled"
        );
        assert_eq!(out.status["active_contracts"], 3);
    }

    #[test]
    fn waiting_reports_raise_costs_and_degraded_mode_cuts_least_important() {
        let cfg = RmConfig {
            // Only the wait-for-resources reports count (the machine running the test
            // may well be busy).
            cpu_free_threshold: 0.0,
            memory_free_threshold: 0.0,
            degraded_enter_after: 1,
            degraded_step_after: 1,
            degraded_recover_after: 1,
            ..Default::default()
        };
        let mut rm = ResourceManager::new(cfg, None).expect("rm");
        let now = Instant::now();
        rm.on_contract_table(
            &table(
                "p",
                &[
                    (ContractRole::Provider, "m", &[1]),
                    (ContractRole::Provider, "m", &[2]),
                    (ContractRole::Provider, "m", &[3]),
                ],
            ),
            now,
        );
        let mut bars = Vec::new();
        for _ in 0..8 {
            let sent = hng_runtime::clock::monotonic_ns();
            rm.on_report(&report("w", 0, sent, true), sent, now);
            let out = rm.tick(now);
            bars.push(out.costs.min_priority().map(<[u16]>::to_vec));
        }
        let first_cut = bars.iter().flatten().next().cloned();
        assert_eq!(first_cut, Some(vec![2]), "{bars:?}");
        assert_eq!(bars.last().cloned().flatten(), Some(vec![1]), "{bars:?}");
        // Calm: the module reports that it no longer waits; back to normal.
        let mut last = None;
        for _ in 0..5 {
            let sent = hng_runtime::clock::monotonic_ns();
            rm.on_report(&report("w", 0, sent, false), sent, now);
            last = Some(rm.tick(now));
        }
        let last = last.expect("ticks");
        assert_eq!(last.costs.degraded, 0);
        assert!(last.costs.cpu < RmConfig::default().cost_max);
    }

    #[test]
    fn bad_supervisor_status_and_priorities_do_not_crash() {
        let mut rm = ResourceManager::new(RmConfig::default(), None).expect("rm");
        let now = Instant::now();
        rm.on_supervisor_status(b"not json", now);
        rm.on_supervisor_status(b"{\"modules\": 3}", now);
        // A document of another shape is ignored whole (the schema is the runtime's typed
        // StatusDoc), then a real one is learned.
        rm.on_supervisor_status(
            br#"{"modules":[{"name":"a","pid":-5,"caps":{"cpu_quota":0.2,"memory_max":1000}},{"nope":1}]}"#,
            now,
        );
        assert!(rm.supervisor_limits.is_empty());
        let doc = hng_runtime::system::status::StatusDoc {
            system: "s".into(),
            prefix: "p_".into(),
            supervisor_pid: 1,
            uptime_ms: 0.0,
            shutting_down: false,
            commands: 0,
            last_command: None,
            modules: vec![hng_runtime::system::status::ModuleRow {
                name: "a".into(),
                state: "running".into(),
                pid: None,
                uptime_ms: None,
                restarts: 2,
                last_exit: None,
                last_exit_text: None,
                heartbeat_age_ms: None,
                restart_in_ms: None,
                manager: false,
                report: None,
                caps: Some(hng_runtime::system::status::CapsRow {
                    cpu_quota: Some(0.2),
                    memory_max: Some(1000),
                    ..Default::default()
                }),
            }],
        };
        rm.on_supervisor_status(&serde_json::to_vec(&doc).expect("json"), now);
        let a = rm.supervisor_limits.get("a").expect("caps learned");
        assert_eq!(a.memory_bytes, Some(1000));
        assert!(a.cpu_percent.is_some_and(|c| (c - 20.0).abs() < 1e-9));
        let mut t = table("a", &[(ContractRole::Provider, "b", &[1])]);
        t.entries[0].priority[0] = 0; // invalid: components start at 1
        rm.on_contract_table(&t, now);
        let mut cyc = table("x", &[(ContractRole::Client, "y", &[1])]);
        cyc.count = 1;
        rm.on_contract_table(&cyc, now);
        rm.on_contract_table(&table("y", &[(ContractRole::Client, "x", &[1])]), now);
        let out = rm.tick(now);
        assert_eq!(out.status["active_contracts"], 2);
        assert!(
            out.status["modules"]
                .as_array()
                .is_some_and(|m| m.iter().any(|m| m["name"] == "a"))
        );
    }
}
