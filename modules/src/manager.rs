//! Manager: holds the mission (Table 1: needs "Robot integrity" and "Human control"; the
//! root of the contract tree).
//!
//! The mission is an ordered list of objectives: 1 robot integrity, 2 human control, then the
//! goals. The first two are standing objectives served by Security and the human interface;
//! the goals are pursued one after the other: the current one is published as a [`Goal`] on
//! `goal_out` (a state channel, so a restarted Planning gets it at once); a [`GoalStatus`]
//! `Reached` (from the Servo-controller) or `Refused` (from Planning) for it moves to the next.
//! When every goal is dealt with, a goal with id 0 ("none") is published and the robot holds.
//! The mission changes while running through [`Mission`] messages on `mission_in`
//! (`hng/mission`): replace, append, clear, skip. Progress is published as [`MissionStatus`].
//!
//! Quality Q: 1 (the Manager is the mission; it can always evaluate itself). Checkpoint: the
//! whole mission with its progress, so a restarted Manager resumes at the same goal.

use hng_runtime::channel::InputId;
use hng_runtime::msg::{FrameId, Goal, Header};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{decode_state, encode_state, field_error};
use crate::msgs::{GoalState, GoalStatus, Mission, MissionGoal, MissionOp, MissionStatus};

/// The mission's standing objectives, most important first (their priorities are 1 and 2;
/// goals are pursued under "Human control").
pub const OBJECTIVES: [&str; 2] = ["Robot integrity", "Human control"];

/// A goal of the mission with its id.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlannedGoal {
    /// Unique id within the manager's life (never reused, also across restarts).
    pub id: u32,
    /// The goal.
    pub goal: MissionGoal,
}

/// How a goal ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Outcome {
    /// Reached.
    Reached,
    /// Refused by Planning, or skipped.
    Refused,
}

/// The mission logic, without I/O.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MissionCore {
    goals: Vec<PlannedGoal>,
    outcomes: Vec<Outcome>,
    next_id: u32,
}

impl MissionCore {
    /// A mission with these goals.
    pub fn new(goals: &[MissionGoal]) -> MissionCore {
        let mut m = MissionCore {
            next_id: 1,
            ..Default::default()
        };
        m.append(goals);
        m
    }

    fn append(&mut self, goals: &[MissionGoal]) {
        for g in goals {
            self.goals.push(PlannedGoal {
                id: self.next_id,
                goal: *g,
            });
            self.next_id = self.next_id.wrapping_add(1).max(1);
        }
    }

    /// The goal being pursued.
    pub fn current(&self) -> Option<&PlannedGoal> {
        self.goals.get(self.outcomes.len())
    }

    /// Index of the current goal (= number of goals dealt with).
    pub fn index(&self) -> usize {
        self.outcomes.len()
    }

    /// Every goal dealt with.
    pub fn done(&self) -> bool {
        self.outcomes.len() >= self.goals.len()
    }

    /// A goal's status arrived; returns true if the mission moved on.
    pub fn on_status(&mut self, s: &GoalStatus) -> bool {
        let Some(cur) = self.current() else {
            return false;
        };
        if cur.id != s.goal_id {
            return false;
        }
        match s.goal_state() {
            GoalState::Reached => self.outcomes.push(Outcome::Reached),
            GoalState::Refused => self.outcomes.push(Outcome::Refused),
            GoalState::Active | GoalState::Idle => return false,
        }
        true
    }

    /// Applies a mission change; returns true if the current goal changed.
    pub fn apply(&mut self, op: MissionOp, goals: &[MissionGoal]) -> bool {
        let before = self.current().map(|g| g.id);
        match op {
            MissionOp::Replace => {
                self.goals.truncate(self.outcomes.len());
                self.append(goals);
            }
            MissionOp::Append => self.append(goals),
            MissionOp::Clear => self.goals.truncate(self.outcomes.len()),
            MissionOp::Skip => {
                if self.current().is_some() {
                    self.outcomes.push(Outcome::Refused);
                }
            }
        }
        self.current().map(|g| g.id) != before
    }

    /// The goal message to publish now (id 0 when there is none).
    pub fn goal_msg(&self) -> Goal {
        let header = Header {
            frame_id: FrameId::MAP,
            ..Header::default()
        };
        match self.current() {
            Some(g) => Goal {
                header,
                id: g.id,
                pose: g.goal.pose,
                tolerance_m: g.goal.tolerance_m,
                use_theta: g.goal.use_theta,
            },
            None => Goal {
                header,
                ..Default::default()
            },
        }
    }

