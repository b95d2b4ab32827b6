//! The Beacon reacher module (Table 1: `hng module reacher`, "Reach beacon"): needs "Robot
//! control" (rank 1) and "Track beacon" (rank 2), both required; drives toward the designated
//! beacon as its tracker reports it ([`crate::reacher::ReachLaw`]), stops at
//! `stop_distance_m`, and stops when the beacon has not been seen for `lost_timeout_s`
//! (predicted tracks are followed at half speed until then). A lost beacon seen again by the
//! tracker is approached again (re-acquisition): a track that drops out for longer than the
//! timeout stops the robot and is reported, but does not end the approach for good. It publishes a [`ReachStatus`]
//! on its offer's data channel (`status_out`, `reacher/status`) at every track and on every
//! change, and rates its tracker by progress toward the beacon
//! ([`crate::reacher::ProgressJudge`], `ctx.evaluate_provider`) from the odometry on `odom`
//! (`robot/odom`).
//!
//! It works only while selected (a client holds its "Reach beacon" contract) and a beacon is
//! designated (`operator/designation`); otherwise it sends no command. Tracks of another
//! beacon than the designated one are ignored.
//!
//! Q: 1 while it approaches or holds a reached beacon, 0 when the beacon is lost or none is
//! designated.

use std::collections::VecDeque;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::{FollowProvider as _, ProviderInfo, ProviderInput, ProviderOutput};
use hng_runtime::msg::{
    BeaconTrack, DESIGNATION_CHANNEL, Designation, Header, Odometry, Pose2D, TRACK_LOST,
    TRACK_SEEN, Twist,
};
use hng_runtime::qos::ChannelKind;
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::positive;
use crate::reacher::{JudgeParams, ProgressJudge, Reach, ReachLaw, ReachParams};
use crate::robot::ROBOT_CONTROL;
use crate::tracker_module::TRACK_BEACON;

/// Rank of the reacher's "Robot control" need.
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of the reacher's "Track beacon" need.
pub const TRACK_NEED: u16 = 2;

/// Reach state: nothing to do (not selected, or no beacon designated).
pub const REACH_IDLE: u8 = 0;
/// Reach state: driving toward the beacon.
pub const REACH_APPROACHING: u8 = 1;
/// Reach state: within the stop distance, stopped.
pub const REACH_REACHED: u8 = 2;
/// Reach state: the beacon was not seen for the timeout, stopped.
pub const REACH_LOST: u8 = 3;

/// What the reacher is doing (state channel: late joiners get the latest).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-modules/ReachStatus/v1")]
pub struct ReachStatus {
    /// Header.
    pub header: Header,
    /// The designated beacon (0: none).
    pub beacon_id: u32,
    /// [`REACH_IDLE`], [`REACH_APPROACHING`], [`REACH_REACHED`] or [`REACH_LOST`].
    pub state: u8,
    /// The tracker's last range, m (negative: unknown).
    pub range: f64,
    /// Module id of the tracker followed (0: none).
    pub tracker: u32,
    /// The last evaluation sent to the tracker, in [-1, 0].
    pub evaluation: f32,
}
hng_runtime::impl_message!(ReachStatus, ChannelKind::State);

/// Configuration of `hng module reacher`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct ReacherConfig {
    /// Status out, the offer's data channel (default `reacher/status`).
    #[default("reacher/status".into())]
    pub status_out: String,
    /// Designations (default `operator/designation`).
    #[default(DESIGNATION_CHANNEL.into())]
    pub designation: String,
    /// Odometry for the feedback (default `robot/odom`).
    #[default("robot/odom".into())]
    pub odom: String,
    /// Rate the tracker (default true).
    #[default(true)]
    pub evaluate: bool,
    /// The command law (`law = { stop_distance_m = 0.4, lost_timeout_s = 1.5, ... }`).
    #[default(ReachParams::default())]
    pub law: ReachParams,
    /// The feedback.
    #[default(JudgeParams::default())]
    pub feedback: JudgeParams,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct ReacherState {
    reached: u64,
    lost: u64,
    penalties: u64,
}

/// The Beacon reacher module; see the module documentation.
#[derive(Debug)]
pub struct ReacherModule {
    cfg: ReacherConfig,
    law: ReachLaw,
    judge: ProgressJudge,
    track: ProviderInput<BeaconTrack>,
    designation: Subscriber<Designation>,
    odom: Subscriber<Odometry>,
    odom_log: VecDeque<(u64, Pose2D)>,
    cmd_out: ProviderOutput<Twist>,
    status: Publisher<ReachStatus>,
    target: Option<u32>,
    active: bool,
    last_seen_s: Option<f64>,
    /// When the current target was set (or the reacher selected), s.
    since_s: f64,
    last_track_s: Option<f64>,
    current: ReachStatus,
    state: ReacherState,
}

