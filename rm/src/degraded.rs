//! Degraded mode (section 5.3): when resources stay scarce although their cost is
//! maximal, publish a minimum priority; queries less important than it are not served.
//!
//! Priorities are `Ord`, smaller = more important (for the paper's dotted priorities,
//! lexicographic: 1.2.5 < 1.3.2, and a parent 1.2 < its sub-contract 1.2.1). Which
//! priorities a published minimum admits is the [`Admission`] trait: plain `p <= min`
//! by default, and for dotted priorities (`Vec<u32>` here, hng-runtime's `Priority`)
//! the runtime's rule: `p` cut to the depth of `min` is `<= min`, so the sub-contracts
//! (needs) of an admitted contract stay admitted (`min = 2` admits 2.2.1.1).
//!
//! Raising the bar (one step): among the active contracts still admitted, pick the
//! published minimum, chosen from their own priorities, that admits the most of them
//! while cutting at least one and re-admitting none already cut; ties go to the most
//! general (smallest) bar. So each step stops the smallest least-important piece of
//! work that can be stopped alone (a whole subtree under the runtime's rule), least
//! important first. Lowering restores the previous bars in reverse order; when all are
//! restored the RM leaves the degraded mode. A step costs O(n²) admission checks for n
//! active contracts and happens at most once per `step_after` updates.

use crate::cost::{CostConfig, CostController, CostUpdate, ResourceObservation, ResourceVec};
use crate::error::{Result, RmError};

/// How a published minimum priority admits a query's priority.
pub trait Admission: Ord + Clone {
    /// Whether a query of priority `self` is served when `min` is published.
    /// Default: `self <= min`.
    fn admitted_by(&self, min: &Self) -> bool {
        self <= min
    }
}

impl Admission for u32 {}
impl Admission for u64 {}
impl Admission for i64 {}

/// Dotted priorities with the runtime's rule: cut `self` to the depth of `min`, then
/// compare.
impl Admission for Vec<u32> {
    fn admitted_by(&self, min: &Self) -> bool {
        let cut = self.len().min(min.len());
        self[..cut] <= min[..]
    }
}

impl Admission for hng_runtime::contract::Priority {
    fn admitted_by(&self, min: &Self) -> bool {
        hng_runtime::contract::Priority::admitted_by(self, min)
    }
}

/// Which queries may be served.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServeBar<P> {
    /// Every query (normal mode).
    All,
    /// Only queries this minimum priority admits ([`Admission::admitted_by`]): the
    /// minimum priority published in degraded mode.
    AtMost(P),
    /// No query at all (only with [`DegradedConfig::allow_full_stop`]).
    Nothing,
}

impl<P: Admission> ServeBar<P> {
    /// Whether a query of this priority may be served.
    pub fn serves(&self, p: &P) -> bool {
        match self {
            ServeBar::All => true,
            ServeBar::AtMost(bar) => p.admitted_by(bar),
            ServeBar::Nothing => false,
        }
    }

    /// Whether this is degraded mode.
    pub fn is_degraded(&self) -> bool {
        !matches!(self, ServeBar::All)
    }
}

/// Settings of the degraded mode, counted in updates of the RM (at 10 Hz, 3 updates
/// = 0.3 s). Plain data with documented defaults.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DegradedConfig {
    /// Consecutive updates under pressure at maximal cost before entering the degraded
    /// mode (default 3).
    pub enter_after: u32,
    /// While degraded, consecutive updates still under pressure before cutting the next
    /// level (default 3: gives the stopped work time to free its resources).
    pub step_after: u32,
    /// Consecutive updates without pressure before restoring one level (default 10:
    /// slower than cutting, so the bar does not oscillate).
    pub recover_after: u32,
    /// Whether the last, most important level may be cut too (a global stop, which the
    /// paper allows). Default false: the most important active work keeps running.
    pub allow_full_stop: bool,
}

impl Default for DegradedConfig {
    fn default() -> Self {
        DegradedConfig {
            enter_after: 3,
            step_after: 3,
            recover_after: 10,
            allow_full_stop: false,
        }
    }
}

/// What an update changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BarChange {
    /// Nothing.
    Unchanged,
    /// One more level cut (or degraded mode entered).
    Raised,
    /// One level restored (or degraded mode left).
    Lowered,
}

/// The degraded-mode state machine.
#[derive(Debug, Clone)]
pub struct DegradedMode<P> {
    config: DegradedConfig,
    bar: ServeBar<P>,
    previous: Vec<ServeBar<P>>,
    pressure_run: u32,
    calm_run: u32,
}