    /// The progress message.
    pub fn status_msg(&self) -> MissionStatus {
        let count = |o: Outcome| self.outcomes.iter().filter(|&&x| x == o).count() as u32;
        MissionStatus {
            header: Header::default(),
            goals_total: self.goals.len() as u32,
            goals_reached: count(Outcome::Reached),
            goals_refused: count(Outcome::Refused),
            current: self.outcomes.len() as u32,
            current_goal_id: self.current().map_or(0, |g| g.id),
            done: u8::from(self.done()),
        }
    }
}

/// A goal in the Manager's configuration.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalConfig {
    /// x, m (map frame).
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// Final heading, rad (optional; ignored if absent).
    pub theta: Option<f64>,
    /// Position tolerance, m (default 0.2).
    pub tolerance: Option<f64>,
}

/// Configuration of `hng module manager`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ManagerConfig {
    /// The goals, in order.
    pub goals: Vec<GoalConfig>,
    /// Current goal out (default `manager/goal`).
    pub goal_out: String,
    /// Goal statuses in (default `servo/status` and `planning/status`).
    pub status_in: Vec<String>,
    /// Mission changes in (default `hng/mission`).
    pub mission_in: String,
    /// Progress out (default `manager/status`).
    pub status_out: String,
}

impl Default for ManagerConfig {
    fn default() -> Self {
        ManagerConfig {
            goals: Vec::new(),
            goal_out: "manager/goal".into(),
            status_in: vec!["servo/status".into(), "planning/status".into()],
            mission_in: "hng/mission".into(),
            status_out: "manager/status".into(),
        }
    }
}

/// Checks and converts configured goals.
pub fn mission_goals(goals: &[GoalConfig]) -> Result<Vec<MissionGoal>, crate::common::ConfigError> {
    goals
        .iter()
        .enumerate()
        .map(|(i, g)| {
            let tol = g.tolerance.unwrap_or(0.2);
            if !(g.x.is_finite() && g.y.is_finite() && g.theta.is_none_or(f64::is_finite)) {
                return Err(field_error(
                    format!("goals[{i}]"),
                    "coordinates must be finite",
                ));
            }
            if !(tol.is_finite() && tol > 0.0) {
                return Err(field_error(format!("goals[{i}].tolerance"), "must be > 0"));
            }
            Ok(MissionGoal {
                pose: hng_runtime::msg::Pose2D {
                    x: g.x,
                    y: g.y,
                    theta: g.theta.unwrap_or(0.0),
                },
                tolerance_m: tol,
                use_theta: u8::from(g.theta.is_some()),
            })
        })
        .collect()
}

/// The Manager module.
pub struct ManagerModule {
    core: MissionCore,
    goal_out: Publisher<Goal>,
    status_out: Publisher<MissionStatus>,
    status_in: Vec<Subscriber<GoalStatus>>,
    mission_in: Subscriber<Mission>,
}

impl std::fmt::Debug for ManagerModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManagerModule")
            .field("core", &self.core)
            .finish_non_exhaustive()
    }
}

impl ManagerModule {
    fn publish(&mut self, ctx: &Context) -> ModuleResult {
        let g = self.core.goal_msg();
        if g.id == 0 {
            tracing::info!(module = ctx.name(), status = ?self.core.status_msg(), "mission done");
        } else {
            tracing::info!(
                module = ctx.name(),
                goal = g.id,
                x = g.pose.x,
                y = g.pose.y,
                "next goal"
            );
        }
        self.goal_out.publish(g)?;
        self.status_out.publish(self.core.status_msg())?;
        Ok(())
    }
}

impl Module for ManagerModule {
    type Config = ManagerConfig;

    fn configure(ctx: &mut Context, cfg: ManagerConfig) -> ModuleResult<Self> {
        let goals = mission_goals(&cfg.goals)?;
        // The Manager's objectives, in order: "Robot integrity" (priority 1, Security) and
        // "Reach goal" (priority 2, Planning), which activates the navigation subtree.
        // CONTRACTS: "Human control" in place of "Reach goal" (the Interface would then need
        // "Reach goal") once an Interface module exists.
        ctx.manager(&["Robot integrity", "Reach goal"]);
        let mut status_in = Vec::new();
        for c in &cfg.status_in {
            status_in.push(ctx.subscribe::<GoalStatus>(c, None)?);
        }
        ctx.set_quality(true, 1.0);
        Ok(ManagerModule {
            core: MissionCore::new(&goals),
            goal_out: ctx.publisher(&cfg.goal_out)?,
            status_out: ctx.publisher(&cfg.status_out)?,
            status_in,
            mission_in: ctx.subscribe(&cfg.mission_in, None)?,
        })
    }