impl Module for ReacherModule {
    type Config = ReacherConfig;

    fn configure(ctx: &mut Context, cfg: ReacherConfig) -> ModuleResult<Self> {
        let l = &cfg.law;
        for (f, v) in [
            ("law.stop_distance_m", l.stop_distance_m),
            ("law.max_speed", l.max_speed),
            ("law.min_speed", l.min_speed),
            ("law.max_turn", l.max_turn),
            ("law.k_speed", l.k_speed),
            ("law.k_turn", l.k_turn),
            ("law.turn_in_place_rad", l.turn_in_place_rad),
            ("law.lost_timeout_s", l.lost_timeout_s),
            ("feedback.window_s", cfg.feedback.window_s),
            ("feedback.bearing_tol_rad", cfg.feedback.bearing_tol_rad),
            ("feedback.range_tol_frac", cfg.feedback.range_tol_frac),
            ("feedback.horizon_s", cfg.feedback.horizon_s),
        ] {
            positive(f, v)?;
        }
        let mut offer = ServiceOffer::new("Reach beacon", "hng-modules/ReachStatus/v1");
        offer.channel = cfg.status_out.clone();
        ctx.provide(offer)
            .need(NeedSpec::required(ROBOT_CONTROL, ROBOT_CONTROL_NEED))
            .need(NeedSpec::required(TRACK_BEACON, TRACK_NEED));
        ctx.set_quality(true, 0.0);
        ctx.add_timer(std::time::Duration::from_millis(100));
        Ok(ReacherModule {
            law: ReachLaw { params: cfg.law },
            judge: ProgressJudge::new(cfg.feedback),
            track: ProviderInput::new(),
            designation: ctx.subscribe(&cfg.designation, None)?,
            odom: ctx.subscribe(&cfg.odom, None)?,
            odom_log: VecDeque::new(),
            cmd_out: ProviderOutput::new(),
            status: ctx.publisher(&cfg.status_out)?,
            target: None,
            active: false,
            last_seen_s: None,
            since_s: 0.0,
            last_track_s: None,
            current: ReachStatus {
                range: -1.0,
                ..Default::default()
            },
            state: ReacherState::default(),
            cfg,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if input == self.odom.id() {
            while let Some(o) = self.odom.receive()? {
                if self.odom_log.len() >= 64 {
                    self.odom_log.pop_front();
                }
                self.odom_log.push_back((o.header.stamp_ns, o.pose));
            }
        } else if input == self.designation.id() {
            while let Some(d) = self.designation.receive()? {
                let next = (d.active != 0).then_some(d.beacon_id);
                if next != self.target {
                    self.restart(ctx, next)?;
                }
            }
        } else if self.track.is(input) {
            while let Some(t) = self.track.receive()? {
                let t = *t;
                self.on_track(ctx, &t)?;
            }
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        // A silent tracker: the beacon is lost once the timeout has passed.
        let now = ctx.now().as_secs_f64();
        let silent = self
            .last_track_s
            .is_none_or(|t| now - t > self.cfg.law.lost_timeout_s);
        if self.working() && silent && self.current.state == REACH_APPROACHING {
            tracing::warn!(
                module = ctx.name(),
                beacon = self.current.beacon_id,
                silent_s = self.last_track_s.map(|t| now - t),
                "no track from the tracker: beacon lost, stopped"
            );
            self.state.lost += 1;
            self.set_state(ctx, REACH_LOST)?;
            self.halt()?;
        }
        Ok(())
    }

    fn on_activation(&mut self, ctx: &mut Context, active: bool) -> ModuleResult {
        self.active = active;
        if !active {
            self.halt()?;
        }
        let target = self.target;
        self.restart(ctx, target)
    }

    fn on_provider_changed(
        &mut self,
        ctx: &mut Context,
        need: u16,
        provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        match need {
            ROBOT_CONTROL_NEED => self.cmd_out.follow(ctx, provider)?,
            TRACK_NEED => {
                self.track.follow(ctx, provider)?;
                self.judge.reset();
                self.current.tracker = provider.map_or(0, |p| p.module.0);
                if let Some(p) = provider {
                    tracing::info!(module = ctx.name(), tracker = p.module.0, "tracker");
                }
            }
            _ => {}
        }
        Ok(())
    }

    hng_runtime::checkpoint_field!(state);
}

impl ReacherModule {
    fn working(&self) -> bool {
        self.active && self.target.is_some()
    }

    /// A new target (or none), or a new activation: start over.
    fn restart(&mut self, ctx: &mut Context, target: Option<u32>) -> ModuleResult {
        self.target = target;
        self.judge.reset();
        self.last_seen_s = None;
        self.since_s = ctx.now().as_secs_f64();
        self.last_track_s = Some(self.since_s);
        self.current.beacon_id = target.unwrap_or(0);
        self.current.range = -1.0;
        let state = if self.working() {
            REACH_APPROACHING
        } else {
            REACH_IDLE
        };
        self.set_state(ctx, state)
    }

    fn on_track(&mut self, ctx: &mut Context, t: &BeaconTrack) -> ModuleResult {
        let now = ctx.now().as_secs_f64();
        if !self.working() || Some(t.beacon_id) != self.target {
            return Ok(());
        }
        self.last_track_s = Some(now);
        let seen = t.state == TRACK_SEEN;
        if seen {
            self.last_seen_s = Some(now);
            self.evaluate(ctx, t);
        }
        if t.state != TRACK_LOST {
            self.current.range = t.range;
        }
        let unseen = now - self.last_seen_s.unwrap_or(self.since_s);
        let (bearing, range) = if t.state == TRACK_LOST {
            (f64::NAN, f64::NAN)
        } else {
            (t.bearing, t.range)
        };
        // Reached holds still; lost holds still until the beacon is seen again.
        match self.current.state {
            REACH_REACHED => return self.halt(),
            REACH_LOST if !seen => return self.halt(),
            // Seen again: approaching.
            REACH_LOST => self.set_state(ctx, REACH_APPROACHING)?,
            _ => {}
        }
        if t.state == TRACK_LOST && unseen <= self.cfg.law.lost_timeout_s {
            // Not seen yet, or no longer predicted: wait, stopped, until the timeout.
            return self.halt();
        }
        match self.law.command(bearing, range, seen, unseen) {
            Reach::Drive(v, w) => {
                if let Some(out) = self.cmd_out.publisher() {
                    out.publish(Twist {
                        linear_x: v,
                        angular_z: w,
                        ..Default::default()
                    })?;
                }
                self.publish_status()?;
            }
            Reach::Reached => {
                self.state.reached += 1;
                self.set_state(ctx, REACH_REACHED)?;
                self.halt()?;
            }
            Reach::Lost => {
                self.state.lost += 1;
                tracing::warn!(
                    module = ctx.name(),
                    unseen_s = unseen,
                    "beacon lost: stopped"
                );
                self.set_state(ctx, REACH_LOST)?;
                self.halt()?;
            }
        }
        Ok(())
    }

    /// Rates the tracker by the consistency of its track with the robot's motion.
    fn evaluate(&mut self, ctx: &mut Context, t: &BeaconTrack) {
        if !self.cfg.evaluate {
            return;
        }
        let stamp = t.header.stamp_ns;
        let Some(&(_, pose)) = self.odom_log.iter().min_by_key(|(s, _)| s.abs_diff(stamp)) else {
            return;
        };
        if let Some(e) = self
            .judge
            .judge(stamp as f64 * 1e-9, pose, t.bearing, t.range)
        {
            if e < 0.0 {
                self.state.penalties += 1;
                tracing::debug!(module = ctx.name(), e, "tracker penalised");
            }
            self.current.evaluation = e as f32;
            ctx.evaluate_provider(TRACK_NEED, e);
        }
    }

    fn set_state(&mut self, ctx: &mut Context, state: u8) -> ModuleResult {
        if state != self.current.state {
            let name = |s: u8| match s {
                REACH_APPROACHING => "approaching",
                REACH_REACHED => "reached",
                REACH_LOST => "lost",
                _ => "idle",
            };
            tracing::info!(
                module = ctx.name(),
                beacon = self.current.beacon_id,
                range = self.current.range,
                from = name(self.current.state),
                to = name(state),
                "reach state"
            );
        }
        self.current.state = state;
        let q = match state {
            REACH_APPROACHING | REACH_REACHED => 1.0,
            _ => 0.0,
        };
        ctx.set_quality(true, q);
        self.publish_status()
    }

    fn publish_status(&self) -> ModuleResult {
        self.status.publish(ReachStatus {
            header: Header::default(),
            ..self.current
        })?;
        Ok(())
    }

    fn halt(&self) -> ModuleResult {
        if let Some(out) = self.cmd_out.publisher() {
            out.publish(Twist::default())?;
        }
        Ok(())
    }
}
