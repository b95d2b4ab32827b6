//! Interface: the operator's side of the robot (Table 1: provides "Human control"; needs
//! "Robot control", "Reach goal", "Video", and for adjustable autonomy "Follow wall" and
//! "Reach beacon"), headless here. See docs/autonomy.md.
//!
//! It answers the Manager's objective 2, "Human control", so its contracts rank under
//! Security's and above autonomous navigation (paper 5.8). The operator's orders
//! ([`Order`] on `operator/order`, from `hng order`, `hng teleop` or the operator page) are
//! validated field by field ([`orders::validate`]) and against what attention offers now
//! ([`crate::attention`]); every order is answered on `operator/order_status` (accepted, or
//! refused with the reason). An accepted order is put in force by changing what the Interface
//! needs, so the contract tree below "Human control" is rebuilt for it:
//!
//! | order | needs switched on | commands at 2.1 |
//! |---|---|---|
//! | (none: autonomy) | Reach goal: the Manager's goals | forwarded teleop commands |
//! | stop | (none) | zero, every `period_s`, until the next order |
//! | teleop | (none) | forwarded teleop commands; zero after `deadman_s` without one |
//! | goal, waypoints | Reach goal: the operator's points | forwarded teleop commands |
//! | follow wall | Follow wall (2.4), told the side on `operator/follow_wall` | idem |
//! | reach beacon | Reach beacon (2.5), told the beacon on `operator/designation` | idem |
//!
//! - "Robot control" (2.1): teleoperation commands from `teleop_in` (`hng/teleop`) are
//!   forwarded as the Interface's own commands (except under stop); they override every
//!   behaviour below (2.2.x, 2.4.x, 2.5.x), and Security (1.1) still limits them. A command
//!   with a NaN or infinite velocity is dropped and counted (the report's `msgs_dropped`).
//! - Goals reach Planning through the Interface: it relays the Manager's current goal from
//!   `goal_in` (`manager/goal`) to `goal_out` (`interface/goal`, Planning's `goal` input in the
//!   built-in mission) while no order is in force, and publishes the operator's goal or
//!   waypoints there instead (ids from 0x4000_0000, never the Manager's). The order ends when
//!   its last point is reported reached (`status_in`: the Servo's and Planning's
//!   `GoalStatus`) or refused; the end is published on the order status (`active` 0, reason),
//!   and the Manager's goal is relayed again.
//! - An order whose behaviour finds no provider within `provider_timeout_s` ends, saying so.
//! - Attention: the behaviours available now are published on `hng/behaviours` (a state
//!   channel) whenever the offer changes.
//!
//! Quality Q: 1 (aptitude 1): the operator is always there to be served. Checkpoint: counters
//! and the order in force (a restarted Interface puts it in force again).

mod orders;

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::ProviderOutput;
use hng_runtime::msg::{
    BEHAVIOURS_CHANNEL, BeaconObservation, BeaconTrack, Behaviours, DESIGNATION_CHANNEL,
    Designation, FOLLOW_WALL_CHANNEL, FollowWallRequest, Goal, ORDER_CHANNEL, ORDER_STATUS_CHANNEL,
    Order, OrderStatus, Pose2D, TRACK_SEEN, Twist, Walls,
};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

pub use self::orders::{Mode, OrderLimits, validate};
use crate::attention::{Attention, AttentionConfig, Providers, same_offer};
use crate::common::{check_fields, field_error, positive};
use crate::msgs::{GoalState, GoalStatus};
use crate::robot::ROBOT_CONTROL;

/// Rank of the Interface's "Robot control" need (contract priority `P(interface).1`: 2.1).
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of its "Reach goal" need (2.2).
pub const REACH_GOAL_NEED: u16 = 2;
/// Rank of its "Video" need (2.3).
pub const VIDEO_NEED: u16 = 3;
/// Rank of its "Follow wall" need (2.4), on only under a follow-wall order.
pub const FOLLOW_WALL_NEED: u16 = 4;
/// Rank of its "Reach beacon" need (2.5), on only under a reach-beacon order.
pub const REACH_BEACON_NEED: u16 = 5;
/// The services of the behaviours.
pub const REACH_GOAL: &str = "Reach goal";
/// See [`REACH_GOAL`].
pub const FOLLOW_WALL: &str = "Follow wall";
/// See [`REACH_GOAL`].
pub const REACH_BEACON: &str = "Reach beacon";
/// First id of the operator's goals (the Manager's count up from 1).
pub const OPERATOR_GOAL_ID_BASE: u32 = 0x4000_0000;

