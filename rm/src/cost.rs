//! Effective cost R_eff (paper eq. 4) and the resource cost vector C_R(t) (section 5.3).
//! Pure functions and structs fed with data: no I/O, no clock.
//!
//! Both feed the providers' value function, eq. (3),
//! V = Q − R_eff · C_R + Σ E_n e^(−(t − T(E_n))/τ), which the runtime computes
//! (`hng_runtime::contract::value::compute_value`); [`ResourceVec`] converts to and from
//! the runtime's `ResourceVec`.

use std::collections::HashMap;
use std::fmt::Display;
use std::hash::Hash;
use std::ops::{Add, AddAssign, Div, Mul};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::error::{Result, RmError};

/// A resource vector R = (CPU, memory, communication).
///
/// Units are the caller's, but for `R_eff · C_R` to be meaningful all three should be
/// fractions of what the machine can supply: CPU in cores / online cores, memory in
/// bytes / total memory, communication as a fraction of the link budget (see
/// [`ResourceVec::from_usage`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ResourceVec {
    /// CPU.
    pub cpu: f64,
    /// Memory.
    pub memory: f64,
    /// Communication load.
    pub comm: f64,
}

impl ResourceVec {
    /// All zero.
    pub const ZERO: ResourceVec = ResourceVec {
        cpu: 0.0,
        memory: 0.0,
        comm: 0.0,
    };

    /// A vector.
    #[must_use]
    pub const fn new(cpu: f64, memory: f64, comm: f64) -> Self {
        ResourceVec { cpu, memory, comm }
    }

    /// The same value in every component.
    #[must_use]
    pub const fn splat(v: f64) -> Self {
        ResourceVec {
            cpu: v,
            memory: v,
            comm: v,
        }
    }

    /// Normalised use of one module: CPU % of one core over `cpus` cores, memory bytes
    /// over total bytes, communication as given.
    #[must_use]
    pub fn from_usage(
        cpu_percent: f64,
        cpus: u32,
        mem_bytes: u64,
        mem_total: u64,
        comm: f64,
    ) -> Self {
        ResourceVec {
            cpu: cpu_percent / 100.0 / f64::from(cpus.max(1)),
            memory: if mem_total == 0 {
                0.0
            } else {
                mem_bytes as f64 / mem_total as f64
            },
            comm,
        }
    }

    /// Dot product (the `R_eff · C_R` of eq. 3).
    #[must_use]
    pub fn dot(&self, o: &ResourceVec) -> f64 {
        self.cpu * o.cpu + self.memory * o.memory + self.comm * o.comm
    }

    /// Whether every component is finite.
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.cpu.is_finite() && self.memory.is_finite() && self.comm.is_finite()
    }
}

impl From<ResourceVec> for hng_runtime::contract::value::ResourceVec {
    fn from(r: ResourceVec) -> Self {
        hng_runtime::contract::value::ResourceVec::new(r.cpu, r.memory, r.comm)
    }
}

impl From<hng_runtime::contract::value::ResourceVec> for ResourceVec {
    fn from(r: hng_runtime::contract::value::ResourceVec) -> Self {
        ResourceVec::new(r.cpu, r.mem, r.comm)
    }
}

impl Add for ResourceVec {
    type Output = ResourceVec;
    fn add(self, o: ResourceVec) -> ResourceVec {
        ResourceVec::new(self.cpu + o.cpu, self.memory + o.memory, self.comm + o.comm)
    }
}

impl AddAssign for ResourceVec {
    fn add_assign(&mut self, o: ResourceVec) {
        *self = *self + o;
    }
}

impl Mul<f64> for ResourceVec {
    type Output = ResourceVec;
    fn mul(self, k: f64) -> ResourceVec {
        ResourceVec::new(self.cpu * k, self.memory * k, self.comm * k)
    }
}

impl Div<f64> for ResourceVec {
    type Output = ResourceVec;
    fn div(self, k: f64) -> ResourceVec {
        ResourceVec::new(self.cpu / k, self.memory / k, self.comm / k)
    }
}

