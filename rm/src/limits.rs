//! Resource limits of a module, how each one is enforced, and the software check used
//! when the kernel cannot enforce a cap.

use std::collections::HashMap;
use std::fmt;
use std::time::{Duration, Instant};

use crate::sampler::{Liveness, ModuleSample};

/// The caps of one module. `None` = unlimited.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ResourceLimits {
    /// CPU, in % of one core (100 = one full core; 20 = a fifth of one core).
    pub cpu_percent: Option<f64>,
    /// Hard memory limit in bytes (v2 `memory.max`, v1 `memory.limit_in_bytes`); the
    /// kernel OOM-kills inside the group above it.
    pub memory_bytes: Option<u64>,
    /// Soft memory limit in bytes (v2 `memory.high`: throttles and reclaims, never
    /// kills). Ignored on v1 and in software.
    pub memory_high_bytes: Option<u64>,
    /// Maximum number of tasks (processes + threads) in the group (`pids.max`).
    pub pids: Option<u64>,
}

/// How one cap ended up being enforced.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Cap {
    /// The cap was not asked for.
    NotRequested,
    /// The kernel enforces it (cgroup file written).
    Kernel,
    /// The kernel does not: the caller must check samples with a [`SoftwareEnforcer`]
    /// and stop the module (cause "over limit") when it goes over.
    Software {
        /// Why the kernel does not enforce it.
        reason: String,
    },
    /// Neither the kernel nor the software check enforces it (pids without cgroups).
    Unenforced {
        /// Why.
        reason: String,
    },
}

impl Cap {
    /// Whether the kernel enforces the cap.
    #[must_use]
    pub fn is_kernel(&self) -> bool {
        matches!(self, Cap::Kernel)
    }
}

/// Outcome of applying [`ResourceLimits`] to a module.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AppliedLimits {
    /// CPU quota.
    pub cpu: Cap,
    /// Memory limit (`memory_bytes`; `memory_high_bytes` is best effort and not reported).
    pub memory: Cap,
    /// Pids limit.
    pub pids: Cap,
}

impl AppliedLimits {
    /// All caps left to software (no cgroups), with the same reason.
    #[must_use]
    pub fn all_software(limits: &ResourceLimits, reason: &str) -> Self {
        let sw = |requested: bool| {
            if requested {
                Cap::Software {
                    reason: reason.to_owned(),
                }
            } else {
                Cap::NotRequested
            }
        };
        AppliedLimits {
            cpu: sw(limits.cpu_percent.is_some()),
            memory: sw(limits.memory_bytes.is_some()),
            pids: if limits.pids.is_some() {
                Cap::Unenforced {
                    reason: reason.to_owned(),
                }
            } else {
                Cap::NotRequested
            },
        }
    }

    /// The part of `requested` the caller must enforce in software (give it to
    /// [`SoftwareEnforcer::set_limits`]).
    #[must_use]
    pub fn software_limits(&self, requested: &ResourceLimits) -> ResourceLimits {
        let sw = |c: &Cap| matches!(c, Cap::Software { .. });
        ResourceLimits {
            cpu_percent: requested.cpu_percent.filter(|_| sw(&self.cpu)),
            memory_bytes: requested.memory_bytes.filter(|_| sw(&self.memory)),
            memory_high_bytes: None,
            pids: None,
        }
    }
}

/// Which resource a module went over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LimitedResource {
    /// CPU (% of one core, averaged over [`SoftwareEnforcerConfig::cpu_window`]).
    Cpu,
    /// Memory (PSS when known, else RSS), bytes.
    Memory,
}

/// A module over one of its limits: the caller should stop it with cause "over limit".
#[derive(Debug, Clone, PartialEq)]
pub struct OverLimit {
    /// Module name.
    pub module: String,
    /// Which resource.
    pub resource: LimitedResource,
    /// The measured value (CPU %, or bytes).
    pub measured: f64,
    /// The limit (CPU %, or bytes).
    pub limit: f64,
}

impl fmt::Display for OverLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.resource {
            LimitedResource::Cpu => write!(
                f,
                "over limit: module '{}' uses {:.1}% CPU, limit {:.1}%",
                self.module, self.measured, self.limit
            ),
            LimitedResource::Memory => write!(
                f,
                "over limit: module '{}' uses {:.0} bytes of memory, limit {:.0}",
                self.module, self.measured, self.limit
            ),
        }
    }
}

/// Settings of the software check.
#[derive(Debug, Clone, PartialEq)]
pub struct SoftwareEnforcerConfig {
    /// Time constant of the CPU moving average (default 2 s): a short burst over the
    /// quota is not a violation, a sustained one is.
    pub cpu_window: Duration,
}

impl Default for SoftwareEnforcerConfig {
    fn default() -> Self {
        SoftwareEnforcerConfig {
            cpu_window: Duration::from_secs(2),
        }
    }
}

#[derive(Debug, Clone)]
struct SoftState {
    limits: ResourceLimits,
    cpu_avg: Option<f64>,
    last: Option<Instant>,
}

/// Checks samples against limits the kernel does not enforce.
///
/// CPU uses an exponential moving average of the sampled CPU % with time constant
/// `cpu_window` (weight of a sample = 1 − e^(−Δt/window)); memory is checked on every
/// sample against [`ModuleSample::memory_bytes`].
#[derive(Debug, Clone, Default)]
pub struct SoftwareEnforcer {
    config: SoftwareEnforcerConfig,
    modules: HashMap<String, SoftState>,
}

