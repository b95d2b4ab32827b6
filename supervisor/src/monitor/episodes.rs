//! Episodes: many start/goal problems on one running system (`hng run --episodes FILE`, used
//! by `hng eval nav`). For each episode the monitor puts the robot at the episode's start
//! (`sim/teleport`), tells the localization (`operator/initial_pose`), waits until the true
//! pose and every watched pose estimate are there, adds the goal to the Manager
//! (`hng/mission`), judges it against the true pose, cancels it (`Skip`) when it ran out of
//! time or the robot collided, and appends the episode's summary to a JSON-lines file at
//! once. Each episode's figures are differences of the simulator's and the monitor's
//! counters from the moment its goal was given (the least clearance: since the teleport,
//! which restarts the simulator's).

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use hng_modules::manager::MISSION_CHANNEL;
use hng_modules::msgs::{Mission, MissionGoal, MissionOp};
use hng_runtime::msg::{FrameId, Header, INITIAL_POSE_CHANNEL, Pose2D, PoseWithCovariance};
use hng_runtime::{Node, Publisher};
use hng_simulator::module::SimTeleport;
use serde::{Deserialize, Serialize};

use super::{GoalSummary, GoalTimes, State, Summary};
use crate::error::{Context as _, Result};

/// One episode: where the robot starts, where it goes, and the simulated time it has.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Episode {
    /// The caller's id of the episode (copied to its summary line).
    pub id: u64,
    /// Start pose: x, y (m, map frame), heading (rad).
    pub start: [f64; 3],
    /// Goal: x, y (m, map frame).
    pub goal: [f64; 2],
    /// Simulated time allowed from the moment the goal is given, s.
    pub duration_s: f64,
}

/// Reads an episode file: one [`Episode`] as JSON per line (blank lines and `#` comments
/// skipped); errors name the file and the line.
pub fn read_episodes(path: &Path) -> Result<Vec<Episode>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the episodes {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let e: Episode = serde_json::from_str(line)
            .with_context(|| format!("{}:{}: an episode", path.display(), i + 1))?;
        let finite = e.start.iter().chain(&e.goal).all(|v| v.is_finite());
        if !(finite && e.duration_s.is_finite() && e.duration_s > 0.0) {
            crate::error::bail!(
                "{}:{}: an episode needs a finite start and goal and a positive duration_s",
                path.display(),
                i + 1
            );
        }
        out.push(e);
    }
    if out.is_empty() {
        crate::error::bail!("{}: no episode", path.display());
    }
    Ok(out)
}

/// One line of the episode output: the episode's id and its summary (the fields of
/// [`Summary`], for this episode alone).
#[derive(Debug, Serialize)]
pub struct EpisodeLine<'a> {
    /// [`Episode::id`].
    pub episode: u64,
    /// The episode's figures.
    #[serde(flatten)]
    pub summary: &'a Summary,
}

/// The true pose counts as at the start within this, m (a teleport puts it there exactly).
const PLACED_M: f64 = 0.02;
/// A pose estimate counts as at the start within this, m (Localization and SLAM restart
/// there exactly; the filter may move by a GPS fix or two before it is read).
const ESTIMATE_M: f64 = 0.15;
/// Simulated time the teleport, the estimates and the Manager have to answer, s.
const ANSWER_S: f64 = 5.0;
/// The pose estimates count only when stamped this long (simulated s) after the true pose was
/// first seen at the start: Localization and SLAM read the estimate at their next call, and
/// an estimate applied after the robot has begun to move would put it back at the start.
/// Without this, a robot already at the next start (the previous goal) got its goal before
/// the reset and was then reset while driving (a goal missed by 0.66 m).
const SETTLE_S: f64 = 0.5;
/// The robot is moved only when the Manager has held no goal this long (simulated s): the
/// Servo follows Planning's last waypoint for up to its `waypoint_timeout_s` (1 s), and a
/// robot moved before that was driven off its new start by the previous problem's waypoint.
const QUIET_S: f64 = 1.5;

