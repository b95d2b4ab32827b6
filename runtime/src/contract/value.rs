//! The value function of a provider (paper, eq. (3)), client feedback, and the
//! choice of the best proposal.

use std::collections::VecDeque;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::ModuleId;

/// A vector over the resources of the system (paper, 4.1 and 5.3): CPU,
/// memory and communication load. Used both for the effective consumption
/// `R_eff` of a module and for the cost `C_R` published by the Resource Manager.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ResourceVec {
    /// CPU share (any consistent unit, e.g. fraction of one core).
    pub cpu: f64,
    /// Memory (any consistent unit, e.g. fraction of the RAM of the machine).
    pub mem: f64,
    /// Communication load (e.g. fraction of the channel budget).
    pub comm: f64,
}

impl ResourceVec {
    /// Builds a vector.
    pub const fn new(cpu: f64, mem: f64, comm: f64) -> Self {
        Self { cpu, mem, comm }
    }

    /// Dot product `self · other`.
    pub fn dot(&self, other: &ResourceVec) -> f64 {
        self.cpu * other.cpu + self.mem * other.mem + self.comm * other.comm
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.cpu.is_finite() && self.mem.is_finite() && self.comm.is_finite()
    }

    /// Validated copy: `None` if a component is NaN or infinite, negative
    /// components clamped to 0 (a consumption or a cost is never negative).
    pub fn sanitized(&self) -> Option<ResourceVec> {
        if !self.is_finite() {
            return None;
        }
        Some(ResourceVec::new(
            self.cpu.max(0.0),
            self.mem.max(0.0),
            self.comm.max(0.0),
        ))
    }
}

/// Why a module has no value (cannot propose).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Unavailable {
    /// Aptitude `f = 0`: the module says it cannot do its task.
    #[error("aptitude f = 0: the module cannot do its task")]
    NotApt,
    /// The self-evaluated quality `Q` is NaN: treated as invalid (as `f = 0`).
    #[error("quality Q is NaN; the module is treated as unable (f = 0)")]
    InvalidQuality,
    /// `R_eff` or `C_R` has a NaN or infinite component.
    #[error("resource usage or cost is not finite")]
    InvalidResources,
}

/// The inputs of eq. (3) that the module and its Resource Manager report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValueInputs {
    /// Aptitude `f ∈ {0, 1}`.
    pub aptitude: bool,
    /// Working quality `Q ∈ [-1, 1]` (clamped; NaN makes the module unavailable;
    /// a module that cannot evaluate itself reports 0).
    pub quality: f64,
    /// Effective resource consumption `R_eff` (paper, eq. (4), from the RM).
    pub r_eff: ResourceVec,
    /// Cost of the resources `C_R` (from the RM).
    pub cost: ResourceVec,
}

impl Default for ValueInputs {
    fn default() -> Self {
        Self {
            aptitude: true,
            quality: 0.0,
            r_eff: ResourceVec::default(),
            cost: ResourceVec::default(),
        }
    }
}

/// Eq. (3): `V = Q − R_eff · C_R + Σ E_n · exp(−(t − T_n)/τ)`.
///
/// `Q` is clamped to `[-1, 1]`; negative resource components are clamped to 0.
///
/// # Errors
/// [`Unavailable`] when `f = 0`, `Q` is NaN, or a resource component is not finite.
pub fn compute_value(
    inputs: &ValueInputs,
    feedback: &FeedbackLog,
    now: Duration,
) -> Result<f64, Unavailable> {
    if !inputs.aptitude {
        return Err(Unavailable::NotApt);
    }
    if inputs.quality.is_nan() {
        return Err(Unavailable::InvalidQuality);
    }
    let q = inputs.quality.clamp(-1.0, 1.0);
    let r = inputs
        .r_eff
        .sanitized()
        .ok_or(Unavailable::InvalidResources)?;
    let c = inputs
        .cost
        .sanitized()
        .ok_or(Unavailable::InvalidResources)?;
    let v = q - r.dot(&c) + feedback.sum(now);
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Unavailable::InvalidResources)
    }
}

