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
//! (`hng/mission`, sent by `hng mission set|add|clear|skip`): replace, append, clear, skip.
//! Progress is published as [`MissionStatus`], and the whole mission as a JSON
//! [`MissionPlan`] on `plan_out` (`manager/mission`, a state channel read by `hng mission show`).
//!
//! Quality Q: 1 (the Manager is the mission; it can always evaluate itself). Checkpoint: the
//! whole mission with its progress, so a restarted Manager resumes at the same goal.

use hng_runtime::channel::InputId;
use hng_runtime::msg::{FrameId, Goal, Header};
use hng_runtime::system::JsonInfo;
use hng_runtime::{Context, Module, ModuleResult, Publisher, SlicePublisher, Subscriber};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::field_error;
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

/// One goal of a [`MissionPlan`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanEntry {
    /// The goal's id.
    pub id: u32,
    /// x, m (map frame).
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// Final heading, rad, when it matters.
    pub theta: Option<f64>,
    /// Position tolerance, m.
    pub tolerance_m: f64,
    /// `reached`, `refused`, `active` (the current goal) or `pending`.
    pub state: String,
    /// Why a refused goal was refused (`outside the map`, `unreachable`, ..., or `skipped`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The whole mission as the Manager holds it: the JSON document on `plan_out`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MissionPlan {
    /// Mission changes applied by this Manager process (an acknowledgement for
    /// `hng mission`; starts at 0 again after a restart).
    pub revision: u64,
    /// Goals in the mission.
    pub goals_total: u32,
    /// Goals reached.
    pub goals_reached: u32,
    /// Goals refused or skipped.
    pub goals_refused: u32,
    /// Id of the current goal (0 when none).
    pub current_goal_id: u32,
    /// Every goal dealt with.
    pub done: bool,
    /// Every goal, in mission order.
    pub goals: Vec<PlanEntry>,
}