/// Configuration of `hng module interface`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct InterfaceConfig {
    /// The operator's teleoperation commands (default `hng/teleop`).
    #[default("hng/teleop".into())]
    pub teleop_in: String,
    /// Ask for "Reach goal", so goals are pursued under Human control (default true).
    #[default(true)]
    pub reach_goal: bool,
    /// Ask for "Video" (default true).
    #[default(true)]
    pub video: bool,
    /// Offer and accept follow-wall orders (need "Follow wall"; default true).
    #[default(true)]
    pub follow_wall: bool,
    /// Offer and accept reach-beacon orders (need "Reach beacon"; default true).
    #[default(true)]
    pub reach_beacon: bool,
    /// The Manager's current goal (default `manager/goal`).
    #[default("manager/goal".into())]
    pub goal_in: String,
    /// Where the goal to pursue goes, Planning's goal input (default `interface/goal`).
    #[default("interface/goal".into())]
    pub goal_out: String,
    /// Goal statuses (default `servo/status`, `planning/status`).
    #[default(vec!["servo/status".into(), "planning/status".into()])]
    pub status_in: Vec<String>,
    /// Detected walls for attention (default `walls/walls`).
    #[default("walls/walls".into())]
    pub walls_in: String,
    /// Beacon observations for attention (`BeaconObservation`; default none: the camera
    /// gives images, and a beacon is offered once a tracker tracks it).
    pub beacons_in: String,
    /// Trackers' `BeaconTrack` channels for attention (default the two built-in trackers',
    /// `tracker_colour/track` and `tracker_histogram/track`).
    #[default(vec![ "tracker_colour/track".into(), "tracker_histogram/track".into(), ])]
    pub tracks_in: Vec<String>,
    /// Deadman of the teleop order: no command for this long, s: zero (default 0.5).
    #[default(0.5)]
    pub deadman_s: f64,
    /// Period of the hold commands (stop, deadman) and of attention, s (default 0.05).
    #[default(0.05)]
    pub period_s: f64,
    /// An order whose behaviour has no provider this long ends, s (default 3).
    #[default(3.0)]
    pub provider_timeout_s: f64,
    /// Largest |x|, |y| of an order's point, m (default 1000).
    #[default(1000.0)]
    pub max_coordinate_m: f64,
    /// Tolerance of the operator's goals given without one, m (default 0.2).
    #[default(0.2)]
    pub goal_tolerance_m: f64,
    /// Attention: walls farther than this are not offered, m (default 1.5).
    #[default(1.5)]
    pub wall_range_m: f64,
    /// Attention: perception older than this is forgotten, s (default 1).
    #[default(1.0)]
    pub fresh_s: f64,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
struct InterfaceState {
    forwarded: u64,
    dropped: u64,
    /// Teleoperation commands with a NaN or infinite velocity (dropped).
    invalid: u64,
    orders_accepted: u64,
    orders_refused: u64,
    /// The order in force and its sender's seq.
    mode: Mode,
    mode_seq: u32,
    /// The operator goal being reached (0: none) and the next operator goal id.
    op_goal: u32,
    next_op_goal: u32,
}

/// The Interface module.
#[derive(Debug)]
pub struct InterfaceModule {
    cfg: InterfaceConfig,
    limits: OrderLimits,
    teleop_in: Subscriber<Twist>,
    /// Commands to the contracted Robot's channel.
    cmd_out: ProviderOutput<Twist>,
    orders_in: Subscriber<Order>,
    status_out: Publisher<OrderStatus>,
    goal_in: Subscriber<Goal>,
    goal_out: Publisher<Goal>,
    goal_status_in: Vec<Subscriber<GoalStatus>>,
    walls_in: Subscriber<Walls>,
    beacons_in: Option<Subscriber<BeaconObservation>>,
    tracks_in: Vec<Subscriber<BeaconTrack>>,
    designation_out: Publisher<Designation>,
    follow_out: Publisher<FollowWallRequest>,
    behaviours_out: Publisher<Behaviours>,
    attention: Attention,
    offered: Option<Behaviours>,
    manager_goal: Option<Goal>,
    state: InterfaceState,
    /// When the order in force began, and when the last teleop command came, s.
    mode_since: f64,
    last_teleop: f64,
    /// The last teleoperation command was not finite (one warning per run of them).
    last_invalid: bool,
}

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