/// Where an episode is.
#[derive(Debug, Clone, Copy)]
enum Phase {
    /// Waiting for the system: the simulator running, the Manager without a goal.
    Ready,
    /// The robot sent to the start at simulated time `at` (s); the true pose seen there
    /// first at `placed` (its stamp), when the pose estimate was sent; the estimates count
    /// when stamped from `settle` on; `refused`: the simulator's count of refused teleports
    /// when this one was sent.
    Placing {
        at: f64,
        placed: Option<f64>,
        settle: f64,
        refused: u64,
    },
    /// The goal sent at `at`; it will be the monitor's goal number `index`.
    Sent { at: f64, index: usize },
    /// The goal is pursued.
    Running { index: usize },
}

/// The counters when an episode's goal was given.
#[derive(Debug, Clone, Copy)]
struct Base {
    sim_s: f64,
    path_m: f64,
    collisions: u64,
    restarts: u64,
    stuck_s: f64,
    lost: u64,
}

/// A pose estimate watched: channel, reader, latest (stamp s, x, y).
type PoseWatch = (
    String,
    hng_runtime::Subscriber<PoseWithCovariance>,
    Option<(f64, f64, f64)>,
);

/// The episodes of a run and where they are.
pub(super) struct Runner {
    list: Vec<Episode>,
    next: usize,
    out: Option<PathBuf>,
    tolerance_m: f64,
    /// The run started at the first episode's start: no teleport for it.
    first_placed: bool,
    teleport: Publisher<SimTeleport>,
    estimate: Publisher<PoseWithCovariance>,
    mission: Publisher<Mission>,
    /// Pose estimates that must be at the start before the goal is given: channel, reader,
    /// latest (stamp s, x, y).
    poses: Vec<PoseWatch>,
    phase: Phase,
    base: Option<Base>,
    wall: Instant,
    failed: usize,
}

/// What the monitor needs for episodes.
#[derive(Debug, Clone)]
pub struct EpisodeOptions {
    /// The episodes, in order.
    pub list: Vec<Episode>,
    /// Append each episode's summary line to this file (JSON lines).
    pub out: Option<PathBuf>,
    /// Position tolerance of the goals, m.
    pub tolerance_m: f64,
    /// Pose estimates (state channels of `PoseWithCovariance`) that must be at an episode's
    /// start before its goal is given (e.g. `localization/pose`).
    pub pose_channels: Vec<String>,
    /// The system started with the robot at the first episode's start.
    pub first_placed: bool,
}

impl Runner {
    pub(super) fn new(node: &Node, o: &EpisodeOptions) -> Result<Runner> {
        let mut poses = Vec::new();
        for c in &o.pose_channels {
            poses.push((
                c.clone(),
                node.tap_subscriber::<PoseWithCovariance>(c)?,
                None,
            ));
        }
        Ok(Runner {
            list: o.list.clone(),
            next: 0,
            out: o.out.clone(),
            tolerance_m: o.tolerance_m,
            first_placed: o.first_placed,
            teleport: node.publisher::<SimTeleport>("sim/teleport")?,
            estimate: node.publisher::<PoseWithCovariance>(INITIAL_POSE_CHANNEL)?,
            mission: node.publisher::<Mission>(MISSION_CHANNEL)?,
            poses,
            phase: Phase::Ready,
            base: None,
            wall: Instant::now(),
            failed: 0,
        })
    }

    fn read_poses(&mut self) -> Result<()> {
        for (_, sub, last) in &mut self.poses {
            while let Some(p) = sub.receive()? {
                *last = Some((p.header.stamp_ns as f64 * 1e-9, p.pose.x, p.pose.y));
            }
        }
        Ok(())
    }

    fn send<T: hng_runtime::msg::Message>(p: &Publisher<T>, m: T) -> Result<()> {
        p.update_connections();
        p.publish(m)
            .with_context(|| format!("publishing on {}", p.channel()))
    }
}

fn map_header() -> Header {
    Header {
        frame_id: FrameId::MAP,
        ..Header::default()
    }
}

fn near(a: (f64, f64), b: (f64, f64), d: f64) -> bool {
    (a.0 - b.0).hypot(a.1 - b.1) <= d
}

impl State {
    /// Moves the episodes on; `Some(failure)` when the last one is done (`None`: all
    /// succeeded).
    pub(super) fn step_episodes(&mut self) -> Result<Option<Option<String>>> {
        let Some(mut r) = self.episodes.take() else {
            return Ok(None);
        };
        let out = self.step_runner(&mut r);
        self.episodes = Some(r);
        out
    }