impl SoftwareEnforcer {
    /// A checker with no module.
    #[must_use]
    pub fn new(config: SoftwareEnforcerConfig) -> Self {
        SoftwareEnforcer {
            config,
            modules: HashMap::new(),
        }
    }

    /// Sets (or replaces) the software limits of a module.
    pub fn set_limits(&mut self, module: &str, limits: ResourceLimits) {
        self.modules.insert(
            module.to_owned(),
            SoftState {
                limits,
                cpu_avg: None,
                last: None,
            },
        );
    }

    /// Forgets a module.
    pub fn remove(&mut self, module: &str) {
        self.modules.remove(module);
    }

    /// Feeds one sample; returns the violation, if any. Samples of modules without
    /// software limits, of dead processes and without a CPU figure yet are ignored for
    /// the parts they lack.
    pub fn check(&mut self, sample: &ModuleSample) -> Option<OverLimit> {
        let st = self.modules.get_mut(&sample.name)?;
        if sample.liveness != Liveness::Alive {
            return None;
        }
        if let Some(limit) = st.limits.memory_bytes {
            let used = sample.memory_bytes();
            if used > limit {
                return Some(OverLimit {
                    module: sample.name.clone(),
                    resource: LimitedResource::Memory,
                    measured: used as f64,
                    limit: limit as f64,
                });
            }
        }
        let (Some(limit), Some(cpu), Some(at)) =
            (st.limits.cpu_percent, sample.cpu_percent, sample.at)
        else {
            return None;
        };
        let avg = match (st.cpu_avg, st.last) {
            (Some(avg), Some(last)) => {
                let dt = at.saturating_duration_since(last).as_secs_f64();
                let tau = self.config.cpu_window.as_secs_f64().max(1e-9);
                let w = 1.0 - (-dt / tau).exp();
                avg + w * (cpu - avg)
            }
            _ => cpu,
        };
        st.cpu_avg = Some(avg);
        st.last = Some(at);
        // The first samples alone are not a sustained violation: wait until the average
        // covers one window.
        (avg > limit).then(|| OverLimit {
            module: sample.name.clone(),
            resource: LimitedResource::Cpu,
            measured: avg,
            limit,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::CpuSource;

    fn sample(cpu: f64, mem: u64, at: Instant) -> ModuleSample {
        ModuleSample {
            name: "m".into(),
            pid: 1,
            starttime: 1,
            at: Some(at),
            liveness: Liveness::Alive,
            cpu_percent: Some(cpu),
            cpu_source: CpuSource::ProcStat,
            cpu_time: Duration::ZERO,
            rss_bytes: mem,
            pss_bytes: None,
            minor_faults: 0,
            major_faults: 0,
            minor_faults_per_s: None,
            major_faults_per_s: None,
        }
    }

    #[test]
    fn memory_over_limit_is_reported() {
        let mut e = SoftwareEnforcer::default();
        e.set_limits(
            "m",
            ResourceLimits {
                memory_bytes: Some(1000),
                ..Default::default()
            },
        );
        let t = Instant::now();
        assert!(e.check(&sample(0.0, 999, t)).is_none());
        let v = e.check(&sample(0.0, 1001, t)).expect("over limit");
        assert_eq!(v.resource, LimitedResource::Memory);
        assert!(v.to_string().starts_with("over limit"));
    }

    #[test]
    fn cpu_burst_is_tolerated_sustained_is_not() {
        let mut e = SoftwareEnforcer::new(SoftwareEnforcerConfig {
            cpu_window: Duration::from_secs(1),
        });
        e.set_limits(
            "m",
            ResourceLimits {
                cpu_percent: Some(50.0),
                ..Default::default()
            },
        );
        let t0 = Instant::now();
        let mut t = t0;
        // 1 s at 10%.
        for _ in 0..10 {
            t += Duration::from_millis(100);
            assert!(e.check(&sample(10.0, 0, t)).is_none());
        }
        // One 100 ms burst at 100%: average stays well under 50.
        t += Duration::from_millis(100);
        assert!(e.check(&sample(100.0, 0, t)).is_none());
        // Sustained 100%: caught within a couple of windows.
        let mut caught = None;
        for i in 0..30 {
            t += Duration::from_millis(100);
            if let Some(v) = e.check(&sample(100.0, 0, t)) {
                caught = Some((i, v));
                break;
            }
        }
        let (i, v) = caught.expect("sustained overuse must be caught");
        assert!(i >= 3, "caught too early at sample {i}");
        assert_eq!(v.resource, LimitedResource::Cpu);
    }

    #[test]
    fn software_limits_keep_only_software_caps() {
        let req = ResourceLimits {
            cpu_percent: Some(20.0),
            memory_bytes: Some(1 << 20),
            memory_high_bytes: None,
            pids: Some(10),
        };
        let applied = AppliedLimits {
            cpu: Cap::Software {
                reason: "quota too small".into(),
            },
            memory: Cap::Kernel,
            pids: Cap::Kernel,
        };
        let sw = applied.software_limits(&req);
        assert_eq!(sw.cpu_percent, Some(20.0));
        assert_eq!(sw.memory_bytes, None);
        let all = AppliedLimits::all_software(&req, "no cgroups");
        assert!(matches!(all.pids, Cap::Unenforced { .. }));
        assert_eq!(all.software_limits(&req).memory_bytes, Some(1 << 20));
    }
}
