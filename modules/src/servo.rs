//! Servo-controller: reach waypoint (Table 1: provides "Reach waypoint", needs "Robot control"
//! and "Localization"; data in: waypoint, position; data out: commands).
//!
//! Pure pursuit ([`ServoCore`]): the waypoint from Planning is the carrot on the path; the
//! robot follows the arc through it, curvature `κ = 2·sin(α)/L` (`α` the carrot's bearing, `L`
//! its distance), at `max_speed` (or the waypoint's suggested speed if lower), turning in place
//! first when the carrot is more than `rotate_in_place_rad` off the heading. Near a final
//! waypoint the speed falls linearly over `slow_radius_m` (to at least `min_speed`); within
//! `goal_tolerance_m` of it (by the robot's estimate) the goal is reached: a stop, a
//! [`GoalStatus`] `Reached`, and silence until the next goal (so the client above regains the
//! robot). A goal the robot has just passed (behind it, within `3 · goal_tolerance_m`) is
//! reached too: turning back round a point that close would circle it.
//!
//! The stopping radius is kept small (5 cm) because whoever judges the goal does so on the
//! true pose, whose distance to the goal is the stopping radius plus the localization's
//! error: with the fused localization's error of up to about 0.2 m at a stop, a 0.15 m radius
//! left goals 0.33-0.43 m away against a 0.3 m tolerance (arena, `hng eval nav`); with 5 cm the
//! error budget of a 0.3 m tolerance is 0.25 m.
//!
//! Its commands go to the Robot's "Robot control" channel under its contract with the Robot
//! (priority 2.2.1.1 in the paper's tree: the operator and Security override it); before that
//! contract exists it sends nothing.
//!
//! Quality Q: `1 − |α|/π` while following (1 on the path, lower when far off heading); 0 with
//! no waypoint; -1 (aptitude 0) without a recent position.

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::{FollowProvider as _, ProviderInfo, ProviderInput, ProviderOutput};
use hng_runtime::msg::{FrameId, Header, Pose2D, PoseWithCovariance, Twist, Waypoint};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{check_fields, positive, relative, seconds};
use crate::msgs::{GoalState, GoalStatus};

/// Parameters of the controller.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct ServoParams {
    /// Cruise speed, m/s (default 0.6).
    #[default(0.6)]
    pub max_speed: f64,
    /// Turn rate limit, rad/s (default 1.5).
    #[default(1.5)]
    pub max_angular: f64,
    /// Distance to the final waypoint at which the goal counts as reached, m (default 0.05;
    /// keep it well below the goals' tolerance, which must also hold the localization error).
    #[default(0.05)]
    pub goal_tolerance_m: f64,
    /// Distance to the final waypoint over which the robot slows down, m (default 0.8).
    #[default(0.8)]
    pub slow_radius_m: f64,
    /// Slowest approach speed, m/s (default 0.08).
    #[default(0.08)]
    pub min_speed: f64,
    /// Turn in place when the carrot is farther off the heading than this, rad (default 1.0).
    #[default(1.0)]
    pub rotate_in_place_rad: f64,
    /// Turn rate per radian of heading error when turning in place, 1/s (default 2.0).
    #[default(2.0)]
    pub heading_gain: f64,
}

/// One control decision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoOutput {
    /// The command (`None`: say nothing, the goal is already reached).
    pub cmd: Option<Twist>,
    /// True the first time the goal is reached.
    pub reached: bool,
    /// Distance to the waypoint, m.
    pub distance_m: f64,
    /// Bearing of the waypoint from the heading, rad.
    pub bearing: f64,
}

/// Pure-pursuit logic, without I/O.
#[derive(Debug, Clone)]
pub struct ServoCore {
    params: ServoParams,
    reached: Option<u32>,
}

impl ServoCore {
    /// A controller with `params`.
    pub fn new(params: ServoParams) -> ServoCore {
        ServoCore {
            params,
            reached: None,
        }
    }

    /// The last goal reached.
    pub fn reached(&self) -> Option<u32> {
        self.reached
    }