impl<P: Admission> DegradedMode<P> {
    /// Starts in normal mode.
    pub fn new(config: DegradedConfig) -> Result<Self> {
        if config.enter_after == 0 || config.step_after == 0 || config.recover_after == 0 {
            return Err(RmError::Config(format!(
                "degraded mode: enter_after, step_after and recover_after must be >= 1, got {config:?}"
            )));
        }
        Ok(DegradedMode {
            config,
            bar: ServeBar::All,
            previous: Vec::new(),
            pressure_run: 0,
            calm_run: 0,
        })
    }

    /// The current bar.
    pub fn bar(&self) -> &ServeBar<P> {
        &self.bar
    }

    /// Whether degraded mode is active.
    pub fn is_degraded(&self) -> bool {
        self.bar.is_degraded()
    }

    /// One update. `pressure`: in normal mode, resources are scarce (or modules wait for
    /// resources) although the cost is at its maximum; in degraded mode, resources are
    /// scarce or wait-for-resources reports keep arriving. `active`: priorities of the
    /// active contracts (served or not; duplicates and any order are fine).
    pub fn update(&mut self, pressure: bool, active: &[P]) -> BarChange {
        if pressure {
            self.calm_run = 0;
            self.pressure_run = self.pressure_run.saturating_add(1);
            let needed = if self.bar.is_degraded() {
                self.config.step_after
            } else {
                self.config.enter_after
            };
            if self.pressure_run >= needed && self.raise(active) {
                self.pressure_run = 0;
                return BarChange::Raised;
            }
            BarChange::Unchanged
        } else {
            self.pressure_run = 0;
            if !self.bar.is_degraded() {
                return BarChange::Unchanged;
            }
            self.calm_run = self.calm_run.saturating_add(1);
            if self.calm_run >= self.config.recover_after {
                self.calm_run = 0;
                self.bar = self.previous.pop().unwrap_or(ServeBar::All);
                return BarChange::Lowered;
            }
            BarChange::Unchanged
        }
    }

    /// One step up (see the module documentation). Returns false when nothing can be
    /// cut.
    fn raise(&mut self, active: &[P]) -> bool {
        let served = active.iter().filter(|p| self.bar.serves(p)).count();
        if served == 0 {
            return false;
        }
        // (contracts kept, bar)
        let mut best: Option<(usize, &P)> = None;
        for m in active.iter().filter(|p| self.bar.serves(p)) {
            let mut kept = 0usize;
            let mut readmits = false;
            for p in active {
                if p.admitted_by(m) {
                    if !self.bar.serves(p) {
                        readmits = true;
                        break;
                    }
                    kept += 1;
                }
            }
            if readmits || kept >= served {
                continue;
            }
            let better = match best {
                None => true,
                Some((k, b)) => kept > k || (kept == k && m < b),
            };
            if better {
                best = Some((kept, m));
            }
        }
        let new_bar = match best {
            Some((_, m)) => ServeBar::AtMost(m.clone()),
            None if self.config.allow_full_stop => ServeBar::Nothing,
            None => return false,
        };
        let old = std::mem::replace(&mut self.bar, new_bar);
        self.previous.push(old);
        true
    }
}

/// Output of one [`RmCore::update`].
#[derive(Debug, Clone, PartialEq)]
pub struct RmDecision<P> {
    /// C_R(t) to publish.
    pub costs: ResourceVec,
    /// The cost update details.
    pub cost_update: CostUpdate,
    /// The bar to publish (the minimum priority in degraded mode).
    pub bar: ServeBar<P>,
    /// What changed in the bar.
    pub change: BarChange,
}

/// The decision part of a resource manager: cost vector plus degraded mode, fed with
/// observations. No I/O, no clock: the RM process feeds it each period.
#[derive(Debug, Clone)]
pub struct RmCore<P> {
    costs: CostController,
    degraded: DegradedMode<P>,
}

impl<P: Admission> RmCore<P> {
    /// A core in normal mode at minimal costs.
    pub fn new(cost: CostConfig, degraded: DegradedConfig) -> Result<Self> {
        Ok(RmCore {
            costs: CostController::new(cost)?,
            degraded: DegradedMode::new(degraded)?,
        })
    }

