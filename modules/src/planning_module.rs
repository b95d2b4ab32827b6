//! Planning: reach goal (Table 1: provides "Reach goal", needs "Reach waypoint", "Mapping" and
//! a position; data in: goal, map, position; data out: waypoints).
//!
//! [`PlanningCore`] (pure logic) keeps the map inflated by the robot radius plus a clearance,
//! plans with the exact 8-connected A* ([`GridPlanner`]: no corner cutting, diagonal √2) from
//! the robot to the current goal, shortens the grid path by line of sight, and then, at every
//! pose, publishes one [`Waypoint`]: the point `lookahead_m` ahead of the robot's projection on
//! the path (the pure-pursuit carrot the Servo-controller steers to; `is_final` once it is the
//! goal itself), shorter and slower where the path passes near obstacles
//! ([`crate::planning::carrot`]). It replans when the goal or the map changes, or when the robot strays more
//! than `deviation_m` from the path.
//!
//! Goals outside the map, inside obstacles (after inflation, beyond the goal's tolerance) or
//! unreachable are refused: a [`GoalStatus`] `Refused`, an error in the log that says why,
//! Q = -1, and no waypoint (the servo then stops commanding and Security holds the robot).
//!
//! The map comes from its "Mapping" provider (Maps' surveyed map, or SLAM's), the position
//! from its "Localization" provider; until a provider is known, from the configured `map` and
//! `pose` channels.
//!
//! Its [`GoalStatus`] (`planning/status`, a state channel read by the Manager and the
//! Interface, which act on `Reached` and `Refused` only) goes out when the goal, its state or
//! the refusal reason change, and while `Active` only when the distance left has changed by
//! `status_step_m` (0.25 m) since the last one sent ([`StatusFilter`]): in lockstep every
//! message wakes its readers for a round of their own, and one `Active` status per pose
//! (50 Hz) cost the Manager and the Interface a round each at every odometry step.
//!
//! Quality Q: 1 while following a plan; 0 while waiting for a map, a pose or a goal; -1 when
//! the goal is refused.

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::{FollowProvider as _, ProviderInfo, ProviderInput, SliceProviderInput};
use hng_runtime::msg::{Goal, GridInfo, Pose2D, PoseWithCovariance, Waypoint};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{check_fields, non_negative, positive};
use crate::heartbeat::BusyHeartbeat;
use crate::maps::grid_from_msg;
use crate::msgs::GoalStatus;
use crate::planning::OccupancyGrid;
use crate::planning::path::PathOut;
use crate::planning::progress::NavProgress;

pub use crate::planning::config::PlanningModuleConfig;
pub use crate::planning::core::{PlanStep, PlanningCore, PlanningParams};

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct PlanningState {
    goal_id: u32,
    goal: Pose2D,
    tolerance_m: f64,
    use_theta: u8,
    plans: u64,
    refusals: u64,
}

/// Rank of Planning's "Reach waypoint" need (contract priority `P(planning).1`).
pub const WAYPOINT_NEED: u16 = 1;
/// Rank of Planning's "Mapping" need (contract priority `P(planning).2`).
pub const MAPPING_NEED: u16 = 2;
/// Rank of Planning's "Localization" need (contract priority `P(planning).3`).
pub const LOCALIZATION_NEED: u16 = 3;

/// Which goal statuses go out (see the [module documentation](self)).
#[derive(Debug, Clone, Copy)]
pub struct StatusFilter {
    step_m: f64,
    last: Option<GoalStatus>,
}

impl StatusFilter {
    /// Republishes an unchanged `Active` status after the distance left moved `step_m`.
    pub fn new(step_m: f64) -> StatusFilter {
        StatusFilter { step_m, last: None }
    }

    /// True when `s` is to be published (it is then the last one sent).
    pub fn wants(&mut self, s: &GoalStatus) -> bool {
        let same = self.last.is_some_and(|l| {
            l.goal_id == s.goal_id
                && l.state == s.state
                && l.reason == s.reason
                && (l.distance_m - s.distance_m).abs() < self.step_m
        });
        if !same {
            self.last = Some(*s);
        }
        !same
    }
}