    /// The command that takes the robot at `pose` towards `wp`.
    pub fn command(&mut self, pose: &Pose2D, wp: &Waypoint) -> ServoOutput {
        let p = &self.params;
        let rel = relative(pose, &wp.pose);
        let dist = rel.x.hypot(rel.y);
        let bearing = rel.y.atan2(rel.x);
        let mut out = ServoOutput {
            cmd: None,
            reached: false,
            distance_m: dist,
            bearing,
        };
        if self.reached == Some(wp.goal_id) {
            return out;
        }
        let passed =
            dist <= 3.0 * p.goal_tolerance_m && bearing.abs() > std::f64::consts::FRAC_PI_2;
        if wp.is_final != 0 && (dist <= p.goal_tolerance_m || passed) {
            self.reached = Some(wp.goal_id);
            out.cmd = Some(Twist::default());
            out.reached = true;
            return out;
        }
        if wp.speed < 0.0 {
            // Backing up (Planning's recovery, `planning::progress`): straight back.
            out.cmd = Some(Twist::new(wp.speed.max(-p.max_speed), 0.0));
            return out;
        }
        if bearing.abs() > p.rotate_in_place_rad {
            let w = (p.heading_gain * bearing).clamp(-p.max_angular, p.max_angular);
            out.cmd = Some(Twist::new(0.0, w));
            return out;
        }
        let mut v = p.max_speed;
        if wp.speed > 0.0 {
            v = v.min(wp.speed);
        }
        if wp.is_final != 0 {
            v = v.min((p.max_speed * dist / p.slow_radius_m).max(p.min_speed));
        }
        let k = if dist > 1e-9 {
            2.0 * bearing.sin() / dist
        } else {
            0.0
        };
        let mut w = k * v;
        if w.abs() > p.max_angular {
            v = p.max_angular / k.abs();
            w = p.max_angular * w.signum();
        }
        out.cmd = Some(Twist::new(v, w));
        out
    }
}

/// Configuration of `hng module servo`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct ServoModuleConfig {
    /// Waypoint input (default `planning/waypoint`).
    #[default("planning/waypoint".into())]
    pub waypoint: String,
    /// Position input until a "Localization" provider is known (default `slam/pose`).
    #[default("slam/pose".into())]
    pub pose: String,
    /// Goal status out (default `servo/status`).
    #[default("servo/status".into())]
    pub status_out: String,
    /// A waypoint older than this is not followed, s (default 1.0).
    #[default(1.0)]
    pub waypoint_timeout_s: f64,
    /// A position older than this is not trusted, s (default 0.5).
    #[default(0.5)]
    pub pose_timeout_s: f64,
    /// Controller parameters.
    #[default(ServoParams::default())]
    pub params: ServoParams,
    /// Odometry, to rate the "Localization" provider (client feedback, `crate::feedback`;
    /// default `robot/odom`, empty: no rating).
    #[default("robot/odom".into())]
    pub odom: String,
    /// The operator's pose estimates (default `operator/initial_pose`, empty: none): the
    /// Localization provider jumps to one, so the rating holds its judgement for a window.
    #[default(crate::initial_pose::INITIAL_POSE_CHANNEL.into())]
    pub initial_pose: String,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct ServoState {
    reached_goal: Option<u32>,
    goals_reached: u64,
}

/// Rank of Servo's "Robot control" need (its contract priority is `P(servo).1`).
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of Servo's "Localization" need (its contract priority is `P(servo).2`).
pub const LOCALIZATION_NEED: u16 = 2;