    fn step_runner(&mut self, r: &mut Runner) -> Result<Option<Option<String>>> {
        r.read_poses()?;
        let now = self.sim_time_s;
        loop {
            let Some(ep) = r.list.get(r.next).cloned() else {
                let failure = (r.failed > 0)
                    .then(|| format!("{} of {} episodes failed", r.failed, r.list.len()));
                return Ok(Some(failure));
            };
            let start = (ep.start[0], ep.start[1]);
            let start_pose = Pose2D::new(ep.start[0], ep.start[1], ep.start[2]);
            // The first episode starts where the run began: nothing to move or to tell.
            let moved = !(r.next == 0 && r.first_placed);
            match r.phase {
                Phase::Ready => {
                    // The simulator runs (a true pose came) and the Manager holds no goal.
                    let quiet = self.idle_since.is_some_and(|t| now >= t + QUIET_S);
                    if self.log.is_empty() || !quiet {
                        return Ok(None);
                    }
                    r.wall = Instant::now();
                    if moved {
                        Runner::send(
                            &r.teleport,
                            SimTeleport {
                                header: map_header(),
                                pose: start_pose,
                            },
                        )?;
                    }
                    r.phase = Phase::Placing {
                        at: now,
                        placed: None,
                        settle: f64::INFINITY,
                        refused: self.teleports_refused,
                    };
                }
                Phase::Placing {
                    at,
                    mut placed,
                    mut settle,
                    refused,
                } => {
                    if placed.is_none() {
                        placed = self
                            .log
                            .poses()
                            .rev()
                            .take_while(|(t, _, _)| *t as f64 * 1e-9 >= at)
                            .find(|(_, x, y)| near((*x, *y), start, PLACED_M))
                            .map(|(t, _, _)| *t as f64 * 1e-9);
                        if placed.is_some() {
                            // The estimate only once the robot is there (a refused teleport
                            // must not reset the localization elsewhere); it counts from the
                            // latest true pose read on (the monitor reads as it goes).
                            let latest = self
                                .log
                                .poses()
                                .next_back()
                                .map_or(now, |(t, _, _)| *t as f64 * 1e-9);
                            settle = latest + SETTLE_S;
                            if moved {
                                Runner::send(
                                    &r.estimate,
                                    PoseWithCovariance {
                                        header: map_header(),
                                        pose: start_pose,
                                        covariance: [0.0; 9],
                                    },
                                )?;
                            }
                        }
                        r.phase = Phase::Placing {
                            at,
                            placed,
                            settle,
                            refused,
                        };
                    }
                    let off: Vec<String> = r
                        .poses
                        .iter()
                        .filter(|(_, _, l)| {
                            !l.is_some_and(|(t, x, y)| {
                                t >= settle && near((x, y), start, ESTIMATE_M)
                            })
                        })
                        .map(|(c, _, l)| match l {
                            Some((_, x, y)) => format!("{c} at ({x:.2}, {y:.2})"),
                            None => format!("{c} silent"),
                        })
                        .collect();
                    let placed = placed.is_some();
                    if placed && off.is_empty() {
                        self.give_goal(r, &ep)?;
                        continue;
                    }
                    // The simulator publishes its status at once when it refuses a teleport.
                    let turned_down = !placed && self.teleports_refused > refused;
                    if !turned_down && now - at <= ANSWER_S {
                        return Ok(None);
                    }
                    let why = if turned_down {
                        format!(
                            "the robot could not be put at the start ({:.2}, {:.2}): the simulator \
                             refused the teleport (the start overlaps an obstacle or is not finite)",
                            start.0, start.1
                        )
                    } else if !placed {
                        format!(
                            "the robot was not at the start ({:.2}, {:.2}) within {ANSWER_S} s \
                             simulated (no answer from the simulator to the teleport)",
                            start.0, start.1
                        )
                    } else {
                        format!(
                            "the pose estimate did not come to the start within {ANSWER_S} s simulated: {}",
                            off.join(", ")
                        )
                    };
                    self.end_episode(r, &ep, None, Some(why))?;
                }
                Phase::Sent { at, index } => {
                    if self.goals.len() > index {
                        r.phase = Phase::Running { index };
                        continue;
                    }
                    if now - at <= ANSWER_S {
                        return Ok(None);
                    }
                    let why =
                        format!("the Manager did not take the goal within {ANSWER_S} s simulated");
                    self.end_episode(r, &ep, None, Some(why))?;
                }
                Phase::Running { index } => {
                    let Some(base) = r.base else {
                        return Ok(None);
                    };
                    let g = &self.goals[index];
                    // Dealt with: the counters must have caught up with that moment.
                    if let Some(GoalTimes {
                        dealt: Some((t, _)),
                        ..
                    }) = self.goal_times.get(&g.id)
                        && self.sim_time_s < *t
                    {
                        return Ok(None);
                    }
                    let collisions = self.collisions.saturating_sub(base.collisions);
                    let why = if collisions > 0 {
                        Some(format!(
                            "the robot collided with an obstacle ({collisions} contacts)"
                        ))
                    } else {
                        match g.state.as_str() {
                            "reached" => None,
                            "missed" | "refused" => Some(format!(
                                "goal {} {}: {}",
                                g.id,
                                g.state,
                                g.reason.as_deref().unwrap_or("no reason given")
                            )),
                            _ if now - base.sim_s > ep.duration_s => Some(format!(
                                "the goal took longer than its duration ({} s simulated){}",
                                ep.duration_s,
                                self.last_pos
                                    .map(|p| format!(
                                        "; the true pose is {:.2} m from the goal",
                                        (p.0 - g.x).hypot(p.1 - g.y)
                                    ))
                                    .unwrap_or_default()
                            )),
                            _ => return Ok(None),
                        }
                    };
                    self.end_episode(r, &ep, Some(index), why)?;
                }
            }
        }
    }