    /// One period: updates C_R(t), then the degraded mode. Pressure is real scarcity
    /// in normal mode ([`crate::cost::CostUpdate::hard_at_max`]: wait-for-resources
    /// reports, or short memory, at maximal cost) and, once degraded, "wait reports or
    /// no more available resources" (paper 5.3): a wait report, scarce CPU or scarce
    /// memory. Slow reports (communication) raise their cost only.
    pub fn update(&mut self, obs: &ResourceObservation, active: &[P]) -> RmDecision<P> {
        let u = self.costs.update(obs);
        let pressure = if self.degraded.is_degraded() {
            obs.waiting_for.any() || u.scarce.cpu || u.scarce.memory
        } else {
            u.hard_at_max
        };
        let change = self.degraded.update(pressure, active);
        RmDecision {
            costs: u.costs,
            cost_update: u,
            bar: self.degraded.bar().clone(),
            change,
        }
    }

    /// The cost controller.
    pub fn costs(&self) -> &CostController {
        &self.costs
    }

    /// The degraded mode.
    pub fn degraded(&self) -> &DegradedMode<P> {
        &self.degraded
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cost::WaitingFor;

    fn p(s: &str) -> Vec<u32> {
        s.split('.').filter_map(|x| x.parse().ok()).collect()
    }

    #[test]
    fn dotted_priorities_order() {
        assert!(p("1.2.5") < p("1.3.2"));
        assert!(p("1.2") < p("1.2.1"));
        let bar = ServeBar::AtMost(p("1.2"));
        assert!(bar.serves(&p("1.1.9")));
        assert!(bar.serves(&p("1.2")));
        assert!(
            bar.serves(&p("1.2.1")),
            "needs of an admitted contract stay admitted"
        );
        assert!(!bar.serves(&p("1.3")));
        assert!(!bar.serves(&p("2")));
    }

    /// Test (e): degraded mode stops the least important first and recovers.
    ///
    /// Contract tree: objectives 1, 2, 3; 1 needs 1.1 and 1.2, 1.2 needs 1.2.1, 2
    /// needs 2.1, 3 needs 3.1. Under the runtime's admission rule the needs of an
    /// admitted contract stay admitted, so the work is stopped by subtrees: 3.*, then
    /// 2.*, then 1.2.*; 1 and its need 1.1 are never cut (no full stop).
    #[test]
    fn degraded_mode_cuts_least_important_first_and_recovers() {
        let cfg = DegradedConfig {
            enter_after: 2,
            step_after: 2,
            recover_after: 3,
            allow_full_stop: false,
        };
        let mut rm: RmCore<Vec<u32>> =
            RmCore::new(CostConfig::default(), cfg.clone()).expect("valid config");
        let active: Vec<Vec<u32>> = ["1", "1.1", "1.2", "1.2.1", "2", "2.1", "3", "3.1"]
            .into_iter()
            .map(p)
            .collect();
        // A machine without free CPU but with no module waiting is not real scarcity:
        // the cost rises, the degraded mode never starts.
        let busy = ResourceObservation {
            cpu_free: Some(0.01),
            memory_free: Some(0.5),
            ..Default::default()
        };
        let mut other: RmCore<Vec<u32>> =
            RmCore::new(CostConfig::default(), cfg).expect("valid config");
        for _ in 0..30 {
            let d = other.update(&busy, &active);
            assert_eq!(d.bar, ServeBar::All);
        }
        assert_eq!(other.costs().costs().cpu, CostConfig::default().max);
        let scarce = ResourceObservation {
            waiting_for: WaitingFor::CPU_AND_MEMORY,
            ..busy
        };
        let calm = ResourceObservation {
            cpu_free: Some(0.8),
            memory_free: Some(0.8),
            ..Default::default()
        };
        let served = |bar: &ServeBar<Vec<u32>>| -> Vec<String> {
            active
                .iter()
                .filter(|x| bar.serves(x))
                .map(|x| x.iter().map(u32::to_string).collect::<Vec<_>>().join("."))
                .collect()
        };

        // Cost climbs 0.1 -> 1.6 in 4 updates; scarce_at_max from the 5th; enter after 2.
        let mut bars = Vec::new();
        for _ in 0..6 {
            let d = rm.update(&scarce, &active);
            bars.push(d.bar.clone());
        }
        assert!(bars[..5].iter().all(|b| *b == ServeBar::All), "{bars:?}");
        // Entered: objective 3 and its need cut first; published minimum "2".
        assert_eq!(bars[5], ServeBar::AtMost(p("2")));
        assert_eq!(served(&bars[5]), ["1", "1.1", "1.2", "1.2.1", "2", "2.1"]);

        // Still scarce: one more piece every 2 updates, least important first.
        let mut cuts = Vec::new();
        for _ in 0..10 {
            let d = rm.update(&scarce, &active);
            if d.change == BarChange::Raised {
                cuts.push((d.bar.clone(), served(&d.bar)));
            }
        }
        assert_eq!(cuts.len(), 2, "{cuts:?}");
        assert_eq!(cuts[0].0, ServeBar::AtMost(p("1")));
        assert_eq!(cuts[0].1, ["1", "1.1", "1.2", "1.2.1"]);
        assert_eq!(cuts[1].0, ServeBar::AtMost(p("1.1")));
        assert_eq!(cuts[1].1, ["1", "1.1"]);
        // 1.1 is a need of 1: it cannot be cut while 1 runs, and there is no full stop.
        assert_eq!(rm.degraded().bar(), &ServeBar::AtMost(p("1.1")));

        // A wait-for-resources report while degraded keeps the pressure on.
        let waiting = ResourceObservation {
            waiting_for: WaitingFor::CPU_AND_MEMORY,
            ..calm
        };
        assert_eq!(rm.update(&waiting, &active).change, BarChange::Unchanged);

        // Recovery: one step back every 3 calm updates, in reverse order, then normal.
        let mut restored = Vec::new();
        for _ in 0..20 {
            let d = rm.update(&calm, &active);
            if d.change == BarChange::Lowered {
                restored.push(d.bar.clone());
            }
        }
        assert_eq!(
            restored,
            vec![
                ServeBar::AtMost(p("1")),
                ServeBar::AtMost(p("2")),
                ServeBar::All,
            ]
        );
        assert!(!rm.degraded().is_degraded());
    }

    #[test]
    fn plain_order_cuts_one_level_per_step() {
        // With plain `<=` admission (u32 here), each step cuts exactly the least
        // important remaining level.
        let mut d: DegradedMode<u32> = DegradedMode::new(DegradedConfig {
            enter_after: 1,
            step_after: 1,
            recover_after: 1,
            allow_full_stop: false,
        })
        .expect("valid");
        let active = [5, 1, 3, 3, 4, 2];
        let mut bars = Vec::new();
        while d.update(true, &active) == BarChange::Raised {
            bars.push(d.bar().clone());
        }
        assert_eq!(
            bars,
            vec![
                ServeBar::AtMost(4),
                ServeBar::AtMost(3),
                ServeBar::AtMost(2),
                ServeBar::AtMost(1),
            ]
        );
    }

    #[test]
    fn runtime_priority_admission_is_used() {
        use hng_runtime::contract::Priority;
        let two = Priority::new(&[2]).expect("valid priority");
        let deep = Priority::new(&[2, 2, 1, 1]).expect("valid priority");
        let three = Priority::new(&[3]).expect("valid priority");
        let bar = ServeBar::AtMost(two);
        assert!(bar.serves(&deep));
        assert!(!bar.serves(&three));
        // Same rule as the Vec<u32> mirror.
        assert!(p("2.2.1.1").admitted_by(&p("2")));
        assert!(!p("2.2").admitted_by(&p("2.1")));
        assert!(p("1.9").admitted_by(&p("2.1")));
    }

    #[test]
    fn calm_interrupts_pressure_run_and_full_stop_is_opt_in() {
        let mut d: DegradedMode<u32> = DegradedMode::new(DegradedConfig {
            enter_after: 2,
            step_after: 1,
            recover_after: 1,
            allow_full_stop: true,
        })
        .expect("valid");
        let active = [3, 1, 2];
        assert_eq!(d.update(true, &active), BarChange::Unchanged);
        assert_eq!(d.update(false, &active), BarChange::Unchanged);
        assert_eq!(d.update(true, &active), BarChange::Unchanged);
        assert_eq!(d.update(true, &active), BarChange::Raised);
        assert_eq!(d.bar(), &ServeBar::AtMost(2));
        assert_eq!(d.update(true, &active), BarChange::Raised);
        assert_eq!(d.bar(), &ServeBar::AtMost(1));
        assert_eq!(d.update(true, &active), BarChange::Raised);
        assert_eq!(d.bar(), &ServeBar::Nothing);
        assert_eq!(d.update(true, &active), BarChange::Unchanged);
        assert_eq!(d.update(false, &active), BarChange::Lowered);
        assert_eq!(d.bar(), &ServeBar::AtMost(1));
        // No active contract: nothing to cut, stays normal.
        let mut e: DegradedMode<u32> = DegradedMode::new(DegradedConfig::default()).expect("valid");
        for _ in 0..10 {
            assert_eq!(e.update(true, &[]), BarChange::Unchanged);
        }
        assert!(!e.is_degraded());
        assert!(
            DegradedMode::<u32>::new(DegradedConfig {
                enter_after: 0,
                ..Default::default()
            })
            .is_err()
        );
    }
}