/// The Servo-controller module.
#[derive(Debug)]
pub struct ServoModule {
    core: ServoCore,
    /// Planning's waypoint, polled at each pose (Planning sends it from the pose, so it
    /// would only ever be stored).
    waypoint: Subscriber<Waypoint>,
    /// The contracted "Localization" provider's pose (need rank [`LOCALIZATION_NEED`]); the
    /// configured `pose` channel's until one is known.
    localization: ProviderInput<PoseWithCovariance>,
    /// Commands to the contracted Robot's channel (need rank [`ROBOT_CONTROL_NEED`]).
    cmd_out: ProviderOutput<Twist>,
    status_out: Publisher<GoalStatus>,
    last_wp: Option<(Waypoint, Duration)>,
    last_pose: Option<(Pose2D, Duration)>,
    wp_timeout: Duration,
    pose_timeout: Duration,
    state: ServoState,
    /// The rating of the Localization provider by odometry (client feedback).
    check: crate::feedback::PoseCheck,
}

impl ServoModule {
    fn act(&mut self, ctx: &mut Context) -> ModuleResult {
        let now = ctx.now();
        let pose = self
            .last_pose
            .filter(|(_, t)| now.saturating_sub(*t) <= self.pose_timeout);
        let wp = self
            .last_wp
            .filter(|(_, t)| now.saturating_sub(*t) <= self.wp_timeout);
        let (Some((pose, _)), Some((wp, _))) = (pose, wp) else {
            // Nothing to follow or no position: say nothing; the robot's other clients (or
            // Security's hold) take over once our last command is stale.
            let q = if pose.is_none() { -1.0 } else { 0.0 };
            ctx.set_quality(pose.is_some(), q);
            return Ok(());
        };
        let out = self.core.command(&pose, &wp);
        if let (Some(cmd), Some(cmd_out)) = (out.cmd, self.cmd_out.publisher()) {
            cmd_out.publish(cmd)?;
        }
        if out.reached {
            self.state.reached_goal = Some(wp.goal_id);
            self.state.goals_reached += 1;
            tracing::info!(module = ctx.name(), goal = wp.goal_id, "goal reached");
            self.status_out.publish(GoalStatus {
                header: Header {
                    frame_id: FrameId::MAP,
                    ..Header::default()
                },
                goal_id: wp.goal_id,
                state: GoalState::Reached as u8,
                distance_m: out.distance_m,
                reason: 0,
            })?;
        }
        ctx.set_quality(
            true,
            (1.0 - out.bearing.abs() / std::f64::consts::PI) as f32,
        );
        Ok(())
    }
}

impl Module for ServoModule {
    type Config = ServoModuleConfig;

