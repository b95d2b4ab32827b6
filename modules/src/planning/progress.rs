//! Progress toward the goal and recovery behaviours, as Nav2's progress checker and recovery
//! sequence: when the distance left along the path has not shrunk by `progress_m` for
//! `stall_s`, the goal is *stalled*; the behaviours are then tried in turn (clear the
//! obstacle memory: the costmap is rebuilt from the Mapping provider's map and the path
//! planned afresh; rotate in place a full turn, so the lidar sees all round; back up
//! `backup_m`; plan again), each followed by `recovery_wait_s` to see whether the robot
//! moves toward the goal again. Progress ends the recovery (and the next stall starts the
//! sequence again); when the last behaviour did not help the goal *fails*, with its reason.
//!
//! Pure logic: the Planning module feeds it the simulated time, the pose and the distance
//! left, and carries out the action it returns (the rotations and the backing up are
//! waypoints for the Servo-controller: a carrot beside the robot, and a carrot behind it with
//! a negative speed).

use hng_runtime::msg::Header;
use hng_runtime::qos::ChannelKind;
use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

/// Channel of [`NavProgress`] (Planning publishes it on every event).
pub const PROGRESS_CHANNEL: &str = "planning/progress";

/// Stalls and recoveries of the current goal, published by Planning at every [`Event`]
/// (`hng-modules/NavProgress/v1`, a state channel; the counters are cumulative for the goal,
/// so a reader that missed a sample still counts right).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-modules/NavProgress/v1")]
pub struct NavProgress {
    /// Header; `frame_id` is `map`, the stamp simulated time.
    pub header: Header,
    /// The goal.
    pub goal_id: u32,
    /// 1 stalled, 2 recovery started, 3 recovered, 4 failed.
    pub event: u8,
    /// The behaviour started (a [`Recovery`] as a byte, 0 otherwise).
    pub behaviour: u8,
    /// Its number in the sequence (from 1).
    pub step: u8,
    /// Time without progress, s (stalled, failed).
    pub seconds: f64,
    /// Distance left along the path, m.
    pub distance_left_m: f64,
    /// Stalls of this goal so far.
    pub stalls: u32,
    /// Behaviours started for this goal so far.
    pub recoveries: u32,
}

hng_runtime::impl_message!(NavProgress, ChannelKind::State);

impl NavProgress {
    /// The event in words, for progress lines and logs.
    pub fn describe(&self) -> String {
        match self.event {
            1 => format!(
                "goal {} STALLED: no progress for {:.1} s ({:.2} m left)",
                self.goal_id, self.seconds, self.distance_left_m
            ),
            2 => format!(
                "goal {} recovery {}: {}",
                self.goal_id,
                self.step,
                Recovery::from_repr(self.behaviour).map_or("?", Recovery::describe)
            ),
            3 => format!(
                "goal {} recovered: moving toward it again ({:.2} m left)",
                self.goal_id, self.distance_left_m
            ),
            4 => format!(
                "goal {} FAILED: no progress for {:.1} s after {} recovery behaviours (clear the costmap, rotate, back up, re-plan)",
                self.goal_id, self.seconds, self.recoveries
            ),
            _ => format!(
                "goal {}: unknown progress event {}",
                self.goal_id, self.event
            ),
        }
    }
}

/// Parameters of the progress checker and the recoveries.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct ProgressParams {
    /// No progress for this long is a stall, s (simulated; default 10; 0 disables the
    /// checker).
    #[default(10.0)]
    pub stall_s: f64,
    /// Progress: the distance left shrinks by this much, m (default 0.5).
    #[default(0.5)]
    pub progress_m: f64,
    /// Time constant of the low-pass filter on the distance left, s (default 2): a noisy
    /// position (GPS, σ 0.3 m) must not look like progress.
    #[default(2.0)]
    pub filter_s: f64,
    /// Time given to each behaviour's effect before the next one, s (default 6).
    #[default(6.0)]
    pub recovery_wait_s: f64,
    /// Distance to back up, m (default 0.3).
    #[default(0.3)]
    pub backup_m: f64,
    /// Backing-up speed, m/s (default 0.15).
    #[default(0.15)]
    pub backup_speed: f64,
    /// Longest time a motion behaviour (rotate, back up) may take, s (default 8).
    #[default(8.0)]
    pub behaviour_timeout_s: f64,
}