/// The Planning module.
#[derive(Debug)]
pub struct PlanningModule {
    /// Heartbeats during long computations (`None` if its thread could not start).
    heartbeat: Option<std::rc::Rc<BusyHeartbeat>>,
    core: PlanningCore,
    /// The "Mapping" provider's maps (need rank [`MAPPING_NEED`]); the configured `map`
    /// channel's until one is known. A left channel is closed, not kept: on the way back a new
    /// subscription receives the provider's latest map (a state channel, published rarely).
    map: SliceProviderInput<GridInfo>,
    /// The latest map of each publisher seen on the map input (kept so that switching
    /// providers back and forth never leaves Planning without the provider's map).
    maps_seen: Vec<(u32, OccupancyGrid)>,
    /// The contracted "Localization" provider's pose (need rank [`LOCALIZATION_NEED`]); the
    /// configured `pose` channel's until one is known.
    localization: ProviderInput<PoseWithCovariance>,
    goal: Subscriber<Goal>,
    waypoint_out: Publisher<Waypoint>,
    status_out: Publisher<GoalStatus>,
    status_filter: StatusFilter,
    progress_out: Publisher<NavProgress>,
    path_out: PathOut,
    last_pose: Option<Pose2D>,
    state: PlanningState,
    /// Scans, and the rating of the Mapping provider by them (client feedback).
    map_rating: crate::feedback::MapRating,
    /// The Localization provider's poses against odometry: while they are in doubt the map is
    /// not rated (a wrong pose would blame a right map).
    pose_check: crate::feedback::PoseCheck,
}

impl PlanningModule {
    /// Reads the map inputs: the provider's maps only once it is known (the configured
    /// channel's, from any publisher, before).
    fn read_map(&mut self, ctx: &mut Context) -> ModuleResult {
        let hb = self.heartbeat.clone();
        let _busy = hb.as_ref().map(|h| h.busy(ctx));
        let mut use_now = None;
        while let Some(m) = self.map.receive_any()? {
            let from = m.header().header.source;
            let g = match grid_from_msg(m.header(), m.data()) {
                Ok(g) => g,
                Err(e) => {
                    tracing::warn!(module = ctx.name(), "map ignored: {e}");
                    continue;
                }
            };
            // Before a provider is known, the configured channel's maps are used.
            if self.map.accepts(from) {
                use_now = Some(from);
            }
            match self.maps_seen.iter_mut().find(|(s, _)| *s == from) {
                Some(e) => e.1 = g,
                None => self.maps_seen.push((from, g)),
            }
        }
        if let Some(from) = use_now
            && let Some((_, g)) = self.maps_seen.iter().find(|(s, _)| *s == from)
        {
            self.core.set_map(g);
            self.map_rating.rater.set_map(g);
        }
        Ok(())
    }

    fn step(&mut self, ctx: &mut Context) -> ModuleResult {
        let hb = self.heartbeat.clone();
        let _busy = hb.as_ref().map(|h| h.busy(ctx));
        let Some(pose) = self.last_pose else {
            return Ok(());
        };
        let now = ctx.now().as_secs_f64();
        let out = self.core.update_at(Some(now), &pose);
        for mut p in out.progress.iter().copied() {
            p.header.stamp_ns = u64::try_from(ctx.now().as_nanos()).unwrap_or(u64::MAX);
            if matches!(p.event, 1 | 4) {
                tracing::warn!(module = ctx.name(), "{}", p.describe());
            } else {
                tracing::info!(module = ctx.name(), "{}", p.describe());
            }
            self.progress_out.publish(p)?;
        }
        if out.replanned {
            self.state.plans += 1;
        }
        if let Some(why) = &out.refused {
            self.state.refusals += 1;
            tracing::error!(module = ctx.name(), "goal refused: {why}");
        }
        if let Some(why) = &out.pending {
            tracing::warn!(
                module = ctx.name(),
                "goal not in the map as it is ({why}); the map may still grow: planning again \
                 with the next map or Mapping provider"
            );
        }
        if let Some(w) = out.waypoint {
            self.waypoint_out.publish(w)?;
        }
        if let Some(s) = out.status
            && self.status_filter.wants(&s)
        {
            self.status_out.publish(s)?;
        }
        let goal_id = self.core.goal().map_or(0, |g| g.id);
        self.path_out
            .update(goal_id, self.core.path_points(), self.core.path_length())?;
        let q = if self.core.is_refused() {
            -1.0
        } else if self.core.has_path() {
            1.0
        } else {
            0.0
        };
        ctx.set_quality(true, q);
        Ok(())
    }
}