    fn configure(ctx: &mut Context, cfg: ServoModuleConfig) -> ModuleResult<Self> {
        check_fields!(positive, cfg.params, "params"; max_speed, max_angular, goal_tolerance_m,
            slow_radius_m, rotate_in_place_rad, heading_gain)?;
        let wp_timeout = seconds("waypoint_timeout_s", cfg.waypoint_timeout_s)?;
        let pose_timeout = seconds("pose_timeout_s", cfg.pose_timeout_s)?;
        // Provides "Reach waypoint" (needed by Planning); needs "Robot control" (its commands
        // go to the Robot's channel) and "Localization" (the pose comes from the contracted
        // provider, from `pose` until one is known).
        ctx.provide(ServiceOffer::new("Reach waypoint", ""))
            .need(NeedSpec::required(
                crate::robot::ROBOT_CONTROL,
                ROBOT_CONTROL_NEED,
            ))
            .need(NeedSpec::required("Localization", LOCALIZATION_NEED));
        ctx.add_timer(Duration::from_millis(100));
        ctx.set_quality(false, -1.0);
        Ok(ServoModule {
            core: ServoCore::new(cfg.params),
            waypoint: ctx.subscribe_polled(&cfg.waypoint)?,
            localization: ProviderInput::new().with_fallback(ctx, &cfg.pose)?,
            cmd_out: ProviderOutput::new(),
            status_out: ctx.publisher(&cfg.status_out)?,
            last_wp: None,
            last_pose: None,
            wp_timeout,
            pose_timeout,
            state: ServoState::default(),
            check: crate::feedback::PoseCheck::new(ctx, &cfg.odom, &cfg.initial_pose)?,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if !self.localization.is(input) {
            return Ok(());
        }
        // The pose is the one trigger: the waypoint and the odometry are polled inputs, read
        // here (what was sent before the pose; in lockstep, before this round opened).
        let now = ctx.now();
        self.check.poll(now.as_secs_f64())?;
        if let Some(w) = self.waypoint.latest()? {
            self.last_wp = Some((*w, now));
        }
        while let Some(p) = self.localization.receive()? {
            self.last_pose = Some((p.pose, now));
            if let Some(e) = self.check.on_pose(&p, now.as_secs_f64()) {
                ctx.evaluate_provider(LOCALIZATION_NEED, e);
            }
        }
        self.act(ctx)
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        // Re-evaluate freshness when inputs stop (quality; nothing is sent on stale data).
        let now = ctx.now();
        if self
            .last_pose
            .is_none_or(|(_, t)| now.saturating_sub(t) > self.pose_timeout)
        {
            ctx.set_quality(false, -1.0);
        }
        Ok(())
    }

    fn on_provider_changed(
        &mut self,
        ctx: &mut Context,
        need: u16,
        provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        if need == LOCALIZATION_NEED {
            self.localization.follow(ctx, provider)?;
            self.check.rater.reset();
        } else if need == ROBOT_CONTROL_NEED {
            self.cmd_out.follow(ctx, provider)?;
        }
        Ok(())
    }

    hng_runtime::checkpoint_field!(state, Self::load_state);
}

impl ServoModule {
    fn load_state(&mut self, s: ServoState) -> ModuleResult {
        self.state = s;
        self.core.reached = s.reached_goal;
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::planning_module::{PlanningCore, PlanningParams};

    fn wp(x: f64, y: f64, is_final: bool) -> Waypoint {
        Waypoint {
            goal_id: 7,
            pose: Pose2D { x, y, theta: 0.0 },
            is_final: u8::from(is_final),
            ..Default::default()
        }
    }

    /// Unicycle integration with the base's acceleration limits.
    fn drive(pose: &mut Pose2D, vel: &mut (f64, f64), cmd: &Twist, dt: f64) {
        vel.0 += (cmd.linear_x - vel.0).clamp(-2.0 * dt, 2.0 * dt);
        vel.1 += (cmd.angular_z - vel.1).clamp(-6.0 * dt, 6.0 * dt);
        pose.x += vel.0 * pose.theta.cos() * dt;
        pose.y += vel.0 * pose.theta.sin() * dt;
        pose.theta = crate::common::wrap_angle(pose.theta + vel.1 * dt);
    }

    /// The module's own loop (in-process harness): with "Localization" and "Robot control"
    /// served by the test, it steers to the waypoint from the provider's pose, ignores its
    /// fallback pose channel, and reports the goal reached.
    #[test]
    fn the_module_steers_from_the_providers_pose_to_the_waypoint() {
        use hng_runtime::harness::Harness;
        use hng_runtime::msg::PoseWithCovariance;
        use std::f64::consts::FRAC_PI_2;
        let at = |x: f64, y: f64, theta: f64| PoseWithCovariance {
            pose: Pose2D { x, y, theta },
            ..Default::default()
        };
        let mut h = Harness::new("servo").unwrap();
        let pose = h.input::<PoseWithCovariance>("test/pose").unwrap();
        let fallback = h.input::<PoseWithCovariance>("slam/pose").unwrap();
        let waypoint = h.input::<Waypoint>("planning/waypoint").unwrap();
        let mut cmd = h.output::<Twist>("test/cmd_vel").unwrap();
        let mut status = h.output::<GoalStatus>("servo/status").unwrap();
        h.provider(LOCALIZATION_NEED, "test/pose")
            .provider(ROBOT_CONTROL_NEED, "test/cmd_vel");
        h.start::<ServoModule>("odom = \"\"").unwrap();

        // A pose, again until the module answers (a waypoint and a pose that come together
        // may be read in either order: the waypoint counts from the next pose on).
        let mut steer = |h: &Harness, p: PoseWithCovariance, pred: &dyn Fn(&Twist) -> bool| {
            for _ in 0..50 {
                pose.publish(p).unwrap();
                if let Ok(c) = h.wait_for(&mut cmd, Duration::from_millis(100), pred) {
                    return c;
                }
            }
            panic!("no command with {p:?}: {:?}", cmd.samples.last());
        };
        waypoint.publish(wp(2.0, 0.0, false)).unwrap();
        let c = steer(&h, at(0.0, 0.0, 0.0), &|c| c.linear_x > 0.0);
        assert!(c.angular_z.abs() < 1e-9, "straight on: {c:?}");

        // The waypoint to the left: a left turn. A fallback pose facing it is not read.
        fallback.publish(at(0.0, 0.0, FRAC_PI_2)).unwrap();
        waypoint.publish(wp(0.0, 2.0, false)).unwrap();
        let c = steer(&h, at(0.0, 0.0, 0.0), &|c| c.angular_z != 0.0);
        assert!(
            c.angular_z > 0.0,
            "turns left, from the provider's heading: {c:?}"
        );

        // At the final waypoint: reached.
        waypoint.publish(wp(0.0, 2.0, true)).unwrap();
        let reached = GoalState::Reached as u8;
        let s = (0..50)
            .find_map(|_| {
                pose.publish(at(0.0, 1.99, FRAC_PI_2)).unwrap();
                h.wait_for(&mut status, Duration::from_millis(100), |s| {
                    s.state == reached
                })
                .ok()
            })
            .expect("the goal reached");
        assert_eq!(s.goal_id, 7);
        h.finish().unwrap();
    }

    #[test]
    fn pure_pursuit_converges_on_a_goal_from_any_heading() {
        for theta in [0.0, 1.0, -2.0, 3.0] {
            let mut core = ServoCore::new(ServoParams::default());
            let mut pose = Pose2D {
                x: 0.0,
                y: 0.0,
                theta,
            };
            let mut vel = (0.0, 0.0);
            let goal = wp(3.0, 2.0, true);
            let mut reached = false;
            for _ in 0..3000 {
                let out = core.command(&pose, &goal);
                if out.reached {
                    reached = true;
                    break;
                }
                drive(&mut pose, &mut vel, &out.cmd.unwrap(), 0.01);
            }
            assert!(reached, "start heading {theta}: ended at {pose:?}");
            assert!((pose.x - 3.0).hypot(pose.y - 2.0) <= 0.05 + 1e-9);
            assert_eq!(core.command(&pose, &goal).cmd, None, "silent once reached");
        }
    }

    #[test]
    fn servo_slows_near_the_goal_and_respects_the_turn_limit() {
        let mut core = ServoCore::new(ServoParams::default());
        let start = Pose2D::default();
        let far = core.command(&start, &wp(5.0, 0.0, true)).cmd.unwrap();
        let near = core.command(&start, &wp(0.4, 0.0, true)).cmd.unwrap();
        assert_eq!(far.linear_x, 0.6);
        assert!(
            near.linear_x < far.linear_x && near.linear_x >= 0.08,
            "{near:?}"
        );
        let side = core.command(&start, &wp(0.5, 0.4, false)).cmd.unwrap();
        assert!(
            side.angular_z <= 1.5 + 1e-12 && side.angular_z > 0.0,
            "{side:?}"
        );
        let behind = core.command(&start, &wp(-1.0, 0.1, false)).cmd.unwrap();
        assert_eq!(behind.linear_x, 0.0, "turns in place first");
    }

    #[test]
    fn planning_and_pure_pursuit_together_reach_a_goal_behind_a_wall() {
        let grid = crate::planning_module::tests::room();
        let mut planner = PlanningCore::new(PlanningParams::default());
        planner.set_map(&grid);
        planner.set_goal(hng_runtime::msg::Goal {
            id: 1,
            pose: Pose2D::new(8.0, 1.0, 0.0),
            tolerance_m: 0.2,
            ..Default::default()
        });
        let mut servo = ServoCore::new(ServoParams::default());
        let mut pose = Pose2D::new(2.0, 1.0, 0.0);
        let mut vel = (0.0, 0.0);
        let mut min_clear = f64::INFINITY;
        let mut reached = false;
        for step in 0..6000 {
            let plan = planner.update(&pose);
            let Some(w) = plan.waypoint else {
                panic!("no waypoint at step {step}: {plan:?}");
            };
            let out = servo.command(&pose, &w);
            if out.reached {
                reached = true;
                break;
            }
            drive(&mut pose, &mut vel, &out.cmd.unwrap(), 0.01);
            // Clearance to the wall x = 5, y < 4 (cells 50, 0..40 at 0.1 m: x 5.0..5.1).
            let dx = if pose.x < 5.0 {
                5.0 - pose.x
            } else if pose.x > 5.1 {
                pose.x - 5.1
            } else {
                0.0
            };
            let dy = (pose.y - 4.0).max(0.0);
            min_clear = min_clear.min(dx.hypot(dy) - 0.2);
        }
        assert!(reached, "ended at {pose:?}");
        assert!(min_clear > 0.0, "the robot touched the wall: {min_clear}");
    }

    /// Planning and the Servo in a closed loop (perfect localisation) from (2, 1) to (8, 1)
    /// through a 0.9 m door in the wall x = 5: the robot's least gap to an obstacle, and the
    /// planned path's.
    fn through_a_door(params: PlanningParams, goal: (f64, f64)) -> (f64, f64) {
        use crate::planning::path_clearance;
        // The 0.9 m door: cells 26 to 34.
        let grid = crate::planning_module::tests::walled_room(26..35);
        let mut planner = PlanningCore::new(params);
        planner.set_map(&grid);
        planner.set_goal(hng_runtime::msg::Goal {
            id: 1,
            pose: Pose2D::new(goal.0, goal.1, 0.0),
            tolerance_m: 0.2,
            ..Default::default()
        });
        let mut servo = ServoCore::new(ServoParams::default());
        let mut pose = Pose2D::new(2.0, 1.0, 0.0);
        let mut vel = (0.0, 0.0);
        let gap = |points: &[[f64; 2]]| path_clearance(&grid, points, 50, 5.0) - 0.2;
        let mut plan_gap = None;
        let mut driven = f64::INFINITY;
        for step in 0..8000 {
            let plan = planner.update(&pose);
            plan_gap.get_or_insert_with(|| gap(planner.path_points()));
            let w = plan
                .waypoint
                .unwrap_or_else(|| panic!("no waypoint at step {step}"));
            let out = servo.command(&pose, &w);
            if out.reached {
                assert!(
                    (pose.x - goal.0).hypot(pose.y - goal.1) <= 0.15 + 1e-9,
                    "{pose:?}"
                );
                return (driven, plan_gap.unwrap_or(f64::NAN));
            }
            drive(&mut pose, &mut vel, &out.cmd.unwrap(), 0.01);
            driven = driven.min(gap(&[[pose.x, pose.y]]));
        }
        panic!("not reached: {pose:?}");
    }

    #[test]
    fn through_a_door_the_robot_keeps_the_planned_clearance() {
        // Through the door, then up along the wall on its far side.
        let goal = (6.0, 5.0);
        let (driven, plan) = through_a_door(PlanningParams::default(), goal);
        // The fixed 0.6 m carrot of before, for comparison.
        let fixed_carrot = PlanningParams {
            min_lookahead_m: 0.6,
            ..PlanningParams::default()
        };
        let (fixed, _) = through_a_door(fixed_carrot, goal);
        eprintln!("plan {plan:.3} m, driven {driven:.3} m, with a fixed carrot {fixed:.3} m");
        assert!(plan > 0.24, "the plan keeps to the door's middle: {plan}");
        assert!(
            plan - driven <= 0.015,
            "driven {driven} against the plan's {plan}"
        );
        assert!(
            plan - fixed >= 0.025,
            "with a fixed carrot {fixed}, plan {plan}"
        );
    }
}