    fn start(&mut self, ctx: &mut Context) -> ModuleResult {
        tracing::info!(
            module = ctx.name(),
            objectives = ?OBJECTIVES,
            goals = self.core.status_msg().goals_total,
            "mission"
        );
        self.publish(ctx)
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        let mut changed = false;
        if input == self.mission_in.id() {
            while let Some(m) = self.mission_in.receive()? {
                let Some(op) = MissionOp::from_u8(m.op) else {
                    tracing::warn!(
                        module = ctx.name(),
                        op = m.op,
                        "unknown mission operation ignored"
                    );
                    continue;
                };
                tracing::info!(
                    module = ctx.name(),
                    ?op,
                    goals = m.goals().len(),
                    "mission changed"
                );
                self.core.apply(op, m.goals());
                changed = true; // publish the new totals even if the goal stays
            }
        } else if let Some(sub) = self.status_in.iter().find(|s| s.id() == input) {
            while let Some(s) = sub.receive()? {
                if self.core.on_status(&s) {
                    let state = s.goal_state();
                    tracing::info!(module = ctx.name(), goal = s.goal_id, ?state, "goal done");
                    changed = true;
                }
            }
        }
        if changed {
            self.publish(ctx)?;
        }
        Ok(())
    }

    fn checkpoint(&self) -> Option<Vec<u8>> {
        encode_state(&self.core)
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        self.core = decode_state(state)?;
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use hng_runtime::msg::Pose2D;

    fn g(x: f64) -> MissionGoal {
        MissionGoal {
            pose: Pose2D {
                x,
                y: 0.0,
                theta: 0.0,
            },
            tolerance_m: 0.2,
            use_theta: 0,
        }
    }

    fn status(id: u32, s: GoalState) -> GoalStatus {
        GoalStatus {
            goal_id: id,
            state: s as u8,
            ..Default::default()
        }
    }

    #[test]
    fn manager_sequences_goals_on_reached_and_refused() {
        let mut m = MissionCore::new(&[g(1.0), g(2.0), g(3.0)]);
        assert_eq!(m.goal_msg().id, 1);
        assert!(!m.on_status(&status(1, GoalState::Active)));
        assert!(
            !m.on_status(&status(2, GoalState::Reached)),
            "not the current goal"
        );
        assert!(m.on_status(&status(1, GoalState::Reached)));
        assert_eq!(m.goal_msg().pose.x, 2.0);
        assert!(m.on_status(&status(2, GoalState::Refused)));
        assert!(
            !m.on_status(&status(1, GoalState::Reached)),
            "stale report of goal 1"
        );
        assert!(m.on_status(&status(3, GoalState::Reached)));
        assert!(m.done());
        assert_eq!(m.goal_msg().id, 0, "no goal: hold");
        let s = m.status_msg();
        assert_eq!(
            (s.goals_total, s.goals_reached, s.goals_refused, s.done),
            (3, 2, 1, 1)
        );
    }

    #[test]
    fn mission_changes_while_running() {
        let mut m = MissionCore::new(&[g(1.0), g(2.0)]);
        assert!(m.on_status(&status(1, GoalState::Reached)));
        assert!(m.apply(MissionOp::Replace, &[g(5.0), g(6.0)]));
        assert_eq!(m.goal_msg().pose.x, 5.0);
        assert_eq!(m.goal_msg().id, 3, "ids are never reused");
        assert!(!m.apply(MissionOp::Append, &[g(7.0)]));
        assert_eq!(m.status_msg().goals_total, 4);
        assert!(m.apply(MissionOp::Skip, &[]));
        assert_eq!(m.goal_msg().pose.x, 6.0);
        assert!(m.apply(MissionOp::Clear, &[]));
        assert!(m.done() && m.goal_msg().id == 0);
        assert!(
            m.apply(MissionOp::Append, &[g(8.0)]),
            "a goal after the end restarts"
        );
        assert_eq!(m.goal_msg().pose.x, 8.0);
        // Checkpoint round trip.
        let bytes = encode_state(&m).unwrap();
        let back: MissionCore = decode_state(&bytes).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn configured_goals_are_checked() {
        let ok = mission_goals(&[GoalConfig {
            x: 1.0,
            y: 2.0,
            theta: Some(0.5),
            tolerance: None,
        }])
        .unwrap();
        assert_eq!(ok[0].use_theta, 1);
        let e = mission_goals(&[GoalConfig {
            x: 1.0,
            y: 2.0,
            theta: None,
            tolerance: Some(-1.0),
        }])
        .unwrap_err();
        assert!(e.to_string().contains("goals[0].tolerance"), "{e}");
    }
}