impl Module for PlanningModule {
    type Config = PlanningModuleConfig;

    fn configure(ctx: &mut Context, cfg: PlanningModuleConfig) -> ModuleResult<Self> {
        let p = &cfg.params;
        check_fields!(positive, p, "params"; robot_radius, lookahead_m, min_lookahead_m,
            comfort_m, deviation_m, speed)?;
        check_fields!(non_negative, p, "params"; inflation_m, cost_weight, cost_decay, clearance)?;
        // Provides "Reach goal" (needed by the Interface, under Human control) and needs
        // "Reach waypoint" (Servo; the waypoints go on `waypoint_out`), "Mapping" and
        // "Localization": the map and the pose come from the contracted providers, from `map`
        // and `pose` until they are known.
        positive("max_compute_s", cfg.max_compute_s)?;
        let max_compute = std::time::Duration::try_from_secs_f64(cfg.max_compute_s)
            .map_err(|e| crate::common::field_error("max_compute_s", e.to_string()))?;
        let heartbeat = match BusyHeartbeat::start(ctx, max_compute) {
            Ok(h) => Some(std::rc::Rc::new(h)),
            Err(e) => {
                tracing::warn!(
                    module = ctx.name(),
                    "no heartbeats during long computations: {e}"
                );
                None
            }
        };
        ctx.provide(ServiceOffer::new("Reach goal", ""))
            .need(NeedSpec::required("Reach waypoint", WAYPOINT_NEED))
            .need(NeedSpec::required("Mapping", MAPPING_NEED))
            .need(NeedSpec::required("Localization", LOCALIZATION_NEED));
        Ok(PlanningModule {
            heartbeat,
            core: PlanningCore::new(cfg.params),
            map: SliceProviderInput::new()
                .keep_left(0)
                .with_fallback(ctx, &cfg.map)?,
            maps_seen: Vec::new(),
            localization: ProviderInput::new().with_fallback(ctx, &cfg.pose)?,
            goal: ctx.subscribe(&cfg.goal, None)?,
            waypoint_out: ctx.publisher(&cfg.waypoint_out)?,
            status_out: ctx.publisher(&cfg.status_out)?,
            status_filter: StatusFilter::new(non_negative("status_step_m", cfg.status_step_m)?),
            progress_out: ctx.publisher(&cfg.progress_out)?,
            path_out: PathOut::new(ctx, &cfg.path_out)?,
            last_pose: None,
            state: PlanningState::default(),
            map_rating: crate::feedback::MapRating::new(ctx, &cfg.scan, cfg.map_feedback)?,
            pose_check: crate::feedback::PoseCheck::new(ctx, &cfg.odom, &cfg.initial_pose)?,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if self.map_rating.is(input) {
            let t = ctx.now().as_secs_f64();
            let pose = self
                .last_pose
                .filter(|_| !self.pose_check.rater.in_doubt(t));
            return self.map_rating.on_input(ctx, pose, MAPPING_NEED);
        }
        if self.map.is(input) {
            self.read_map(ctx)?;
        } else if input == self.goal.id() {
            while let Some(g) = self.goal.receive()? {
                self.core.set_goal(*g);
                self.state.goal_id = g.id;
                self.state.goal = g.pose;
                self.state.tolerance_m = g.tolerance_m;
                self.state.use_theta = g.use_theta;
            }
        } else if self.localization.is(input) {
            let t = ctx.now().as_secs_f64();
            self.pose_check.poll(t)?;
            while let Some(p) = self.localization.receive()? {
                self.pose_check.on_pose(&p, t);
                self.last_pose = Some(p.pose);
            }
        }
        self.step(ctx)
    }

    fn on_provider_changed(
        &mut self,
        ctx: &mut Context,
        need: u16,
        provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        let hb = self.heartbeat.clone();
        let _busy = hb.as_ref().map(|h| h.busy(ctx));
        if need == LOCALIZATION_NEED {
            self.localization.follow(ctx, provider)?;
            self.pose_check.rater.reset();
        } else if need == MAPPING_NEED {
            let changed = self.map.provider() != provider;
            self.map.follow(ctx, provider)?;
            // No provider: a switch is in flight (no refusal is final until it settles).
            self.core.set_provider_settled(provider.is_some());
            if changed {
                self.map_rating.rater.reset();
            }
            if changed && let Some(p) = provider {
                tracing::info!(module = ctx.name(), provider = %p.module, channel = %p.channel, "map from the Mapping provider");
                // Its map may have been seen already (a state channel, published rarely).
                self.read_map(ctx)?;
                if let Some((_, g)) = self.maps_seen.iter().find(|(s, _)| *s == p.module.0) {
                    self.core.set_map(g);
                    self.map_rating.rater.set_map(g);
                }
            }
        }
        Ok(())
    }

    hng_runtime::checkpoint_field!(state, Self::load_state);
}

impl PlanningModule {
    fn load_state(&mut self, s: PlanningState) -> ModuleResult {
        if s.goal_id != 0 {
            self.core.set_goal(Goal {
                id: s.goal_id,
                pose: s.goal,
                tolerance_m: s.tolerance_m,
                use_theta: s.use_theta,
                ..Default::default()
            });
        }
        self.state = s;
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
pub(crate) mod tests {
    use super::*;
    use crate::msgs::{GoalState, RefusalReason};
    use crate::planning::{FREE, OCCUPIED};

    #[test]
    fn an_active_status_goes_out_again_only_after_the_distance_moved_and_any_change_at_once() {
        let st = |goal_id, state: GoalState, distance_m, reason| GoalStatus {
            goal_id,
            state: state as u8,
            distance_m,
            reason,
            ..GoalStatus::default()
        };
        let mut f = StatusFilter::new(0.25);
        assert!(f.wants(&st(1, GoalState::Active, 10.0, 0)), "the first one");
        assert!(!f.wants(&st(1, GoalState::Active, 9.9, 0)));
        assert!(
            !f.wants(&st(1, GoalState::Active, 9.76, 0)),
            "0.24 m from the last sent"
        );
        assert!(f.wants(&st(1, GoalState::Active, 9.75, 0)), "0.25 m");
        assert!(!f.wants(&st(1, GoalState::Active, 9.7, 0)));
        assert!(f.wants(&st(2, GoalState::Active, 9.7, 0)), "another goal");
        assert!(f.wants(&st(2, GoalState::Refused, 9.7, 3)), "another state");
        assert!(!f.wants(&st(2, GoalState::Refused, 9.7, 3)));
        assert!(
            f.wants(&st(2, GoalState::Refused, 9.7, 4)),
            "another reason"
        );
        let mut every = StatusFilter::new(0.0);
        assert!((0..3).all(|_| every.wants(&st(1, GoalState::Active, 5.0, 0))));
    }

    /// A walled 10 x 6 m room at 0.1 m, split by a wall at x = 5 but for the cells `gap` of y.
    pub(crate) fn walled_room(gap: std::ops::Range<i64>) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(100, 60, 0.1, [0.0, 0.0], FREE).unwrap();
        for x in 0..100 {
            g.set(x, 0, OCCUPIED);
            g.set(x, 59, OCCUPIED);
        }
        for y in 0..60 {
            g.set(0, y, OCCUPIED);
            g.set(99, y, OCCUPIED);
            if !gap.contains(&y) {
                g.set(50, y, OCCUPIED);
            }
        }
        g
    }

    /// The room with a wall at x = 5 from y = 0 to y = 4 (a gap above).
    pub(crate) fn room() -> OccupancyGrid {
        walled_room(40..60)
    }

    fn goal(id: u32, x: f64, y: f64) -> Goal {
        Goal {
            id,
            pose: Pose2D { x, y, theta: 0.0 },
            tolerance_m: 0.2,
            ..Default::default()
        }
    }

    /// A planner with the default parameters in [`room`], given goal 1 at (`x`, `y`).
    fn in_room(x: f64, y: f64) -> PlanningCore {
        let mut p = PlanningCore::new(PlanningParams::default());
        p.set_map(&room());
        p.set_goal(goal(1, x, y));
        p
    }

    fn at(x: f64, y: f64) -> Pose2D {
        Pose2D { x, y, theta: 0.0 }
    }

    /// The module's own loop (in-process harness), with "Mapping" and "Localization" served
    /// by the test: it plans round the wall in the provider's map (a map on its fallback
    /// channel is not read), sends the carrot, and refuses a goal inside the wall.
    #[test]
    fn the_module_plans_in_the_providers_map_and_refuses_a_goal_in_a_wall() {
        use hng_runtime::harness::Harness;
        use std::time::Duration;
        let mut h = Harness::new("planning").unwrap();
        let map = h.slice_input::<GridInfo>("test/map", 6000).unwrap();
        // The fallback channel's map comes from a process of its own (as from Maps): from
        // the harness's own node it would have the provider's source, and the module could
        // not tell the two maps apart (the later one read would win).
        let maps = hng_runtime::Node::new(hng_runtime::NodeOptions::new("maps").prefix(h.prefix()))
            .unwrap();
        let blocked = maps.slice_publisher::<GridInfo>("maps/map", 6000).unwrap();
        let pose = h.input::<PoseWithCovariance>("test/pose").unwrap();
        let goals = h.input::<Goal>("manager/goal").unwrap();
        let mut waypoints = h.output::<Waypoint>("planning/waypoint").unwrap();
        let mut status = h.output::<GoalStatus>("planning/status").unwrap();
        h.provider(MAPPING_NEED, "test/map")
            .provider(LOCALIZATION_NEED, "test/pose");
        h.start::<PlanningModule>("").unwrap();
        let g = room();
        map.publish_copy(g.info(), g.data()).unwrap();
        let full = OccupancyGrid::new(100, 60, 0.1, [0.0, 0.0], OCCUPIED).unwrap();
        blocked.publish_copy(full.info(), full.data()).unwrap();
        goals.publish(goal(1, 8.0, 1.0)).unwrap();
        let robot = PoseWithCovariance {
            pose: at(2.0, 1.0),
            ..Default::default()
        };
        // A pose, again until the module answers (the map and the goal may be read after it).
        let mut answer = |h: &Harness, id: u32| {
            (0..50).find_map(|_| {
                pose.publish(robot).unwrap();
                h.wait_for(&mut status, Duration::from_millis(100), |s| s.goal_id == id)
                    .ok()
            })
        };
        let st = answer(&h, 1).expect("a status for goal 1");
        assert_eq!(st.goal_state(), GoalState::Active, "{st:?}");
        assert!(st.distance_m > 8.0, "detour through the gap: {st:?}");
        let w = h
            .wait_for(&mut waypoints, Duration::from_secs(5), |w| w.goal_id == 1)
            .unwrap();
        let d = (w.pose.x - 2.0).hypot(w.pose.y - 1.0);
        assert!((d - 0.6).abs() < 0.05, "carrot at the lookahead: {d}");

        goals.publish(goal(2, 5.0, 2.0)).unwrap();
        let st = answer(&h, 2).expect("a status for goal 2");
        assert_eq!(st.goal_state(), GoalState::Refused, "{st:?}");
        assert_eq!(st.refusal_reason(), Some(RefusalReason::InObstacle));
        h.finish().unwrap();
    }

    #[test]
    fn plans_around_the_wall_and_gives_a_carrot_ahead() {
        let mut p = in_room(8.0, 1.0);
        let s = p.update(&at(2.0, 1.0));
        assert!(s.replanned && s.refused.is_none(), "{s:?}");
        let w = s.waypoint.unwrap();
        assert_eq!(w.goal_id, 1);
        assert_eq!(w.is_final, 0);
        let d = (w.pose.x - 2.0).hypot(w.pose.y - 1.0);
        assert!((d - 0.6).abs() < 0.05, "carrot at the lookahead: {d}");
        let st = s.status.unwrap();
        assert_eq!(st.goal_state(), GoalState::Active);
        assert!(
            st.distance_m > 8.0,
            "detour through the gap: {}",
            st.distance_m
        );
        // Near the goal the carrot is the goal itself.
        let s = p.update(&at(7.8, 1.1));
        assert!(!s.replanned || s.waypoint.is_some());
        let w = s.waypoint.unwrap();
        assert_eq!(w.is_final, 1);
        assert_eq!((w.pose.x, w.pose.y), (8.0, 1.0));
    }

    #[test]
    fn replans_when_the_robot_strays_or_the_map_changes() {
        let mut p = in_room(8.0, 1.0);
        assert!(p.update(&at(2.0, 1.0)).replanned);
        assert!(!p.update(&at(2.1, 1.0)).replanned);
        assert!(p.update(&at(2.0, 3.0)).replanned, "1.9 m off the path");
        p.set_map(&room());
        assert!(p.update(&at(2.0, 3.0)).replanned);
    }

    #[test]
    fn planner_refuses_out_of_map_inside_obstacle_and_unreachable_goals() {
        let mut p = in_room(12.0, 1.0);
        let s = p.update(&at(2.0, 1.0));
        let why = s.refused.unwrap();
        assert!(why.contains("outside the map"), "{why}");
        assert_eq!(s.status.unwrap().goal_state(), GoalState::Refused);
        assert!(s.waypoint.is_none());
        assert!(p.is_refused());
        assert_eq!(p.update(&at(2.0, 1.0)), PlanStep::default(), "refused once");

        p.set_goal(goal(2, 5.0, 2.0));
        let why = p.update(&at(2.0, 1.0)).refused.unwrap();
        assert!(why.contains("inside an obstacle"), "{why}");

        let mut closed = room();
        for y in 40..60 {
            closed.set(50, y, OCCUPIED);
        }
        p.set_map(&closed);
        p.set_goal(goal(3, 8.0, 1.0));
        let why = p.update(&at(2.0, 1.0)).refused.unwrap();
        assert!(why.contains("unreachable"), "{why}");
    }

    #[test]
    fn a_refusal_in_a_map_that_may_grow_is_retried_and_final_only_in_the_known_map() {
        use crate::planning::UNKNOWN;
        let mut p = PlanningCore::new(PlanningParams::default());
        // A partial map (SLAM's): the right half is still unknown, the goal beyond the map.
        let mut partial = room();
        for x in 60..99 {
            for y in 1..59 {
                partial.set(x, y, UNKNOWN);
            }
        }
        p.set_map(&partial);
        p.set_goal(goal(1, 12.0, 1.0));
        let s = p.update(&at(2.0, 1.0));
        assert!(
            s.refused.is_none() && s.status.is_none(),
            "not final: {s:?}"
        );
        assert!(s.pending.unwrap().contains("outside the map"));
        assert!(!p.is_refused());
        // The map grows (a new map): planned again, still provisional.
        p.set_map(&partial);
        assert!(p.update(&at(2.0, 1.0)).pending.is_some());
        // A Mapping provider switch in flight: still provisional, even with a known map.
        p.set_provider_settled(false);
        p.set_map(&room());
        assert!(p.update(&at(2.0, 1.0)).pending.is_some());
        // Settled on the known map: the refusal is final, with its reason.
        p.set_provider_settled(true);
        let s = p.update(&at(2.0, 1.0));
        assert!(s.refused.unwrap().contains("outside the map"));
        let st = s.status.unwrap();
        assert_eq!(st.goal_state(), GoalState::Refused);
        assert_eq!(st.refusal_reason(), Some(RefusalReason::OutsideMap));
        assert!(p.is_refused());
        // A goal that the known map contains is planned after a provisional refusal.
        p.set_map(&partial);
        p.set_goal(goal(2, 12.0, 2.0));
        assert!(p.update(&at(2.0, 1.0)).pending.is_some());
        let mut bigger = OccupancyGrid::new(140, 60, 0.1, [0.0, 0.0], FREE).unwrap();
        for x in 0..140 {
            bigger.set(x, 0, OCCUPIED);
        }
        p.set_map(&bigger);
        let s = p.update(&at(2.0, 1.0));
        assert!(
            s.waypoint.is_some() && s.refused.is_none() && s.pending.is_none(),
            "{s:?}"
        );
    }

    #[test]
    fn a_position_outside_the_map_holds_without_refusing_the_goal() {
        let mut p = PlanningCore::new(PlanningParams::default());
        p.set_map(&room());
        p.set_goal(goal(1, 3.0, 3.0));
        let s = p.update(&at(-0.85, 3.0)); // a localization outlier
        assert!(s.refused.is_none() && s.waypoint.is_none(), "{s:?}");
        assert!(!p.is_refused());
        let s = p.update(&at(2.0, 1.0));
        assert!(s.refused.is_none() && s.waypoint.is_some(), "{s:?}");
    }

    #[test]
    fn a_robot_inside_the_inflation_band_still_gets_a_path() {
        let mut p = PlanningCore::new(PlanningParams::default());
        p.set_map(&room());
        p.set_goal(goal(1, 3.0, 3.0));
        let s = p.update(&at(0.25, 0.25)); // 0.15 m from both walls
        assert!(s.refused.is_none() && s.waypoint.is_some(), "{s:?}");
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod progress_tests {
    use super::tests::room;
    use super::*;
    use crate::msgs::{GoalState, RefusalReason};

    #[test]
    fn a_robot_that_never_gets_closer_is_reported_stalled_recovers_and_then_fails() {
        let mut p = PlanningCore::new(PlanningParams::default());
        p.set_map(&room());
        p.set_goal(Goal {
            id: 7,
            pose: Pose2D::new(8.0, 1.0, 0.0),
            tolerance_m: 0.2,
            ..Default::default()
        });
        let mut events = Vec::new();
        let mut saw_rotate = false;
        let mut saw_backup = false;
        let mut refused = None;
        let mut status = None;
        for i in 0..2000 {
            let t = f64::from(i) * 0.05;
            // The robot stays put but turns (as the servo would while rotating).
            let pose = Pose2D::new(
                2.0,
                1.0,
                (t * 1.5).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI,
            );
            let s = p.update_at(Some(t), &pose);
            events.extend(s.progress.iter().map(|m| m.event));
            if let Some(w) = s.waypoint {
                saw_backup |= w.speed < 0.0;
                let rel = crate::common::relative(&pose, &w.pose);
                saw_rotate |= w.speed > 0.0 && rel.y.atan2(rel.x) > 1.5;
            }
            if s.refused.is_some() {
                refused = s.refused;
                status = s.status;
                break;
            }
        }
        assert_eq!(events.first(), Some(&1), "stalled first: {events:?}");
        assert_eq!(events.iter().filter(|&&e| e == 2).count(), 4, "{events:?}");
        assert_eq!(events.last(), Some(&4), "{events:?}");
        assert!(saw_rotate && saw_backup);
        let why = refused.unwrap();
        assert!(why.contains("FAILED") && why.contains("recovery"), "{why}");
        let st = status.unwrap();
        assert_eq!(st.goal_state(), GoalState::Refused);
        assert_eq!(st.refusal_reason(), Some(RefusalReason::Stuck));
        assert!(p.is_refused());
    }
}