/// Evaluations `E_n ∈ [-1, 1]` received from clients, with their time `T_n`,
/// and the characteristic validity time `τ` (paper, 4.2).
///
/// Entries whose weight `|E_n|·exp(−(t−T_n)/τ)` has fallen below
/// [`FeedbackLog::NEGLIGIBLE`] are pruned; at most [`FeedbackLog::MAX_ENTRIES`]
/// are kept (the oldest is dropped first), so memory is bounded whatever the
/// clients send.
#[derive(Debug, Clone)]
pub struct FeedbackLog {
    tau: Duration,
    entries: VecDeque<(f64, Duration)>,
}

impl FeedbackLog {
    /// Weight below which an evaluation is forgotten.
    pub const NEGLIGIBLE: f64 = 1e-4;
    /// Maximum number of evaluations kept.
    pub const MAX_ENTRIES: usize = 1024;

    /// An empty log with validity time `tau` (a zero `tau` is raised to 1 ms).
    pub fn new(tau: Duration) -> Self {
        Self {
            tau: tau.max(Duration::from_millis(1)),
            entries: VecDeque::new(),
        }
    }

    /// The validity time `τ`.
    pub fn tau(&self) -> Duration {
        self.tau
    }

    /// Records evaluation `e` at time `at`. `e` is clamped to `[-1, 1]`; a NaN
    /// `e` is rejected (returns `false`).
    pub fn record(&mut self, e: f64, at: Duration) -> bool {
        if e.is_nan() {
            return false;
        }
        if self.entries.len() >= Self::MAX_ENTRIES {
            self.entries.pop_front();
        }
        self.entries.push_back((e.clamp(-1.0, 1.0), at));
        true
    }

    fn weight(&self, at: Duration, now: Duration) -> f64 {
        // Evaluations stamped in the future count as fresh (weight 1).
        let age = now.saturating_sub(at).as_secs_f64();
        (-age / self.tau.as_secs_f64()).exp()
    }

    /// `Σ E_n · exp(−(now − T_n)/τ)`.
    pub fn sum(&self, now: Duration) -> f64 {
        self.entries
            .iter()
            .map(|&(e, at)| e * self.weight(at, now))
            .sum()
    }

    /// Weighted mean of the evaluations (weights `exp(−(now − T_n)/τ)`), in
    /// `[-1, 1]`; `None` when nothing significant remains. This is what a
    /// module forwards to its providers (paper, 4.2: the evaluation a module
    /// sends follows the one it receives).
    pub fn mean(&self, now: Duration) -> Option<f64> {
        let (mut num, mut den) = (0.0, 0.0);
        for &(e, at) in &self.entries {
            let w = self.weight(at, now);
            num += e * w;
            den += w;
        }
        (den > Self::NEGLIGIBLE).then(|| (num / den).clamp(-1.0, 1.0))
    }

    /// Forgets the evaluations whose weight is negligible at `now`.
    pub fn prune(&mut self, now: Duration) {
        let tau = self.tau.as_secs_f64();
        self.entries.retain(|&(e, at)| {
            let age = now.saturating_sub(at).as_secs_f64();
            e.abs() * (-age / tau).exp() >= Self::NEGLIGIBLE
        });
    }

    /// Number of evaluations kept.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when no evaluation is kept.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// One provider's answer to a query, as a client compares them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Proposal {
    /// Who proposes.
    pub provider: ModuleId,
    /// Its value `V` (eq. (3)).
    pub value: f64,
    /// The data channel the provided data will come on.
    pub channel: String,
}

/// Decides one query: the proposal with the greatest value `V`; ties go to
/// the smallest [`ModuleId`]; proposals with a non-finite value are ignored.
/// `O(N)`, no allocation. This is the `decide_N` benchmark.
pub fn select_best(proposals: &[Proposal]) -> Option<&Proposal> {
    best_of(proposals.iter())
}