/// One module of the contract graph, as plain data.
#[derive(Debug, Clone, PartialEq)]
pub struct ModuleNode<K> {
    /// Module id.
    pub id: K,
    /// Its own measured use R(m).
    pub own: ResourceVec,
    /// F(m): the modules chosen as its providers. Listed twice counts once (F is a set).
    pub providers: Vec<K>,
    /// N_R(m): the number of queries m answers. Raised to the number of distinct
    /// clients that list m when lower (each of them has at least one query answered).
    pub queries_answered: u32,
}

/// Effective cost of every module, eq. (4):
///
/// R_eff(m) = R(m) + Σ_{j ∈ F(m)} R_eff(j) / N_R(j)
///
/// Fails on a provider missing from `modules`, on a duplicate id, and on a cycle (the
/// contract graph must be acyclic; a cycle would make the sum infinite), naming the
/// modules involved. Computed once per module (memoised, iterative post-order), so
/// shared providers (a DAG) cost nothing extra. O(modules + contracts).
pub fn effective_costs<K>(modules: &[ModuleNode<K>]) -> Result<HashMap<K, ResourceVec>>
where
    K: Eq + Hash + Clone + Display,
{
    let mut index: HashMap<&K, usize> = HashMap::with_capacity(modules.len());
    for (i, m) in modules.iter().enumerate() {
        if index.insert(&m.id, i).is_some() {
            return Err(RmError::DuplicateModule(m.id.to_string()));
        }
    }
    // Resolve F(m) to indices (as a set) and count distinct clients per provider.
    let mut providers: Vec<Vec<usize>> = Vec::with_capacity(modules.len());
    let mut clients = vec![0u32; modules.len()];
    for m in modules {
        let mut f: Vec<usize> = Vec::with_capacity(m.providers.len());
        for p in &m.providers {
            let j = *index.get(p).ok_or_else(|| RmError::UnknownProvider {
                module: m.id.to_string(),
                provider: p.to_string(),
            })?;
            if !f.contains(&j) {
                f.push(j);
                clients[j] = clients[j].saturating_add(1);
            }
        }
        providers.push(f);
    }
    let n_r: Vec<f64> = modules
        .iter()
        .zip(&clients)
        .map(|(m, &c)| f64::from(m.queries_answered.max(c).max(1)))
        .collect();

    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        OnStack,
        Done,
    }
    let mut mark = vec![Mark::New; modules.len()];
    let mut eff = vec![ResourceVec::ZERO; modules.len()];
    // Explicit stack of (module, next provider position).
    let mut stack: Vec<(usize, usize)> = Vec::new();
    for root in 0..modules.len() {
        if mark[root] != Mark::New {
            continue;
        }
        mark[root] = Mark::OnStack;
        stack.push((root, 0));
        while let Some(&mut (m, ref mut next)) = stack.last_mut() {
            if let Some(&j) = providers[m].get(*next) {
                *next += 1;
                match mark[j] {
                    Mark::Done => {}
                    Mark::New => {
                        mark[j] = Mark::OnStack;
                        stack.push((j, 0));
                    }
                    Mark::OnStack => {
                        let start = stack.iter().position(|&(x, _)| x == j).unwrap_or(0);
                        let mut cycle: Vec<String> = stack[start..]
                            .iter()
                            .map(|&(x, _)| modules[x].id.to_string())
                            .collect();
                        cycle.push(modules[j].id.to_string());
                        return Err(RmError::Cycle(cycle));
                    }
                }
            } else {
                let mut r = modules[m].own;
                for &j in &providers[m] {
                    r += eff[j] / n_r[j];
                }
                eff[m] = r;
                mark[m] = Mark::Done;
                stack.pop();
            }
        }
    }
    Ok(modules
        .iter()
        .zip(eff)
        .map(|(m, r)| (m.id.clone(), r))
        .collect())
}