impl InterfaceModule {
    fn providers(&self, ctx: &Context) -> Providers {
        let listening = |service: &str| {
            ctx.contracts()
                .and_then(|a| a.provider_count(service))
                .is_some_and(|n| n > 0)
        };
        Providers {
            reach_goal: self.cfg.reach_goal && listening(REACH_GOAL),
            follow_wall: self.cfg.follow_wall && listening(FOLLOW_WALL),
            reach_beacon: self.cfg.reach_beacon && listening(REACH_BEACON),
        }
    }

    fn publish_status(&self, seq: u32, accepted: bool, reason: &str) -> ModuleResult {
        let mut s = OrderStatus {
            seq,
            accepted: u8::from(accepted),
            active: u8::from(self.state.mode != Mode::Autonomy),
            in_force: self.state.mode.kind().map_or(0, |k| k as u32),
            ..Default::default()
        };
        s.set_reason(reason);
        self.status_out.publish(s)?;
        Ok(())
    }

    fn send_command(&self, cmd: Twist) -> ModuleResult {
        if let Some(out) = self.cmd_out.publisher() {
            out.publish(cmd)?;
        }
        Ok(())
    }

    /// Publishes the goal Planning should pursue now.
    fn publish_goal(&mut self) -> ModuleResult {
        match &self.state.mode {
            Mode::Goals {
                points,
                tolerance_m,
                next,
                ..
            } => {
                let (x, y) = points[(*next).min(points.len() - 1)];
                self.state.op_goal = OPERATOR_GOAL_ID_BASE + self.state.next_op_goal;
                self.state.next_op_goal = (self.state.next_op_goal + 1) % OPERATOR_GOAL_ID_BASE;
                self.goal_out.publish(Goal {
                    id: self.state.op_goal,
                    pose: Pose2D::new(x, y, 0.0),
                    tolerance_m: *tolerance_m,
                    ..Default::default()
                })?;
            }
            _ => {
                self.state.op_goal = 0;
                if let Some(g) = self.manager_goal {
                    self.goal_out.publish(g)?;
                }
            }
        }
        Ok(())
    }

    /// Puts the mode in force: needs, requests to the behaviours, goal, first command.
    fn apply_mode(&mut self, ctx: &mut Context) -> ModuleResult {
        let mode = self.state.mode.clone();
        if self.cfg.reach_goal {
            ctx.set_need_enabled(
                REACH_GOAL_NEED,
                matches!(mode, Mode::Autonomy | Mode::Goals { .. }),
            );
        }
        if self.cfg.follow_wall {
            ctx.set_need_enabled(FOLLOW_WALL_NEED, matches!(mode, Mode::FollowWall { .. }));
        }
        if self.cfg.reach_beacon {
            ctx.set_need_enabled(REACH_BEACON_NEED, matches!(mode, Mode::ReachBeacon { .. }));
        }
        let (side, distance_m, follow) = match mode {
            Mode::FollowWall { side, distance_m } => (side, distance_m, true),
            _ => (0, 0.0, false),
        };
        self.follow_out.publish(FollowWallRequest {
            side,
            distance_m,
            active: u8::from(follow),
            ..Default::default()
        })?;
        let (beacon_id, designated) = match mode {
            Mode::ReachBeacon { id, .. } => (id, true),
            _ => (0, false),
        };
        self.designation_out.publish(Designation {
            beacon_id,
            active: u8::from(designated),
            ..Default::default()
        })?;
        self.publish_goal()?;
        if matches!(mode, Mode::Stop | Mode::Teleop) {
            self.send_command(Twist::default())?;
        }
        self.mode_since = secs(ctx.now());
        Ok(())
    }