/// The mission logic, without I/O.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MissionCore {
    goals: Vec<PlannedGoal>,
    outcomes: Vec<Outcome>,
    next_id: u32,
    /// Why refused goals were refused, by goal id.
    #[serde(default)]
    reasons: std::collections::BTreeMap<u32, String>,
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
        let id = cur.id;
        match s.goal_state() {
            GoalState::Reached => self.outcomes.push(Outcome::Reached),
            GoalState::Refused => {
                let why = s
                    .refusal_reason()
                    .map_or("refused by Planning", |r| r.describe());
                self.reasons.insert(id, why.to_owned());
                self.outcomes.push(Outcome::Refused);
            }
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
                if let Some(id) = self.current().map(|g| g.id) {
                    self.reasons.insert(id, "skipped".to_owned());
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

    /// The whole mission, for `hng mission show`.
    pub fn plan(&self, revision: u64) -> MissionPlan {
        let s = self.status_msg();
        let goals = self
            .goals
            .iter()
            .enumerate()
            .map(|(i, g)| {
                let state = match self.outcomes.get(i) {
                    Some(Outcome::Reached) => "reached",
                    Some(Outcome::Refused) => "refused",
                    None if i == self.outcomes.len() => "active",
                    None => "pending",
                };
                PlanEntry {
                    id: g.id,
                    x: g.goal.pose.x,
                    y: g.goal.pose.y,
                    theta: (g.goal.use_theta != 0).then_some(g.goal.pose.theta),
                    tolerance_m: g.goal.tolerance_m,
                    state: state.to_owned(),
                    reason: self.reasons.get(&g.id).cloned(),
                }
            })
            .collect();
        MissionPlan {
            revision,
            goals_total: s.goals_total,
            goals_reached: s.goals_reached,
            goals_refused: s.goals_refused,
            current_goal_id: s.current_goal_id,
            done: s.done != 0,
            goals,
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
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct ManagerConfig {
    /// The goals, in order.
    pub goals: Vec<GoalConfig>,
    /// Current goal out (default `manager/goal`).
    #[default("manager/goal".into())]
    pub goal_out: String,
    /// Goal statuses in (default `servo/status` and `planning/status`).
    #[default(vec!["servo/status".into(), "planning/status".into()])]
    pub status_in: Vec<String>,
    /// Mission changes in (default `hng/mission`).
    #[default("hng/mission".into())]
    pub mission_in: String,
    /// Progress out (default `manager/status`).
    #[default("manager/status".into())]
    pub status_out: String,
    /// The whole mission as JSON out (default `manager/mission`).
    #[default(MISSION_PLAN_CHANNEL.into())]
    pub plan_out: String,
}

/// Default channel of the [`MissionPlan`] document.
pub const MISSION_PLAN_CHANNEL: &str = "manager/mission";

/// Default channel of mission changes.
pub const MISSION_CHANNEL: &str = "hng/mission";

/// Why a goal cannot be part of a mission.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum GoalProblem {
    /// A coordinate is NaN or infinite.
    #[error("coordinates must be finite")]
    Coordinates,
    /// A coordinate is farther than [`MAX_COORDINATE_M`] from the origin: no map is that big.
    #[error("coordinates must be within ±{MAX_COORDINATE_M} m of the map origin")]
    Range,
    /// The tolerance is not a positive number.
    #[error("tolerance must be > 0")]
    Tolerance,
}

/// Largest goal coordinate accepted, m (1000 km: beyond any map a robot plans in; a goal
/// inside this bound but outside the map is refused by Planning, with the map's bounds).
pub const MAX_COORDINATE_M: f64 = 1.0e6;

/// Checks a goal (`None`: it can be part of a mission).
pub fn goal_problem(g: &MissionGoal) -> Option<GoalProblem> {
    if !(g.pose.x.is_finite() && g.pose.y.is_finite() && g.pose.theta.is_finite()) {
        Some(GoalProblem::Coordinates)
    } else if g.pose.x.abs() > MAX_COORDINATE_M || g.pose.y.abs() > MAX_COORDINATE_M {
        Some(GoalProblem::Range)
    } else if !(g.tolerance_m.is_finite() && g.tolerance_m > 0.0) {
        Some(GoalProblem::Tolerance)
    } else {
        None
    }
}

/// Checks and converts configured goals.
pub fn mission_goals(goals: &[GoalConfig]) -> Result<Vec<MissionGoal>, crate::common::ConfigError> {
    goals
        .iter()
        .enumerate()
        .map(|(i, g)| {
            let goal = MissionGoal {
                pose: hng_runtime::msg::Pose2D::new(g.x, g.y, g.theta.unwrap_or(0.0)),
                tolerance_m: g.tolerance.unwrap_or(0.2),
                use_theta: u8::from(g.theta.is_some()),
            };
            match goal_problem(&goal) {
                None => Ok(goal),
                Some(GoalProblem::Tolerance) => {
                    Err(field_error(format!("goals[{i}].tolerance"), "must be > 0"))
                }
                Some(why) => Err(field_error(format!("goals[{i}]"), why.to_string())),
            }
        })
        .collect()
}

/// The Manager module.
#[derive(Debug)]
pub struct ManagerModule {
    core: MissionCore,
    goal_out: Publisher<Goal>,
    status_out: Publisher<MissionStatus>,
    plan_out: SlicePublisher<JsonInfo>,
    /// Mission changes applied (see [`MissionPlan::revision`]).
    revision: u64,
    status_in: Vec<Subscriber<GoalStatus>>,
    mission_in: Subscriber<Mission>,
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
        match serde_json::to_vec(&self.core.plan(self.revision)) {
            Ok(doc) => self.plan_out.publish_copy(JsonInfo::default(), &doc)?,
            Err(e) => tracing::warn!(module = ctx.name(), "mission document: {e}"),
        }
        Ok(())
    }
}

impl Module for ManagerModule {
    type Config = ManagerConfig;

    fn configure(ctx: &mut Context, cfg: ManagerConfig) -> ModuleResult<Self> {
        let goals = mission_goals(&cfg.goals)?;
        // The Manager's objectives, in order: "Robot integrity" (priority 1, Security) and
        // "Human control" (priority 2, the Interface, which needs "Reach goal": the goals are
        // pursued under Human control, paper 5.8).
        ctx.manager(&OBJECTIVES);
        let mut status_in = Vec::new();
        for c in &cfg.status_in {
            status_in.push(ctx.subscribe::<GoalStatus>(c, None)?);
        }
        ctx.set_quality(true, 1.0);
        Ok(ManagerModule {
            core: MissionCore::new(&goals),
            goal_out: ctx.publisher(&cfg.goal_out)?,
            status_out: ctx.publisher(&cfg.status_out)?,
            plan_out: ctx.slice_publisher(&cfg.plan_out, 4096)?,
            revision: 0,
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
                let Some(op) = MissionOp::from_repr(m.op) else {
                    tracing::warn!(
                        module = ctx.name(),
                        op = m.op,
                        "unknown mission operation ignored"
                    );
                    continue;
                };
                let goals: Vec<MissionGoal> = m
                    .goals()
                    .iter()
                    .enumerate()
                    .filter(|(i, g)| match goal_problem(g) {
                        Some(why) => {
                            tracing::warn!(module = ctx.name(), goal = i, "goal dropped: {why}");
                            false
                        }
                        None => true,
                    })
                    .map(|(_, g)| *g)
                    .collect();
                tracing::info!(
                    module = ctx.name(),
                    ?op,
                    goals = goals.len(),
                    "mission changed"
                );
                self.core.apply(op, &goals);
                self.revision += 1;
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

    hng_runtime::checkpoint_field!(core);
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
        let bytes = hng_runtime::module::encode_state(&m).unwrap();
        let back: MissionCore = hng_runtime::module::decode_state(&bytes).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn plan_lists_every_goal_with_its_state() {
        let mut m = MissionCore::new(&[g(1.0), g(2.0), g(3.0)]);
        assert!(m.on_status(&status(1, GoalState::Reached)));
        let p = m.plan(7);
        assert_eq!(p.revision, 7);
        let states: Vec<&str> = p.goals.iter().map(|e| e.state.as_str()).collect();
        assert_eq!(states, ["reached", "active", "pending"]);
        assert_eq!(
            (p.goals_total, p.goals_reached, p.current_goal_id),
            (3, 1, 2)
        );
        assert_eq!(p.goals[1].x, 2.0);
        assert!(p.goals[1].theta.is_none());
        let bad = MissionGoal {
            tolerance_m: 0.0,
            ..g(1.0)
        };
        assert_eq!(goal_problem(&bad), Some(GoalProblem::Tolerance));
        let mut nan = g(1.0);
        nan.pose.y = f64::NAN;
        assert_eq!(goal_problem(&nan), Some(GoalProblem::Coordinates));
    }

    #[test]
    fn refused_and_skipped_goals_keep_their_reason() {
        let mut m = MissionCore::new(&[g(1.0), g(2.0), g(3.0)]);
        let mut refused = status(1, GoalState::Refused);
        refused.reason = crate::msgs::RefusalReason::OutsideMap as u8;
        assert!(m.on_status(&refused));
        assert!(m.apply(MissionOp::Skip, &[]));
        let p = m.plan(0);
        assert_eq!(p.goals[0].reason.as_deref(), Some("outside the map"));
        assert_eq!(p.goals[1].reason.as_deref(), Some("skipped"));
        assert_eq!(p.goals[2].reason, None);
        let far = MissionGoal {
            pose: Pose2D::new(1e300, 1e300, 0.0),
            ..g(0.0)
        };
        assert_eq!(goal_problem(&far), Some(GoalProblem::Range));
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
