//! What the mission monitor tracks of navigation: Planning's stalls and recovery behaviours
//! (`planning/progress`, printed as progress lines) and the time the robot stood still by the
//! simulator's true pose.

use hng_modules::planning::progress::NavProgress;
use std::collections::BTreeMap;

/// A window of at least this long (simulated s) with less than [`STILL_M`] of motion counts
/// as standing still.
const WINDOW_S: f64 = 1.0;
/// Motion below which a window counts as standing still, m.
const STILL_M: f64 = 0.05;

/// Stalls, recoveries and standing-still time of a mission.
#[derive(Debug, Default)]
pub struct NavWatch {
    /// Per goal: (stalls, recoveries), the latest cumulative counters.
    per_goal: BTreeMap<u32, (u32, u32)>,
    anchor: Option<(f64, f64, f64)>,
    stuck_s: f64,
}

impl NavWatch {
    /// A progress message: its counters; returns the line to print.
    pub fn on_progress(&mut self, m: &NavProgress) -> String {
        let e = self.per_goal.entry(m.goal_id).or_default();
        e.0 = e.0.max(m.stalls);
        e.1 = e.1.max(m.recoveries);
        m.describe()
    }

    /// A true pose at simulated time `t` (s); `active`: a goal is being pursued.
    pub fn on_truth(&mut self, t: f64, x: f64, y: f64, active: bool) {
        let Some((t0, x0, y0)) = self.anchor else {
            self.anchor = Some((t, x, y));
            return;
        };
        if t < t0 {
            self.anchor = Some((t, x, y));
            return;
        }
        if t - t0 >= WINDOW_S {
            if active && (x - x0).hypot(y - y0) < STILL_M {
                self.stuck_s += t - t0;
            }
            self.anchor = Some((t, x, y));
        }
    }

    /// Stalls reported over the mission.
    pub fn stalls(&self) -> u64 {
        self.per_goal.values().map(|v| u64::from(v.0)).sum()
    }

    /// Recovery behaviours started over the mission.
    pub fn recoveries(&self) -> u64 {
        self.per_goal.values().map(|v| u64::from(v.1)).sum()
    }

    /// Stalls and recovery behaviours of one goal.
    pub fn goal_counts(&self, goal_id: u32) -> (u64, u64) {
        self.per_goal
            .get(&goal_id)
            .map_or((0, 0), |v| (u64::from(v.0), u64::from(v.1)))
    }

    /// Simulated time the robot stood still while a goal was pursued, s.
    pub fn stuck_time_s(&self) -> f64 {
        self.stuck_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standing_still_is_counted_only_while_a_goal_is_pursued() {
        let mut w = NavWatch::default();
        for i in 0..=100 {
            let t = f64::from(i) * 0.1;
            // Moving 0.3 m/s for 5 s, then still for 5 s.
            let x = 0.3 * t.min(5.0);
            w.on_truth(t, x, 0.0, true);
        }
        assert!(
            (w.stuck_time_s() - 5.0).abs() < 1.01,
            "{}",
            w.stuck_time_s()
        );
        let mut idle = NavWatch::default();
        for i in 0..=100 {
            idle.on_truth(f64::from(i) * 0.1, 0.0, 0.0, false);
        }
        assert_eq!(idle.stuck_time_s(), 0.0);
    }

    #[test]
    fn counters_are_the_latest_per_goal() {
        let mut w = NavWatch::default();
        let m = |goal_id, stalls, recoveries| NavProgress {
            goal_id,
            event: 2,
            behaviour: 1,
            step: 1,
            stalls,
            recoveries,
            ..Default::default()
        };
        w.on_progress(&m(1, 1, 1));
        w.on_progress(&m(1, 1, 3));
        let line = w.on_progress(&m(2, 1, 1));
        assert!(line.contains("recovery 1: clear the costmap"), "{line}");
        assert_eq!((w.stalls(), w.recoveries()), (2, 4));
    }
}