    /// The order in force ended (reached, refused, no provider): back to autonomy.
    fn end_order(&mut self, ctx: &mut Context, reason: &str) -> ModuleResult {
        tracing::info!(module = ctx.name(), "order ended: {reason}");
        self.state.mode = Mode::Autonomy;
        self.apply_mode(ctx)?;
        self.publish_status(self.state.mode_seq, true, reason)
    }

    fn on_order(&mut self, ctx: &mut Context, o: &Order) -> ModuleResult {
        let now = secs(ctx.now());
        let providers = self.providers(ctx);
        let verdict = validate(o, &self.limits).and_then(|mode| {
            if let Some(kind) = mode.kind() {
                self.attention
                    .available(kind, mode.param(), providers, now)?;
            }
            let wanted = match &mode {
                Mode::Goals { .. } => self.cfg.reach_goal,
                Mode::FollowWall { .. } => self.cfg.follow_wall,
                Mode::ReachBeacon { .. } => self.cfg.reach_beacon,
                _ => true,
            };
            if wanted {
                Ok(mode)
            } else {
                Err("this Interface is configured without that behaviour".into())
            }
        });
        match verdict {
            Ok(mode) => {
                self.state.orders_accepted += 1;
                let what = describe(&mode);
                tracing::info!(module = ctx.name(), seq = o.seq, "order accepted: {what}");
                self.state.mode = mode;
                self.state.mode_seq = o.seq;
                self.apply_mode(ctx)?;
                self.publish_status(o.seq, true, &what)
            }
            Err(reason) => {
                self.state.orders_refused += 1;
                let c = &ctx.node().counters().msgs_dropped;
                c.set(c.get() + 1);
                tracing::warn!(module = ctx.name(), seq = o.seq, "order refused: {reason}");
                self.publish_status(o.seq, false, &reason)
            }
        }
    }

    fn on_goal_status(&mut self, ctx: &mut Context, s: &GoalStatus) -> ModuleResult {
        if self.state.op_goal == 0 || s.goal_id != self.state.op_goal {
            return Ok(());
        }
        let Mode::Goals {
            waypoints,
            points,
            next,
            ..
        } = &mut self.state.mode
        else {
            return Ok(());
        };
        match s.goal_state() {
            GoalState::Reached => {
                *next += 1;
                if *next < points.len() {
                    tracing::info!(module = ctx.name(), "waypoint {} reached", *next);
                    self.publish_goal()?;
                } else {
                    let (x, y) = points[points.len() - 1];
                    let what = if *waypoints {
                        format!("waypoints reached ({} points)", points.len())
                    } else {
                        format!("goal ({x:.2}, {y:.2}) reached")
                    };
                    self.end_order(ctx, &what)?;
                }
            }
            GoalState::Refused => {
                let why = s
                    .refusal_reason()
                    .map_or("refused by Planning", |r| r.describe());
                let (x, y) = points[(*next).min(points.len() - 1)];
                self.end_order(ctx, &format!("goal ({x:.2}, {y:.2}) failed: {why}"))?;
            }
            _ => {}
        }
        Ok(())
    }

    fn on_teleop(&mut self, ctx: &mut Context) -> ModuleResult {
        while let Some(cmd) = self.teleop_in.receive()? {
            if ![cmd.linear_x, cmd.linear_y, cmd.angular_z]
                .iter()
                .all(|v| v.is_finite())
            {
                // NaN or infinite: never forwarded, counted (state and the report's
                // msgs_dropped), said once per run of bad commands.
                self.state.invalid += 1;
                let c = &ctx.node().counters().msgs_dropped;
                c.set(c.get() + 1);
                if !self.last_invalid {
                    tracing::warn!(
                        module = ctx.name(),
                        invalid = self.state.invalid,
                        "non-finite teleoperation command dropped"
                    );
                }
                self.last_invalid = true;
                continue;
            }
            self.last_invalid = false;
            if self.state.mode == Mode::Stop {
                // Emergency stop in force: the operator's commands wait for another order.
                self.state.dropped += 1;
                continue;
            }
            self.last_teleop = secs(ctx.now());
            match self.cmd_out.publisher() {
                Some(out) => {
                    out.publish(Twist {
                        header: Default::default(),
                        ..*cmd
                    })?;
                    self.state.forwarded += 1;
                }
                None => self.state.dropped += 1,
            }
        }
        Ok(())
    }

