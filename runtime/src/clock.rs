//! The common clock.
//!
//! By default every module reads `CLOCK_MONOTONIC`, which all processes on one computer share,
//! so time stamps from different modules are comparable. In simulation-clock mode the time is
//! the latest [`crate::msg::Clock`] sample on [`CLOCK_CHANNEL`], published by the simulator;
//! modules' timers and input deadlines then follow simulated time, so a simulated system can
//! run faster (or slower) than real time. Heartbeats always use the wall clock, so a paused
//! simulation never looks like a hung module.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

pub mod lockstep;
#[cfg(target_arch = "x86_64")]
pub mod tsc;

/// The channel the simulation clock is published on.
pub const CLOCK_CHANNEL: &str = "hng/clock";

/// Which time source a [`Clock`] follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockMode {
    /// `CLOCK_MONOTONIC`.
    Wall,
    /// The simulation clock channel.
    Sim,
}

/// A cheap, cloneable handle on the process's clock.
#[derive(Debug, Clone)]
pub struct Clock {
    mode: ClockMode,
    sim_ns: Arc<AtomicU64>,
}

/// Nanoseconds of `CLOCK_MONOTONIC`.
///
/// Called for every message published (the header stamp). Where the kernel itself keeps
/// time with the TSC (clocksource `tsc`, synchronised across CPUs), this reads the TSC and
/// converts it with a line kept within a few tens of nanoseconds of `CLOCK_MONOTONIC`
/// (see [`tsc`]): about 12 ns, against 28 ns for the vDSO's `clock_gettime`, and without
/// the vDSO's serialising TSC read, which waits for every load before it (the shared-memory
/// loads of the receive that came just before, on a hop). Elsewhere, or with
/// `HNG_TSC=off`, it calls `clock_gettime` (the vDSO) directly.
#[inline]
pub fn monotonic_ns() -> u64 {
    #[cfg(target_arch = "x86_64")]
    if let Some(ns) = tsc::now_ns() {
        return ns;
    }
    os_monotonic_ns()
}

/// Nanoseconds of `CLOCK_MONOTONIC` from the C library (the vDSO), not through `nix`,
/// whose wrapper costs a third more on this project's machine (38 ns against 28 ns).
#[inline]
pub fn os_monotonic_ns() -> u64 {
    let mut ts = nix::libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; clock_gettime writes only into it.
    let rc = unsafe { nix::libc::clock_gettime(nix::libc::CLOCK_MONOTONIC, &mut ts) };
    if rc == 0 {
        (ts.tv_sec as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(ts.tv_nsec as u64)
    } else {
        // CLOCK_MONOTONIC cannot fail on Linux; fall back to a process-local clock.
        fallback_ns()
    }
}

fn fallback_ns() -> u64 {
    use std::sync::OnceLock;
    static START: OnceLock<std::time::Instant> = OnceLock::new();
    START
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_nanos() as u64
}

impl Clock {
    /// A clock following `CLOCK_MONOTONIC`.
    pub fn wall() -> Clock {
        Clock {
            mode: ClockMode::Wall,
            sim_ns: Arc::new(AtomicU64::new(0)),
        }
    }

    /// A clock following the simulation clock channel; it reads 0 until the first sample.
    pub fn sim() -> Clock {
        Clock {
            mode: ClockMode::Sim,
            sim_ns: Arc::new(AtomicU64::new(0)),
        }
    }

    /// The mode.
    pub fn mode(&self) -> ClockMode {
        self.mode
    }

    /// True when following the simulation clock.
    pub fn is_sim(&self) -> bool {
        self.mode == ClockMode::Sim
    }

    /// Now, in nanoseconds.
    #[inline]
    pub fn now_ns(&self) -> u64 {
        match self.mode {
            ClockMode::Wall => monotonic_ns(),
            ClockMode::Sim => self.sim_ns.load(Ordering::Acquire),
        }
    }

    /// Now, as a duration since the clock's epoch.
    pub fn now(&self) -> Duration {
        Duration::from_nanos(self.now_ns())
    }

    /// Advances the simulation time (never backwards). Used by the executor when a clock
    /// sample arrives, and by the simulator for its own process.
    pub fn set_sim_ns(&self, ns: u64) {
        self.sim_ns.fetch_max(ns, Ordering::AcqRel);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_clock_is_monotonic() {
        let c = Clock::wall();
        let a = c.now_ns();
        let b = c.now_ns();
        assert!(b >= a);
        assert!(a > 0);
    }

    #[test]
    fn sim_clock_follows_samples_and_never_goes_back() {
        let c = Clock::sim();
        assert_eq!(c.now_ns(), 0);
        c.set_sim_ns(5_000);
        let shared = c.clone();
        assert_eq!(shared.now_ns(), 5_000);
        c.set_sim_ns(1_000);
        assert_eq!(c.now_ns(), 5_000);
    }
}