/// [`select_best`] over any iterator of proposals.
pub fn best_of<'a, I: IntoIterator<Item = &'a Proposal>>(proposals: I) -> Option<&'a Proposal> {
    let mut best: Option<&Proposal> = None;
    for p in proposals {
        if !p.value.is_finite() {
            continue;
        }
        best = match best {
            Some(b) if !better(p, b) => Some(b),
            _ => Some(p),
        };
    }
    best
}

/// True when `a` beats `b`: higher value, or equal value and smaller id.
pub(crate) fn better(a: &Proposal, b: &Proposal) -> bool {
    a.value > b.value || (a.value == b.value && a.provider < b.provider)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // Tests may unwrap.
mod tests {
    use super::*;
    use crate::contract::tests::ms;

    #[test]
    fn contract_value_formula() {
        let mut log = FeedbackLog::new(Duration::from_secs(2));
        let inputs = ValueInputs {
            aptitude: true,
            quality: 0.8,
            r_eff: ResourceVec::new(0.5, 0.2, 0.1),
            cost: ResourceVec::new(0.4, 1.0, 2.0),
        };
        let v0 = compute_value(&inputs, &log, ms(0)).unwrap();
        assert!((v0 - (0.8 - (0.2 + 0.2 + 0.2))).abs() < 1e-12);
        log.record(-0.5, ms(0));
        log.record(1.0, ms(1000));
        let t = ms(3000);
        let expect = 0.8 - 0.6 + (-0.5 * (-1.5f64).exp()) + (-1.0f64).exp();
        assert!((compute_value(&inputs, &log, t).unwrap() - expect).abs() < 1e-12);
    }

    #[test]
    fn contract_value_validation() {
        let log = FeedbackLog::new(ms(1000));
        let mut i = ValueInputs {
            quality: 7.0,
            ..ValueInputs::default()
        };
        assert_eq!(compute_value(&i, &log, ms(0)), Ok(1.0));
        i.quality = -3.0;
        assert_eq!(compute_value(&i, &log, ms(0)), Ok(-1.0));
        i.quality = f64::NAN;
        assert_eq!(
            compute_value(&i, &log, ms(0)),
            Err(Unavailable::InvalidQuality)
        );
        i.quality = 0.5;
        i.aptitude = false;
        assert_eq!(compute_value(&i, &log, ms(0)), Err(Unavailable::NotApt));
        i.aptitude = true;
        i.cost.cpu = f64::INFINITY;
        assert_eq!(
            compute_value(&i, &log, ms(0)),
            Err(Unavailable::InvalidResources)
        );
        i.cost = ResourceVec::new(1.0, 1.0, 1.0);
        i.r_eff = ResourceVec::new(-5.0, 0.0, 0.0);
        assert_eq!(compute_value(&i, &log, ms(0)), Ok(0.5));
    }

    #[test]
    fn contract_feedback_log_prunes_and_bounds() {
        let mut log = FeedbackLog::new(ms(100));
        assert!(!log.record(f64::NAN, ms(0)));
        assert!(log.record(5.0, ms(0)));
        assert!((log.sum(ms(0)) - 1.0).abs() < 1e-12);
        log.prune(ms(500));
        assert_eq!(log.len(), 1, "weight e^-5 is still significant");
        log.prune(ms(2000));
        assert!(log.is_empty(), "weight e^-20 is negligible");
        for i in 0..(FeedbackLog::MAX_ENTRIES as u64 + 10) {
            log.record(-1.0, ms(i));
        }
        assert_eq!(log.len(), FeedbackLog::MAX_ENTRIES);
        assert_eq!(log.mean(ms(2000)), Some(-1.0));
        assert_eq!(FeedbackLog::new(ms(1)).mean(ms(0)), None);
    }

    #[test]
    fn contract_select_best_ties_and_nan() {
        let p = |id, value| Proposal {
            provider: ModuleId(id),
            value,
            channel: String::new(),
        };
        assert!(select_best(&[]).is_none());
        let v = [p(5, 0.3), p(2, 0.7), p(9, f64::NAN), p(1, 0.7), p(3, 0.1)];
        assert_eq!(select_best(&v).map(|b| b.provider), Some(ModuleId(1)));
        assert!(select_best(&[p(1, f64::NAN)]).is_none());
    }
}