    fn read_attention(&mut self, ctx: &Context) -> ModuleResult {
        let now = secs(ctx.now());
        while let Some(w) = self.walls_in.receive()? {
            self.attention.on_walls(&w, now);
        }
        if let Some(b) = &self.beacons_in {
            while let Some(obs) = b.receive()? {
                for beacon in obs.beacons() {
                    self.attention.on_beacon(beacon.id, 1.0, now);
                }
            }
        }
        for t in &self.tracks_in {
            while let Some(track) = t.receive()? {
                if track.state == TRACK_SEEN {
                    self.attention
                        .on_beacon(track.beacon_id, track.quality, now);
                }
            }
        }
        Ok(())
    }

    fn publish_behaviours(&mut self, ctx: &Context) -> ModuleResult {
        let b = self
            .attention
            .behaviours(self.providers(ctx), secs(ctx.now()));
        if self.offered.as_ref().is_none_or(|o| !same_offer(o, &b)) {
            self.behaviours_out.publish(b)?;
            self.offered = Some(b);
        }
        Ok(())
    }
}

/// The order in force, in words.
fn describe(mode: &Mode) -> String {
    match mode {
        Mode::Autonomy => "released: autonomy".into(),
        Mode::Stop => "stop in force".into(),
        Mode::Teleop => "teleop in force".into(),
        Mode::Goals {
            waypoints: false,
            points,
            ..
        } => format!("goal ({:.2}, {:.2}) in force", points[0].0, points[0].1),
        Mode::Goals { points, .. } => format!("{} waypoints in force", points.len()),
        Mode::FollowWall { side, distance_m } => format!(
            "follow wall {} in force{}",
            if *side > 0 { "left" } else { "right" },
            if *distance_m > 0.0 {
                format!(" at {distance_m:.2} m")
            } else {
                String::new()
            }
        ),
        Mode::ReachBeacon { id, .. } => format!("reach beacon {id} in force"),
    }
}

impl Module for InterfaceModule {
    type Config = InterfaceConfig;

    fn configure(ctx: &mut Context, cfg: InterfaceConfig) -> ModuleResult<Self> {
        for (field, v) in [
            ("teleop_in", &cfg.teleop_in),
            ("goal_in", &cfg.goal_in),
            ("goal_out", &cfg.goal_out),
            ("walls_in", &cfg.walls_in),
        ] {
            if v.is_empty() {
                return Err(field_error(field, "is empty").into());
            }
        }
        check_fields!(positive, cfg; deadman_s, period_s, provider_timeout_s, max_coordinate_m,
            goal_tolerance_m, wall_range_m, fresh_s)?;
        ctx.provide(ServiceOffer::new("Human control", ""))
            .need(NeedSpec::required(ROBOT_CONTROL, ROBOT_CONTROL_NEED));
        if cfg.reach_goal {
            ctx.need(NeedSpec::optional(REACH_GOAL, REACH_GOAL_NEED, 0.2));
        }
        if cfg.video {
            // Held for the operator page, which reads the images itself: the Interface takes
            // no frames (a reader would make the Camera relay, and the simulator render,
            // every frame for nobody), so the need has no field in `follow_needs!`.
            ctx.need(NeedSpec::optional("Video", VIDEO_NEED, 0.1));
        }
        // The behaviours' needs: no penalty (they are asked for only under their order).
        if cfg.follow_wall {
            ctx.need(NeedSpec::optional(FOLLOW_WALL, FOLLOW_WALL_NEED, 0.0));
            ctx.set_need_enabled(FOLLOW_WALL_NEED, false);
        }
        if cfg.reach_beacon {
            ctx.need(NeedSpec::optional(REACH_BEACON, REACH_BEACON_NEED, 0.0));
            ctx.set_need_enabled(REACH_BEACON_NEED, false);
        }
        ctx.set_quality(true, 1.0);
        ctx.add_timer(Duration::from_secs_f64(cfg.period_s));
        let mut goal_status_in = Vec::new();
        for c in &cfg.status_in {
            goal_status_in.push(ctx.subscribe(c, None)?);
        }
        let mut tracks_in = Vec::new();
        for c in &cfg.tracks_in {
            tracks_in.push(ctx.subscribe(c, None)?);
        }
        let beacons_in = if cfg.beacons_in.is_empty() {
            None
        } else {
            Some(ctx.subscribe(&cfg.beacons_in, None)?)
        };
        let limits = OrderLimits {
            max_coordinate_m: cfg.max_coordinate_m,
            default_tolerance_m: cfg.goal_tolerance_m,
            ..OrderLimits::default()
        };
        let attention = Attention::new(AttentionConfig {
            wall_range_m: cfg.wall_range_m,
            fresh_s: cfg.fresh_s,
        });
        Ok(InterfaceModule {
            limits,
            teleop_in: ctx.subscribe(&cfg.teleop_in, None)?,
            cmd_out: ProviderOutput::new(),
            orders_in: ctx.subscribe(ORDER_CHANNEL, None)?,
            status_out: ctx.publisher(ORDER_STATUS_CHANNEL)?,
            goal_in: ctx.subscribe(&cfg.goal_in, None)?,
            goal_out: ctx.publisher(&cfg.goal_out)?,
            goal_status_in,
            walls_in: ctx.subscribe(&cfg.walls_in, None)?,
            beacons_in,
            tracks_in,
            designation_out: ctx.publisher(DESIGNATION_CHANNEL)?,
            follow_out: ctx.publisher(FOLLOW_WALL_CHANNEL)?,
            behaviours_out: ctx.publisher(BEHAVIOURS_CHANNEL)?,
            attention,
            offered: None,
            manager_goal: None,
            state: InterfaceState::default(),
            mode_since: 0.0,
            last_teleop: f64::NEG_INFINITY,
            last_invalid: false,
            cfg,
        })
    }