/// Delay of a report: received − sent, 0 if the clocks say it arrived before it left.
/// Both in ns of the same clock (iceoryx2 peers on one machine share CLOCK_REALTIME /
/// CLOCK_MONOTONIC).
#[must_use]
pub fn report_delay(sent_ns: u64, received_ns: u64) -> Duration {
    Duration::from_nanos(received_ns.saturating_sub(sent_ns))
}

/// The largest report delay seen since the last [`ReportDelays::take_max`]: feed it
/// every report's sent/received timestamps, take the maximum each RM period for
/// [`ResourceObservation::max_report_delay`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReportDelays {
    max: Option<Duration>,
    count: u64,
}

impl ReportDelays {
    /// Records one report (ns of the same clock).
    pub fn record(&mut self, sent_ns: u64, received_ns: u64) {
        let d = report_delay(sent_ns, received_ns);
        self.max = Some(self.max.map_or(d, |m| m.max(d)));
        self.count = self.count.saturating_add(1);
    }

    /// Reports recorded since the last take.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The largest delay since the last call (`None` if no report), and resets.
    pub fn take_max(&mut self) -> Option<Duration> {
        self.count = 0;
        self.max.take()
    }
}

/// Which resources modules reported waiting for ("waiting for resources to answer
/// queries X"). A report that does not say which: set `cpu` and `memory`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WaitingFor {
    /// CPU.
    pub cpu: bool,
    /// Memory.
    pub memory: bool,
    /// Communication.
    pub comm: bool,
}

impl WaitingFor {
    /// Nothing waited for.
    pub const NONE: WaitingFor = WaitingFor {
        cpu: false,
        memory: false,
        comm: false,
    };

    /// CPU and memory (a report that does not say which resource).
    pub const CPU_AND_MEMORY: WaitingFor = WaitingFor {
        cpu: true,
        memory: true,
        comm: false,
    };

    /// Whether anything is waited for.
    #[must_use]
    pub fn any(&self) -> bool {
        self.cpu || self.memory || self.comm
    }
}

/// What the RM observed since the last update.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ResourceObservation {
    /// Free CPU as a fraction of the machine, [0, 1] (see
    /// [`crate::sampler::SystemSample::cpu_free`]); `None` = unknown, no signal.
    pub cpu_free: Option<f64>,
    /// Free (available) memory as a fraction of total, [0, 1]; `None` = unknown.
    pub memory_free: Option<f64>,
    /// Wait-for-resources reports received.
    pub waiting_for: WaitingFor,
    /// Largest report delay (sent → received) seen; `None` = no report.
    pub max_report_delay: Option<Duration>,
    /// Share of the machine's busy CPU that the system's own modules use, [0, 1]
    /// (Σ module CPU / (cores × (1 − `cpu_free`))); `None` = unknown, in which case a low
    /// `cpu_free` alone makes CPU scarce.
    pub own_cpu_share: Option<f64>,
}

impl ResourceObservation {
    /// An observation from a machine-wide sample plus the reports of the period.
    #[must_use]
    pub fn from_system(
        system: &crate::sampler::SystemSample,
        waiting_for: WaitingFor,
        max_report_delay: Option<Duration>,
    ) -> Self {
        ResourceObservation {
            cpu_free: system.cpu_free,
            memory_free: Some(system.mem_free()),
            waiting_for,
            max_report_delay,
            own_cpu_share: None,
        }
    }

    /// Sets [`ResourceObservation::own_cpu_share`].
    #[must_use]
    pub fn with_own_cpu_share(mut self, share: Option<f64>) -> Self {
        self.own_cpu_share = share.filter(|s| s.is_finite()).map(|s| s.clamp(0.0, 1.0));
        self
    }
}

