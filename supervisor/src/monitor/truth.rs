//! The true poses and the simulator's path counter as the monitor keeps them, so that it can
//! give the figures of a moment of simulated time (a goal's report, the mission's end)
//! whatever the moment it happened to read them: the monitor is no lockstep participant, and
//! the simulator's status comes every 100 ms of wall time.

use std::collections::VecDeque;

/// True poses kept (40 s simulated at the default 100 Hz).
const POSES: usize = 4096;
/// Path counters kept (the simulator's status, every 100 ms of wall time).
const PATHS: usize = 256;
/// A step between two true poses faster than this is a teleport, not driving, m/s (the
/// simulator's own path counter leaves teleports out too).
const TELEPORT_SPEED: f64 = 20.0;

/// Recent true poses and path counters, oldest first.
#[derive(Debug, Default)]
pub(super) struct TruthLog {
    /// (simulated ns, x, y).
    poses: VecDeque<(u64, f64, f64)>,
    /// (simulated ns, the true path's length until then, m).
    paths: VecDeque<(u64, f64)>,
}

impl TruthLog {
    /// A true pose at simulated time `ns`.
    pub(super) fn push_pose(&mut self, ns: u64, x: f64, y: f64) {
        if self.poses.len() >= POSES {
            self.poses.pop_front();
        }
        self.poses.push_back((ns, x, y));
    }

    /// The simulator's path counter at simulated time `ns`, m.
    pub(super) fn push_path(&mut self, ns: u64, path_m: f64) {
        if self.paths.len() >= PATHS {
            self.paths.pop_front();
        }
        self.paths.push_back((ns, path_m));
    }

    /// No true pose yet.
    pub(super) fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Recent true poses, oldest first.
    pub(super) fn poses(&self) -> impl DoubleEndedIterator<Item = &(u64, f64, f64)> {
        self.poses.iter()
    }

    /// The true position at simulated time `ns`: the last pose at or before it (the oldest
    /// kept if none is that old).
    pub(super) fn at(&self, ns: u64) -> Option<(f64, f64)> {
        self.poses
            .iter()
            .rev()
            .find(|(t, _, _)| *t <= ns)
            .or(self.poses.front())
            .map(|(_, x, y)| (*x, *y))
    }

    /// The true path's length at simulated time `ns`, m: the last path counter at or before
    /// it, plus the true poses' steps from there to `ns` (the simulator adds the same steps
    /// in the same order, so the sum is its own counter at `ns`). `None` if no counter is
    /// that old or the poses kept do not reach back to it.
    pub(super) fn path_at(&self, ns: u64) -> Option<f64> {
        let &(from, path) = self.paths.iter().rev().find(|(t, _)| *t <= ns)?;
        if self.poses.front().is_none_or(|(t, _, _)| *t > from) {
            return None;
        }
        let mut sum = path;
        let mut last: Option<(u64, f64, f64)> = None;
        for &(t, x, y) in self
            .poses
            .iter()
            .filter(|(t, _, _)| (from..=ns).contains(t))
        {
            if let Some((t0, x0, y0)) = last {
                let d = (x - x0).hypot(y - y0);
                if d <= TELEPORT_SPEED * t.saturating_sub(t0) as f64 * 1e-9 {
                    sum += d;
                }
            }
            last = Some((t, x, y));
        }
        Some(sum)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// A robot driving 0.5 m/s along x from 0 at 10 ms steps, with the simulator's counter.
    fn drive(log: &mut TruthLog, steps: u64, counter_every: u64) -> f64 {
        let mut path = 0.0;
        let mut last = None;
        for k in 0..=steps {
            let x = 0.005 * k as f64;
            if let Some(x0) = last {
                path += x - x0;
            }
            last = Some(x);
            log.push_pose(k * 10 * MS, x, 0.0);
            if k % counter_every == 0 {
                log.push_path(k * 10 * MS, path);
            }
        }
        path
    }

    #[test]
    fn the_path_at_a_moment_does_not_depend_on_when_the_counter_came() {
        let (mut a, mut b) = (TruthLog::default(), TruthLog::default());
        drive(&mut a, 500, 7);
        drive(&mut b, 500, 23);
        for k in [40u64, 230, 499] {
            let pa = a.path_at(k * 10 * MS).expect("a");
            let pb = b.path_at(k * 10 * MS).expect("b");
            assert!((pa - 0.005 * k as f64).abs() < 1e-9, "{pa} at step {k}");
            assert!((pa - pb).abs() < 1e-12, "{pa} vs {pb}");
        }
    }

    #[test]
    fn a_teleport_is_not_driven() {
        let mut log = TruthLog::default();
        let before = drive(&mut log, 100, 100);
        log.push_pose(1_010 * MS, 30.0, 4.0);
        log.push_pose(1_020 * MS, 30.005, 4.0);
        let p = log.path_at(1_020 * MS).expect("path");
        assert!((p - (before + 0.005)).abs() < 1e-9, "{p}");
    }

    #[test]
    fn no_path_without_a_counter_or_poses_that_old() {
        let mut log = TruthLog::default();
        assert_eq!(log.path_at(0), None);
        log.push_path(5 * MS, 1.0);
        log.push_pose(10 * MS, 0.0, 0.0);
        assert_eq!(log.path_at(20 * MS), None, "poses start after the counter");
        assert_eq!(log.path_at(1), None, "no counter that old");
        assert_eq!(log.at(1), Some((0.0, 0.0)), "the oldest pose kept");
    }
}
