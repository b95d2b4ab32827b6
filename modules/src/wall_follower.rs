//! Wall follower module (`hng module wall_follower`; Table 1: provides "Follow wall", needs
//! "Robot control" and "Detect wall").
//!
//! While a client holds its "Follow wall" contract (the Interface, under a follow-wall order)
//! it steers with [`crate::wall_follow::WallFollower`] at every [`Walls`] message of its
//! "Detect wall" provider: keeps `distance` (0.6 m) from the wall on the chosen side, turns
//! at inner and outer corners, and stops at a dead end or when the wall is lost. The side and
//! distance come from the Interface's [`FollowWallRequest`] on `request_in`
//! (`operator/follow_wall`, a state channel); without one, from the configuration. Commands go
//! to the Robot's channel under its "Robot control" contract (priority 2.4.1 under the
//! Interface), so Security (1.1) limits them and the operator's teleop (2.1) overrides them.
//! Inactive, it sends nothing.
//!
//! Quality Q: 1 following, 0.5 at a corner, 0 stopped (dead end, no wall); aptitude 1.
//! Checkpoint: counters.

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::{ProviderInput, ProviderOutput};
use hng_runtime::msg::{FOLLOW_WALL_CHANNEL, FollowWallRequest, SIDE_LEFT, Twist, Walls};
use hng_runtime::{Context, Module, ModuleResult, Subscriber};
use serde::{Deserialize, Serialize};

use crate::robot::ROBOT_CONTROL;
use crate::wall_follow::{FollowState, WallFollowConfig, WallFollower};
use crate::walls::Side;
use crate::walls_module::{DETECT_WALL, wall_of_segment};

/// The service this module provides.
pub const FOLLOW_WALL: &str = "Follow wall";
/// Rank of its "Robot control" need.
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of its "Detect wall" need.
pub const DETECT_WALL_NEED: u16 = 2;

/// Configuration of `hng module wall_follower`.
#[derive(Debug, Clone, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct WallFollowerConfig {
    /// The Interface's requests (default `operator/follow_wall`).
    pub request_in: String,
    /// The control law's parameters (distance 0.6 m, side when no request says, speeds,
    /// gains).
    pub follow: WallFollowConfig,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct FollowerState {
    steps: u64,
    corners: u64,
    dead_ends: u64,
}

/// The Wall follower module.
#[derive(Debug)]
pub struct WallFollowerModule {
    base: WallFollowConfig,
    follower: WallFollower,
    walls: ProviderInput<Walls>,
    requests: Subscriber<FollowWallRequest>,
    cmd_out: ProviderOutput<Twist>,
    active: bool,
    last_step: Option<f64>,
    last_state: Option<FollowState>,
    state: FollowerState,
}

impl WallFollowerModule {
    fn on_request(&mut self, r: &FollowWallRequest) {
        if r.active == 0 {
            return;
        }
        let mut cfg = self.base;
        cfg.side = if r.side == SIDE_LEFT {
            Side::Left
        } else {
            Side::Right
        };
        if r.distance_m > 0.0 && r.distance_m.is_finite() {
            cfg.distance = r.distance_m;
        }
        if cfg != *self.follower.config() && cfg.validate().is_ok() {
            self.follower = WallFollower::new(cfg);
        }
    }

    fn on_walls(&mut self, ctx: &mut Context, w: &Walls) -> ModuleResult {
        let now = ctx.now().as_secs_f64();
        let dt = self.last_step.map_or(0.1, |t| (now - t).clamp(0.0, 0.5));
        self.last_step = Some(now);
        let walls: Vec<_> = w.walls().iter().filter_map(wall_of_segment).collect();
        let (cmd, state) = self.follower.step(&walls, w.front, dt);
        self.state.steps += 1;
        if self.last_state != Some(state) {
            match state {
                FollowState::InnerCorner | FollowState::OuterCorner => self.state.corners += 1,
                FollowState::DeadEnd => self.state.dead_ends += 1,
                _ => {}
            }
            tracing::info!(module = ctx.name(), ?state, "wall following");
            self.last_state = Some(state);
        }
        let q = match state {
            FollowState::Following => 1.0,
            FollowState::InnerCorner | FollowState::OuterCorner => 0.5,
            FollowState::DeadEnd | FollowState::NoWall => 0.0,
        };
        ctx.set_quality(true, q);
        if let Some(out) = self.cmd_out.publisher() {
            out.publish(Twist {
                linear_x: cmd.linear_x,
                angular_z: cmd.angular_z,
                ..Default::default()
            })?;
        }
        Ok(())
    }
}

impl Module for WallFollowerModule {
    type Config = WallFollowerConfig;

    fn configure(ctx: &mut Context, mut cfg: WallFollowerConfig) -> ModuleResult<Self> {
        if cfg.request_in.is_empty() {
            cfg.request_in = FOLLOW_WALL_CHANNEL.into();
        }
        cfg.follow
            .validate()
            .map_err(|e| crate::common::field_error("follow", e))?;
        ctx.provide(ServiceOffer::new(FOLLOW_WALL, ""))
            .need(NeedSpec::required(ROBOT_CONTROL, ROBOT_CONTROL_NEED))
            .need(NeedSpec::required(DETECT_WALL, DETECT_WALL_NEED));
        ctx.set_quality(true, 1.0);
        Ok(WallFollowerModule {
            base: cfg.follow,
            follower: WallFollower::new(cfg.follow),
            walls: ProviderInput::new(),
            requests: ctx.subscribe(&cfg.request_in, None)?,
            cmd_out: ProviderOutput::new(),
            active: false,
            last_step: None,
            last_state: None,
            state: FollowerState::default(),
        })
    }

    fn on_activation(&mut self, ctx: &mut Context, active: bool) -> ModuleResult {
        self.active = active;
        self.follower.reset();
        self.last_step = None;
        self.last_state = None;
        tracing::info!(module = ctx.name(), active, "follow wall");
        Ok(())
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if input == self.requests.id() {
            while let Some(r) = self.requests.receive()? {
                let r = *r;
                self.on_request(&r);
            }
        } else if self.walls.is(input) {
            while let Some(w) = self.walls.receive()? {
                let w = *w;
                if self.active {
                    self.on_walls(ctx, &w)?;
                }
            }
        }
        Ok(())
    }

    hng_runtime::follow_needs!(ROBOT_CONTROL_NEED => cmd_out, DETECT_WALL_NEED => walls);

    hng_runtime::checkpoint_field!(state);
}