/// A recovery behaviour.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, strum::FromRepr)]
#[serde(rename_all = "snake_case")]
pub enum Recovery {
    /// Rebuild the costmap from the provider's map and plan afresh.
    ClearCostmap = 1,
    /// Turn in place a full turn.
    Rotate = 2,
    /// Drive backwards `backup_m`.
    BackUp = 3,
    /// Plan again from where the robot is.
    Replan = 4,
}

impl Recovery {
    /// The sequence, in order.
    pub const SEQUENCE: [Recovery; 4] = [
        Recovery::ClearCostmap,
        Recovery::Rotate,
        Recovery::BackUp,
        Recovery::Replan,
    ];

    /// In words.
    pub fn describe(self) -> &'static str {
        match self {
            Recovery::ClearCostmap => "clear the costmap",
            Recovery::Rotate => "rotate in place",
            Recovery::BackUp => "back up",
            Recovery::Replan => "re-plan",
        }
    }
}

/// What the planner must do now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Follow the path (the normal waypoint).
    Follow,
    /// Rebuild the costmap and plan afresh (once), then follow.
    Clear,
    /// Plan afresh (once), then follow.
    Replan,
    /// Turn in place (counter-clockwise).
    Rotate,
    /// Back up straight at this speed (m/s, positive).
    BackUp(f64),
    /// Give the goal up.
    Fail,
}

/// What happened, to report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// No progress for this long, s.
    Stalled(f64),
    /// A behaviour starts (its number in the sequence, from 1).
    Started(Recovery, u8),
    /// Progress again after recoveries.
    Recovered,
    /// Every behaviour was tried, no progress for this long, s.
    Failed(f64),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Following,
    /// Doing behaviour `step` of the sequence since `since` (pose at its start).
    Doing {
        step: usize,
        since: f64,
        x: f64,
        y: f64,
        turned: f64,
        last_theta: f64,
    },
    /// Waiting for behaviour `step` to have its effect, since `since`.
    Watching {
        step: usize,
        since: f64,
    },
    Failed,
}

/// The progress checker and recovery sequence of one goal.
#[derive(Debug, Clone)]
pub struct ProgressMonitor {
    params: ProgressParams,
    phase: Phase,
    /// Least distance left so far, and when it last improved by `progress_m`.
    best: f64,
    mark: f64,
    last_progress_s: f64,
    stalled_since: f64,
    /// The filtered distance left and the time of its last update.
    filtered: Option<(f64, f64)>,
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

impl ProgressMonitor {
    /// A monitor for a goal that starts at time `now`.
    pub fn new(params: ProgressParams, now: f64) -> ProgressMonitor {
        ProgressMonitor {
            params,
            phase: Phase::Following,
            best: f64::INFINITY,
            mark: f64::INFINITY,
            last_progress_s: now,
            stalled_since: now,
            filtered: None,
        }
    }

    /// True while a recovery behaviour or its wait is under way.
    pub fn recovering(&self) -> bool {
        !matches!(self.phase, Phase::Following)
    }

    /// The path changed for a reason other than recovery (a new map): a longer path (a
    /// detour) raises the distance from which progress is counted; a shorter one is not
    /// progress by itself and changes nothing.
    pub fn rebase(&mut self, distance_left: f64) {
        if distance_left.is_finite() && distance_left > self.mark {
            self.best = distance_left;
            self.mark = distance_left;
            self.filtered = None;
        }
    }