/// Settings of the cost vector. Plain data with documented defaults.
///
/// Scale: R is a fraction of what the machine supplies (see [`ResourceVec`]), so C_R is
/// the value a module would lose by using the whole machine. At `min` (0.1) a module
/// using one core of two (R = 0.5) loses 0.05 of V, small against Q ∈ [−1, 1]: costs
/// only break ties. At `max` (1.6, four doublings) the same module loses 0.8, so under
/// real scarcity a cheaper provider wins over a better but heavier one.
#[derive(Debug, Clone, PartialEq)]
pub struct CostConfig {
    /// Lowest cost of each resource (default 0.1).
    pub min: f64,
    /// Highest cost (default 1.6).
    pub max: f64,
    /// Multiplicative raise per update while a resource is scarce (default 2: from 0.1
    /// to the maximum 1.6 in 4 updates).
    pub raise_factor: f64,
    /// Multiplicative decay per update otherwise (default 0.8, i.e. −20% per update,
    /// down to `min`). Slower than the raise so the cost does not oscillate.
    pub lower_factor: f64,
    /// CPU is scarce when the free fraction is under this (default 0.10) while the
    /// system's own modules use at least `cpu_own_share_min` of the busy CPU.
    pub cpu_free_threshold: f64,
    /// A machine busy mostly with other work (the system's modules use less than this
    /// share of the busy CPU, default 0.5) does not make CPU scarce for the system:
    /// the scheduler still gives the modules their fair share, and choosing cheaper
    /// providers would free little. Modules that really lack CPU say so in their
    /// reports (`waiting_for_resources`), which always counts. 0 = any load counts.
    pub cpu_own_share_min: f64,
    /// Memory is scarce when the free fraction is under this (default 0.10).
    pub memory_free_threshold: f64,
    /// Communication is scarce when a report took longer than this (default 20 ms).
    pub comm_delay_threshold: Duration,
}

impl Default for CostConfig {
    fn default() -> Self {
        CostConfig {
            min: 0.1,
            max: 1.6,
            raise_factor: 2.0,
            lower_factor: 0.8,
            cpu_free_threshold: 0.10,
            cpu_own_share_min: 0.5,
            memory_free_threshold: 0.10,
            comm_delay_threshold: Duration::from_millis(20),
        }
    }
}

impl CostConfig {
    fn validate(&self) -> Result<()> {
        let ok = self.min.is_finite()
            && self.min > 0.0
            && self.max.is_finite()
            && self.max >= self.min
            && self.raise_factor.is_finite()
            && self.raise_factor > 1.0
            && self.lower_factor.is_finite()
            && self.lower_factor > 0.0
            && self.lower_factor < 1.0
            && (0.0..=1.0).contains(&self.cpu_own_share_min);
        if ok {
            Ok(())
        } else {
            Err(RmError::Config(format!(
                "cost: need 0 < min <= max, raise_factor > 1, 0 < lower_factor < 1 and 0 <= cpu_own_share_min <= 1, got {self:?}"
            )))
        }
    }
}

/// Which resources are scarce after an update.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Scarcity {
    /// CPU.
    pub cpu: bool,
    /// Memory.
    pub memory: bool,
    /// Communication.
    pub comm: bool,
}

impl Scarcity {
    /// Whether any resource is scarce.
    #[must_use]
    pub fn any(&self) -> bool {
        self.cpu || self.memory || self.comm
    }
}

/// Result of one cost update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CostUpdate {
    /// The new C_R(t).
    pub costs: ResourceVec,
    /// Resources found scarce by this update.
    pub scarce: Scarcity,
    /// Whether a scarce resource was already at maximal cost.
    pub scarce_at_max: bool,
    /// Whether a resource was already at maximal cost while modules reported waiting
    /// for it, or while memory was short: real scarcity, the trigger of the degraded
    /// mode (paper 5.3: "if despite a maximal cost for the resources, it still
    /// receives this kind of reports"). A low free-CPU or a slow report alone raise
    /// the cost but never start the degraded mode.
    pub hard_at_max: bool,
}

/// The cost vector C_R(t) of section 5.3.
///
/// Per resource, at each update: scarce (free fraction under its threshold, a
/// wait-for-resources report for it, or for communication a report delay over the
/// threshold) ⇒ cost × `raise_factor` up to `max`; otherwise cost × `lower_factor` down
/// to `min`.
#[derive(Debug, Clone)]
pub struct CostController {
    config: CostConfig,
    costs: ResourceVec,
}