    fn start(&mut self, ctx: &mut Context) -> ModuleResult {
        // A restored order is put in force again; otherwise autonomy is announced.
        self.apply_mode(ctx)?;
        let reason = describe(&self.state.mode);
        self.publish_status(self.state.mode_seq, true, &reason)
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if input == self.teleop_in.id() {
            self.on_teleop(ctx)?;
        } else if input == self.orders_in.id() {
            while let Some(o) = self.orders_in.receive()? {
                let o = *o;
                self.on_order(ctx, &o)?;
            }
        } else if input == self.goal_in.id() {
            while let Some(g) = self.goal_in.receive()? {
                self.manager_goal = Some(*g);
                // An operator goal overrides the Manager's while it is in force.
                if !matches!(self.state.mode, Mode::Goals { .. }) {
                    self.goal_out.publish(*g)?;
                }
            }
        } else if let Some(i) = self.goal_status_in.iter().position(|s| s.id() == input) {
            while let Some(s) = self.goal_status_in[i].receive()? {
                let s = *s;
                self.on_goal_status(ctx, &s)?;
            }
        } else {
            self.read_attention(ctx)?;
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        let now = secs(ctx.now());
        match self.state.mode {
            Mode::Stop => self.send_command(Twist::default())?,
            Mode::Teleop if now - self.last_teleop > self.cfg.deadman_s => {
                self.send_command(Twist::default())?
            }
            _ => {}
        }
        let need = match self.state.mode {
            Mode::Goals { .. } => Some((REACH_GOAL_NEED, REACH_GOAL)),
            Mode::FollowWall { .. } => Some((FOLLOW_WALL_NEED, FOLLOW_WALL)),
            Mode::ReachBeacon { .. } => Some((REACH_BEACON_NEED, REACH_BEACON)),
            _ => None,
        };
        if let Some((rank, service)) = need
            && ctx.provider(rank).is_none()
            && now - self.mode_since > self.cfg.provider_timeout_s
        {
            let why = format!(
                "no provider of \"{service}\" within {:.1} s",
                self.cfg.provider_timeout_s
            );
            self.end_order(ctx, &why)?;
        }
        self.read_attention(ctx)?;
        self.publish_behaviours(ctx)
    }

    hng_runtime::follow_needs!(ROBOT_CONTROL_NEED => cmd_out);

    hng_runtime::checkpoint_field!(state);
}