    /// The robot at `(x, y, theta)` at time `now` with `distance_left` along its path: the
    /// action to take and what to report.
    pub fn update(
        &mut self,
        now: f64,
        pose: (f64, f64, f64),
        distance_left: f64,
    ) -> (Action, Vec<Event>) {
        let p = self.params;
        if p.stall_s.is_nan() || p.stall_s <= 0.0 {
            return (Action::Follow, Vec::new());
        }
        if distance_left.is_finite() {
            let d = match self.filtered {
                Some((f, t)) if p.filter_s > 0.0 => {
                    let a = 1.0 - (-(now - t).max(0.0) / p.filter_s).exp();
                    f + a * (distance_left - f)
                }
                _ => distance_left,
            };
            self.filtered = Some((d, now));
            let distance_left = d;
            self.best = self.best.min(distance_left);
            if !self.mark.is_finite() || self.best <= self.mark - p.progress_m {
                self.mark = self.best;
                self.last_progress_s = now;
                if matches!(self.phase, Phase::Watching { .. } | Phase::Doing { .. }) {
                    self.phase = Phase::Following;
                    return (Action::Follow, vec![Event::Recovered]);
                }
            }
        }
        match self.phase {
            Phase::Failed => (Action::Fail, Vec::new()),
            Phase::Following => {
                if now - self.last_progress_s >= p.stall_s {
                    self.stalled_since = self.last_progress_s;
                    let stalled = now - self.last_progress_s;
                    let (a, started) = self.start(0, now, pose);
                    return (a, vec![Event::Stalled(stalled), started]);
                }
                (Action::Follow, Vec::new())
            }
            Phase::Doing {
                step,
                since,
                x,
                y,
                mut turned,
                last_theta,
            } => {
                let b = Recovery::SEQUENCE[step];
                turned += wrap(pose.2 - last_theta);
                let elapsed = now - since;
                let done = elapsed >= p.behaviour_timeout_s
                    || match b {
                        Recovery::Rotate => turned >= std::f64::consts::TAU,
                        Recovery::BackUp => (pose.0 - x).hypot(pose.1 - y) >= p.backup_m,
                        _ => true,
                    };
                if done {
                    self.phase = Phase::Watching { step, since: now };
                    return (Action::Follow, Vec::new());
                }
                self.phase = Phase::Doing {
                    step,
                    since,
                    x,
                    y,
                    turned,
                    last_theta: pose.2,
                };
                let a = match b {
                    Recovery::Rotate => Action::Rotate,
                    Recovery::BackUp => Action::BackUp(p.backup_speed),
                    Recovery::ClearCostmap => Action::Clear,
                    Recovery::Replan => Action::Replan,
                };
                (a, Vec::new())
            }
            Phase::Watching { step, since } => {
                if now - since < p.recovery_wait_s {
                    return (Action::Follow, Vec::new());
                }
                if step + 1 < Recovery::SEQUENCE.len() {
                    let (a, e) = self.start(step + 1, now, pose);
                    return (a, vec![e]);
                }
                self.phase = Phase::Failed;
                (Action::Fail, vec![Event::Failed(now - self.stalled_since)])
            }
        }
    }