impl CostController {
    /// Starts at the minimum cost.
    pub fn new(config: CostConfig) -> Result<Self> {
        config.validate()?;
        Ok(CostController {
            costs: ResourceVec::splat(config.min),
            config,
        })
    }

    /// The current C_R(t).
    #[must_use]
    pub fn costs(&self) -> ResourceVec {
        self.costs
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &CostConfig {
        &self.config
    }

    /// One update.
    pub fn update(&mut self, obs: &ResourceObservation) -> CostUpdate {
        let c = &self.config;
        let under = |free: Option<f64>, thr: f64| free.is_some_and(|f| f < thr);
        let ours = obs.own_cpu_share.is_none_or(|s| s >= c.cpu_own_share_min);
        let scarce = Scarcity {
            cpu: obs.waiting_for.cpu || (ours && under(obs.cpu_free, c.cpu_free_threshold)),
            memory: obs.waiting_for.memory || under(obs.memory_free, c.memory_free_threshold),
            comm: obs.waiting_for.comm
                || obs
                    .max_report_delay
                    .is_some_and(|d| d > c.comm_delay_threshold),
        };
        let at_max = |v: f64| v >= c.max;
        let scarce_at_max = (scarce.cpu && at_max(self.costs.cpu))
            || (scarce.memory && at_max(self.costs.memory))
            || (scarce.comm && at_max(self.costs.comm));
        let hard_at_max = (obs.waiting_for.cpu && at_max(self.costs.cpu))
            || ((obs.waiting_for.memory || scarce.memory) && at_max(self.costs.memory))
            || (obs.waiting_for.comm && at_max(self.costs.comm));
        let step = |v: f64, s: bool| {
            if s {
                (v * c.raise_factor).min(c.max)
            } else {
                (v * c.lower_factor).max(c.min)
            }
        };
        self.costs = ResourceVec::new(
            step(self.costs.cpu, scarce.cpu),
            step(self.costs.memory, scarce.memory),
            step(self.costs.comm, scarce.comm),
        );
        CostUpdate {
            costs: self.costs,
            scarce,
            scarce_at_max,
            hard_at_max,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(id: &str, cpu: f64, mem: f64, providers: &[&str], nr: u32) -> ModuleNode<String> {
        ModuleNode {
            id: id.to_owned(),
            own: ResourceVec::new(cpu, mem, 0.0),
            providers: providers.iter().map(|s| (*s).to_owned()).collect(),
            queries_answered: nr,
        }
    }

    fn close(a: ResourceVec, b: ResourceVec) -> bool {
        (a.cpu - b.cpu).abs() < 1e-12
            && (a.memory - b.memory).abs() < 1e-12
            && (a.comm - b.comm).abs() < 1e-12
    }

    /// Test (d): a hand-built tree, eq. (4) worked by hand.
    ///
    /// ```text
    /// manager -> planner -> localisation -> lidar
    ///         -> safety  -> lidar
    /// planner -> map
    /// ```
    /// N_R: lidar answers 2 queries, others 1 (map 3: it also serves clients outside
    /// this tree).
    #[test]
    fn effective_cost_matches_eq4_by_hand() {
        let g = vec![
            node("manager", 0.01, 0.02, &["planner", "safety"], 1),
            node("planner", 0.10, 0.05, &["localisation", "map"], 1),
            node("safety", 0.02, 0.01, &["lidar"], 1),
            node("localisation", 0.20, 0.10, &["lidar"], 1),
            node("lidar", 0.08, 0.04, &[], 2),
            node("map", 0.30, 0.30, &[], 3),
        ];
        let eff = effective_costs(&g).expect("acyclic");
        // By hand:
        // lidar        = (0.08, 0.04)
        // map          = (0.30, 0.30)
        // localisation = (0.20, 0.10) + lidar/2 = (0.24, 0.12)
        // safety       = (0.02, 0.01) + lidar/2 = (0.06, 0.03)
        // planner      = (0.10, 0.05) + localisation/1 + map/3 = (0.44, 0.27)
        // manager      = (0.01, 0.02) + planner/1 + safety/1 = (0.51, 0.32)
        let want = [
            ("lidar", 0.08, 0.04),
            ("map", 0.30, 0.30),
            ("localisation", 0.24, 0.12),
            ("safety", 0.06, 0.03),
            ("planner", 0.44, 0.27),
            ("manager", 0.51, 0.32),
        ];
        for (id, cpu, mem) in want {
            let got = eff[id];
            assert!(
                close(got, ResourceVec::new(cpu, mem, 0.0)),
                "{id}: got {got:?}, want ({cpu}, {mem})"
            );
        }
    }

    #[test]
    fn n_r_is_at_least_the_number_of_clients() {
        // lidar says it answers 0 queries but two clients list it: N_R = 2.
        let g = vec![
            node("a", 0.0, 0.0, &["lidar", "lidar"], 1),
            node("b", 0.0, 0.0, &["lidar"], 1),
            node("lidar", 1.0, 0.0, &[], 0),
        ];
        let eff = effective_costs(&g).expect("acyclic");
        assert!((eff["a"].cpu - 0.5).abs() < 1e-12);
        assert!((eff["b"].cpu - 0.5).abs() < 1e-12);
    }

    #[test]
    fn cycles_unknown_and_duplicates_are_errors() {
        let g = vec![
            node("a", 0.0, 0.0, &["b"], 1),
            node("b", 0.0, 0.0, &["c"], 1),
            node("c", 0.0, 0.0, &["a"], 1),
        ];
        match effective_costs(&g) {
            Err(RmError::Cycle(c)) => {
                assert_eq!(c.first(), c.last());
                assert_eq!(c.len(), 4, "{c:?}");
            }
            other => panic!("expected a cycle error, got {other:?}"),
        }
        let selfloop = vec![node("a", 0.0, 0.0, &["a"], 1)];
        assert!(matches!(effective_costs(&selfloop), Err(RmError::Cycle(_))));
        let unknown = vec![node("a", 0.0, 0.0, &["ghost"], 1)];
        let err = effective_costs(&unknown).expect_err("unknown provider");
        assert!(err.to_string().contains("ghost"), "{err}");
        let dup = vec![node("a", 0.0, 0.0, &[], 1), node("a", 0.0, 0.0, &[], 1)];
        assert!(matches!(
            effective_costs(&dup),
            Err(RmError::DuplicateModule(_))
        ));
    }

    #[test]
    fn deep_chain_does_not_overflow_the_stack() {
        let n = 100_000;
        let g: Vec<ModuleNode<usize>> = (0..n)
            .map(|i| ModuleNode {
                id: i,
                own: ResourceVec::new(1.0, 0.0, 0.0),
                providers: if i + 1 < n { vec![i + 1] } else { vec![] },
                queries_answered: 1,
            })
            .collect();
        let eff = effective_costs(&g).expect("acyclic");
        assert!((eff[&0].cpu - n as f64).abs() < 1e-6);
    }

    #[test]
    fn cost_rises_on_scarcity_and_falls_to_min() {
        let mut cc = CostController::new(CostConfig {
            min: 1.0,
            max: 16.0,
            ..CostConfig::default()
        })
        .expect("valid config");
        let scarce = ResourceObservation {
            cpu_free: Some(0.02),
            memory_free: Some(0.5),
            ..Default::default()
        };
        let mut u = cc.update(&scarce);
        assert_eq!(u.costs.cpu, 2.0);
        assert_eq!(u.costs.memory, 1.0);
        assert!(!u.scarce_at_max);
        for _ in 0..3 {
            u = cc.update(&scarce);
        }
        assert_eq!(u.costs.cpu, 16.0);
        assert!(
            !u.scarce_at_max,
            "reached max on this update, was not at max before"
        );
        u = cc.update(&scarce);
        assert!(u.scarce_at_max);
        assert!(!u.hard_at_max, "a low free CPU alone is not real scarcity");
        assert_eq!(u.costs.cpu, 16.0);
        // A wait-for-resources report alone also keeps it at max.
        let waiting = ResourceObservation {
            cpu_free: Some(0.9),
            waiting_for: WaitingFor::CPU_AND_MEMORY,
            ..Default::default()
        };
        let u2 = cc.update(&waiting);
        assert!(u2.scarce_at_max && u2.hard_at_max);
        // Recovery: decays to the minimum and stays there.
        let calm = ResourceObservation {
            cpu_free: Some(0.9),
            memory_free: Some(0.9),
            max_report_delay: Some(Duration::from_millis(1)),
            ..Default::default()
        };
        for _ in 0..100 {
            u = cc.update(&calm);
        }
        assert_eq!(u.costs, ResourceVec::splat(1.0));
        // Slow reports raise the communication cost only.
        let slow = ResourceObservation {
            max_report_delay: Some(report_delay(1_000, 1_000 + 50_000_000)),
            ..calm
        };
        u = cc.update(&slow);
        assert_eq!(u.costs, ResourceVec::new(1.0, 1.0, 2.0));
        assert_eq!(report_delay(10, 5), Duration::ZERO);
        let mut delays = ReportDelays::default();
        assert_eq!(delays.take_max(), None);
        delays.record(0, 5_000_000);
        delays.record(100, 30_000_100);
        delays.record(7, 3);
        assert_eq!(delays.count(), 3);
        assert_eq!(delays.take_max(), Some(Duration::from_millis(30)));
        assert_eq!(delays.take_max(), None);
    }

    #[test]
    fn default_scale_keeps_v_dominated_by_q_until_real_scarcity() {
        let c = CostConfig::default();
        // A module using one core of two (R = 0.5): at min it loses at most 0.05.
        let r = ResourceVec::new(0.5, 0.05, 0.01);
        assert!(r.dot(&ResourceVec::splat(c.min)) < 0.1);
        // At max the same module loses most of a Q range of 1.
        assert!(r.dot(&ResourceVec::splat(c.max)) > 0.8);
        let mut cc = CostController::new(c).expect("valid config");
        // A machine busy with other work (the system uses 20% of the busy CPU): free
        // CPU under the threshold but not scarce for the system.
        let external = ResourceObservation {
            cpu_free: Some(0.0),
            memory_free: Some(0.6),
            ..Default::default()
        }
        .with_own_cpu_share(Some(0.2));
        for _ in 0..20 {
            let u = cc.update(&external);
            assert!(!u.scarce.any() && !u.hard_at_max, "{u:?}");
        }
        assert_eq!(cc.costs(), ResourceVec::splat(0.1));
        // The system itself fills the machine: the CPU cost rises to max, but only a
        // wait report at max cost is real scarcity.
        let own = external.with_own_cpu_share(Some(0.9));
        let mut last = cc.update(&own);
        for _ in 0..10 {
            last = cc.update(&own);
            assert!(!last.hard_at_max);
        }
        assert!((last.costs.cpu - 1.6).abs() < 1e-12 && last.scarce_at_max);
        let starving = ResourceObservation {
            waiting_for: WaitingFor::CPU_AND_MEMORY,
            ..external
        };
        assert!(cc.update(&starving).hard_at_max);
        // Memory short at max cost is real scarcity without any report.
        let mut mc = CostController::new(CostConfig::default()).expect("valid config");
        let low_mem = ResourceObservation {
            cpu_free: Some(0.5),
            memory_free: Some(0.02),
            ..Default::default()
        };
        let hard: Vec<bool> = (0..6).map(|_| mc.update(&low_mem).hard_at_max).collect();
        assert_eq!(hard, [false, false, false, false, true, true]);
    }

    #[test]
    fn bad_cost_config_is_refused() {
        let bad = CostConfig {
            raise_factor: 0.5,
            ..Default::default()
        };
        assert!(CostController::new(bad).is_err());
        let bad = CostConfig {
            cpu_own_share_min: 1.5,
            ..Default::default()
        };
        assert!(CostController::new(bad).is_err());
    }
}