    /// Sends the episode's goal to the Manager and takes the counters.
    fn give_goal(&mut self, r: &mut Runner, ep: &Episode) -> Result<()> {
        let goal = MissionGoal {
            pose: Pose2D::new(ep.goal[0], ep.goal[1], 0.0),
            tolerance_m: r.tolerance_m,
            use_theta: 0,
        };
        Runner::send(&r.mission, Mission::new(MissionOp::Append, &[goal]))?;
        self.idle_since = None;
        self.episode_min_clearance = f64::INFINITY;
        r.base = Some(Base {
            sim_s: self.sim_time_s,
            path_m: self.path_before_m + self.path_length_m,
            collisions: self.collisions,
            restarts: self.restarts,
            stuck_s: self.nav.stuck_time_s(),
            lost: self.truth.stats().dropped,
        });
        r.phase = Phase::Sent {
            at: self.sim_time_s,
            index: self.goals.len(),
        };
        Ok(())
    }

    /// Ends the current episode (its goal, if it got one, `index`; `why`: its failure):
    /// cancels a goal still pursued, writes the line, goes on with the next.
    fn end_episode(
        &mut self,
        r: &mut Runner,
        ep: &Episode,
        index: Option<usize>,
        why: Option<String>,
    ) -> Result<()> {
        let goal = index.and_then(|i| self.goals.get(i)).cloned();
        let settled = goal
            .as_ref()
            .is_some_and(|g| matches!(g.state.as_str(), "reached" | "missed" | "refused"));
        if goal.is_some() && !settled {
            // Give it up: the Manager holds, the next episode waits for that.
            Runner::send(&r.mission, Mission::new(MissionOp::Skip, &[]))?;
            self.idle_since = None;
        }
        let base = r.base.take();
        let mut g = goal.unwrap_or_else(|| GoalSummary {
            id: 0,
            x: ep.goal[0],
            y: ep.goal[1],
            tolerance_m: r.tolerance_m,
            state: "pending".to_owned(),
            reason: why.clone(),
            true_error_m: None,
        });
        if g.true_error_m.is_none() {
            g.true_error_m = self.last_pos.map(|(x, y)| (x - g.x).hypot(y - g.y));
        }
        let (stalls, recoveries) = if g.id > 0 {
            self.nav.goal_counts(g.id)
        } else {
            (0, 0)
        };
        let success = why.is_none();
        let times = self.goal_times.get(&g.id).copied();
        let summary = match base {
            Some(b) => Summary {
                success,
                goals_reached: u32::from(success),
                goals_total: 1,
                goals: vec![g],
                // From the Manager taking the goal to its dealing with it (the stamps of its
                // documents): the monitor, outside the lockstep, may read them late.
                sim_time_s: match times {
                    Some(t) => t.dealt.map_or(self.sim_time_s, |d| d.0) - t.taken_s,
                    None => self.sim_time_s - b.sim_s,
                }
                .max(0.0),
                wall_time_s: r.wall.elapsed().as_secs_f64(),
                // Between the same two stamps where known (the goal dealt with).
                path_length_m: match times.and_then(|t| Some((t.taken_path_m?, t.dealt?.1?))) {
                    Some((from, to)) => (to - from).max(0.0),
                    None => (self.path_before_m + self.path_length_m - b.path_m).max(0.0),
                },
                min_obstacle_distance_m: self
                    .episode_min_clearance
                    .is_finite()
                    .then_some(self.episode_min_clearance),
                collisions: self.collisions.saturating_sub(b.collisions),
                contract_switches: 0,
                restarts: self.restarts.saturating_sub(b.restarts),
                stuck_time_s: (self.nav.stuck_time_s() - b.stuck_s).max(0.0),
                stalls,
                recoveries,
                true_poses_lost: self.truth.stats().dropped.saturating_sub(b.lost),
                failure: why.clone(),
            },
            None => Summary {
                success,
                goals_total: 1,
                goals: vec![g],
                wall_time_s: r.wall.elapsed().as_secs_f64(),
                failure: why.clone(),
                ..Summary::default()
            },
        };
        let mut why_said = why.clone().unwrap_or_default();
        if summary.restarts > 0 {
            why_said.push_str(&format!(
                " ({} module restart(s) during it)",
                summary.restarts
            ));
        }
        self.say(&format!(
            "episode {} ({} of {}): {}",
            ep.id,
            r.next + 1,
            r.list.len(),
            if success {
                "ok".to_owned()
            } else {
                format!("FAILED: {why_said}")
            }
        ));
        if !success {
            r.failed += 1;
        }
        if let Some(path) = &r.out {
            let line = serde_json::to_string(&EpisodeLine {
                episode: ep.id,
                summary: &summary,
            })
            .context("encoding an episode's summary")?;
            let mut f = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .with_context(|| format!("opening {}", path.display()))?;
            // One write of the whole line: a reader sees whole lines or nothing of it.
            f.write_all(format!("{line}\n").as_bytes())
                .with_context(|| format!("writing {}", path.display()))?;
        }
        r.next += 1;
        r.phase = Phase::Ready;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_episode_file_is_read_and_its_errors_name_the_line() {
        let dir = std::env::temp_dir().join(format!("hng-episodes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("e.jsonl");
        std::fs::write(
            &f,
            "# two\n{\"id\": 3, \"start\": [1, 2, 0.5], \"goal\": [4, 5], \"duration_s\": 30}\n\n\
             {\"id\": 4, \"start\": [4, 5, 0], \"goal\": [1, 2], \"duration_s\": 20}\n",
        )
        .unwrap();
        let e = read_episodes(&f).unwrap();
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].start, [1.0, 2.0, 0.5]);
        assert_eq!((e[1].id, e[1].goal, e[1].duration_s), (4, [1.0, 2.0], 20.0));
        std::fs::write(
            &f,
            "{\"id\": 3, \"start\": [1, 2, 0], \"goal\": [4, 5], \"duration_s\": 30}\n\
             {\"id\": 4, \"start\": [1, 2, 0], \"goal\": [4, 5], \"duration_s\": -1}\n",
        )
        .unwrap();
        let why = format!("{:#}", read_episodes(&f).unwrap_err());
        assert!(
            why.contains("e.jsonl:2") && why.contains("duration_s"),
            "{why}"
        );
        std::fs::write(&f, "{\"id\": 3, \"goal\": [4, 5]}\n").unwrap();
        let why = format!("{:#}", read_episodes(&f).unwrap_err());
        assert!(why.contains("e.jsonl:1"), "{why}");
        std::fs::write(&f, "# nothing\n").unwrap();
        assert!(read_episodes(&f).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