    fn start(&mut self, step: usize, now: f64, pose: (f64, f64, f64)) -> (Action, Event) {
        let b = Recovery::SEQUENCE[step];
        let instant = matches!(b, Recovery::ClearCostmap | Recovery::Replan);
        self.phase = if instant {
            Phase::Watching { step, since: now }
        } else {
            Phase::Doing {
                step,
                since: now,
                x: pose.0,
                y: pose.1,
                turned: 0.0,
                last_theta: pose.2,
            }
        };
        let a = match b {
            Recovery::ClearCostmap => Action::Clear,
            Recovery::Replan => Action::Replan,
            Recovery::Rotate => Action::Rotate,
            Recovery::BackUp => Action::BackUp(self.params.backup_speed),
        };
        (a, Event::Started(b, step as u8 + 1))
    }
}

/// Distance of the recovery carrots from the robot, m.
const CARROT_M: f64 = 0.6;

/// The waypoint that makes the Servo-controller carry out a motion behaviour from `pose`:
/// for [`Action::Rotate`] a carrot 2 rad to the left (beyond the Servo's turn-in-place
/// bearing, so it turns on the spot), for [`Action::BackUp`] a carrot straight behind with a
/// negative speed (the Servo backs up straight). `None` for the other actions.
pub fn recovery_waypoint(
    action: Action,
    pose: &hng_runtime::msg::Pose2D,
    goal_id: u32,
) -> Option<hng_runtime::msg::Waypoint> {
    let (bearing, speed) = match action {
        Action::Rotate => (2.0, 0.1),
        Action::BackUp(v) => (std::f64::consts::PI, -v.abs()),
        _ => return None,
    };
    let a = pose.theta + bearing;
    Some(hng_runtime::msg::Waypoint {
        header: Header {
            frame_id: hng_runtime::msg::FrameId::MAP,
            ..Header::default()
        },
        goal_id,
        index: 0,
        pose: hng_runtime::msg::Pose2D::new(
            pose.x + CARROT_M * a.cos(),
            pose.y + CARROT_M * a.sin(),
            pose.theta,
        ),
        speed,
        is_final: 0,
    })
}

/// The progress message of `event` (counters as of now).
pub fn progress_message(
    event: &Event,
    goal_id: u32,
    distance_left_m: f64,
    stalls: u32,
    recoveries: u32,
) -> NavProgress {
    let (kind, behaviour, step, seconds) = match *event {
        Event::Stalled(s) => (1, 0, 0, s),
        Event::Started(r, n) => (2, r as u8, n, 0.0),
        Event::Recovered => (3, 0, 0, 0.0),
        Event::Failed(s) => (4, 0, 0, s),
    };
    NavProgress {
        header: Header {
            frame_id: hng_runtime::msg::FrameId::MAP,
            ..Header::default()
        },
        goal_id,
        event: kind,
        behaviour,
        step,
        seconds,
        distance_left_m,
        stalls,
        recoveries,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_progress_never_stalls() {
        let mut m = ProgressMonitor::new(ProgressParams::default(), 0.0);
        for i in 0..400 {
            let t = f64::from(i) * 0.1;
            let (a, e) = m.update(t, (0.0, 0.0, 0.0), 30.0 - 0.5 * t);
            assert_eq!((a, e), (Action::Follow, vec![]), "at {t}");
        }
    }

    #[test]
    fn position_noise_is_not_progress() {
        let mut m = ProgressMonitor::new(ProgressParams::default(), 0.0);
        let mut events = Vec::new();
        // A robot standing still with a GPS of σ 0.3 m: the distance left jumps about.
        let mut x: u64 = 12345;
        for i in 0..1200 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (x >> 11) as f64 / (1u64 << 53) as f64;
            let noise = (u - 0.5) * 2.0 * 0.5;
            let (_, e) = m.update(f64::from(i) * 0.2, (0.0, 0.0, 0.0), 10.0 + noise);
            events.extend(e);
        }
        assert!(!events.contains(&Event::Recovered), "{events:?}");
        assert!(
            matches!(events.last(), Some(Event::Failed(_))),
            "{events:?}"
        );
    }

    #[test]
    fn a_stall_runs_the_sequence_and_fails_with_every_behaviour_tried() {
        let mut m = ProgressMonitor::new(ProgressParams::default(), 0.0);
        let mut events = Vec::new();
        let mut actions = Vec::new();
        let mut theta = 0.0;
        let mut x = 0.0;
        for i in 0..1200 {
            let t = f64::from(i) * 0.1;
            let (a, e) = m.update(t, (x, 0.0, theta), 10.0);
            match a {
                Action::Rotate => theta = wrap(theta + 0.15),
                Action::BackUp(v) => x -= v * 0.1,
                _ => {}
            }
            if actions.last() != Some(&a) {
                actions.push(a);
            }
            events.extend(e);
            if a == Action::Fail {
                break;
            }
        }
        let kinds = events;
        assert!(
            matches!(kinds[0], Event::Stalled(s) if (s - 10.0).abs() < 0.15),
            "{kinds:?}"
        );
        let started: Vec<Recovery> = kinds
            .iter()
            .filter_map(|e| match e {
                Event::Started(r, _) => Some(*r),
                _ => None,
            })
            .collect();
        assert_eq!(started, Recovery::SEQUENCE.to_vec(), "{kinds:?}");
        assert!(matches!(kinds.last(), Some(Event::Failed(_))), "{kinds:?}");
        assert!(actions.contains(&Action::Rotate) && actions.contains(&Action::BackUp(0.15)));
        assert_eq!(actions.last(), Some(&Action::Fail));
        assert!(x <= -0.3 + 1e-9, "backed up {x}");
    }

    #[test]
    fn progress_during_recovery_ends_it() {
        let mut m = ProgressMonitor::new(ProgressParams::default(), 0.0);
        let mut t = 0.0;
        while !m.recovering() {
            m.update(t, (0.0, 0.0, 0.0), 10.0);
            t += 0.1;
        }
        // Real progress: the filtered distance follows within a few time constants.
        let mut got = Vec::new();
        for i in 0..50 {
            let (_, e) = m.update(t + f64::from(i) * 0.1, (0.0, 0.0, 0.0), 8.0);
            got.extend(e);
        }
        assert_eq!(got.first(), Some(&Event::Recovered), "{got:?}");
        assert!(!m.recovering());
    }
}
