//! Pacing the simulated clock against the wall clock: real time, N times real time, or as fast
//! as possible. The only place in the crate that reads the wall clock.

use std::str::FromStr;
use std::time::{Duration, Instant};

/// How fast simulated time runs against the wall clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// One simulated second per wall second.
    RealTime,
    /// `N` simulated seconds per wall second (`--speed N`).
    Factor(f64),
    /// No waiting at all.
    Unlimited,
}

impl FromStr for Speed {
    type Err = String;

    /// `realtime`, `max` (or `unlimited`, `inf`), or a positive factor such as `2` or `0.5`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "realtime" | "real-time" | "1" => Ok(Speed::RealTime),
            "max" | "unlimited" | "inf" => Ok(Speed::Unlimited),
            other => match other.parse::<f64>() {
                Ok(f) if f.is_finite() && f > 0.0 => Ok(Speed::Factor(f)),
                Ok(f) if f == f64::INFINITY => Ok(Speed::Unlimited),
                _ => Err(format!(
                    "speed {other:?}: expected `realtime`, `max` or a positive number"
                )),
            },
        }
    }
}

/// Keeps simulated time in step with the wall clock at a chosen [`Speed`].
///
/// ```
/// # use hng_simulator::{Pacer, Speed};
/// let pacer = Pacer::new(Speed::Unlimited, 0);
/// pacer.wait_until(1_000_000_000); // returns at once
/// ```
#[derive(Debug, Clone)]
pub struct Pacer {
    speed: Speed,
    wall_start: Instant,
    sim_start_ns: u64,
}

impl Pacer {
    /// Starts pacing now, with the simulated clock at `sim_now_ns`.
    #[must_use]
    pub fn new(speed: Speed, sim_now_ns: u64) -> Self {
        Self {
            speed,
            wall_start: Instant::now(),
            sim_start_ns: sim_now_ns,
        }
    }

    /// The speed.
    #[must_use]
    pub fn speed(&self) -> Speed {
        self.speed
    }

    /// Wall time still to wait before simulated time `sim_ns` is due (zero if late).
    #[must_use]
    pub fn delay_until(&self, sim_ns: u64) -> Duration {
        let factor = match self.speed {
            Speed::Unlimited => return Duration::ZERO,
            Speed::RealTime => 1.0,
            Speed::Factor(f) => f,
        };
        let sim_elapsed = sim_ns.saturating_sub(self.sim_start_ns) as f64 * 1e-9;
        let due = Duration::from_secs_f64((sim_elapsed / factor).min(1e9));
        due.saturating_sub(self.wall_start.elapsed())
    }

    /// Sleeps until simulated time `sim_ns` is due.
    pub fn wait_until(&self, sim_ns: u64) {
        let d = self.delay_until(sim_ns);
        if !d.is_zero() {
            std::thread::sleep(d);
        }
    }

    /// Simulated seconds per wall second since the pacer started, given the simulated time now.
    #[must_use]
    pub fn achieved_factor(&self, sim_now_ns: u64) -> f64 {
        let wall = self.wall_start.elapsed().as_secs_f64();
        let sim = sim_now_ns.saturating_sub(self.sim_start_ns) as f64 * 1e-9;
        if wall > 0.0 {
            sim / wall
        } else {
            f64::INFINITY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_parses() {
        assert_eq!("realtime".parse(), Ok(Speed::RealTime));
        assert_eq!("max".parse(), Ok(Speed::Unlimited));
        assert_eq!("4".parse(), Ok(Speed::Factor(4.0)));
        assert!("-1".parse::<Speed>().is_err());
        assert!("fast".parse::<Speed>().is_err());
    }

    #[test]
    fn factor_scales_the_delay() {
        let p = Pacer::new(Speed::Factor(10.0), 0);
        let d = p.delay_until(10_000_000_000); // 10 s simulated = 1 s wall
        assert!(
            d <= Duration::from_secs(1) && d > Duration::from_millis(900),
            "{d:?}"
        );
        assert_eq!(
            Pacer::new(Speed::Unlimited, 0).delay_until(u64::MAX),
            Duration::ZERO
        );
    }
}
