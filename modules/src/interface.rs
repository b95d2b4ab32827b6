//! Interface: the operator's side of the robot (Table 1: provides "Human control"; needs
//! "Robot control", "Reach goal" and, for the operator's view, "Video"), headless here.
//!
//! It answers the Manager's objective 2, "Human control", so its contracts rank under
//! Security's and above autonomous navigation (paper 5.8):
//!
//! - "Robot control" (2.1): the operator's teleoperation commands, read from `teleop_in`
//!   (`hng/teleop`, any publisher: a joystick bridge, a test, `hng topic pub`), are forwarded
//!   as the Interface's own commands to the Robot's channel. They override the
//!   Servo-controller's (2.2.1.1) while the operator commands, and Security (1.1) still limits
//!   them. Nothing is forwarded before the contract exists (commands are never wired around
//!   the contract tree). A command with a NaN or infinite velocity is never forwarded: it is
//!   dropped and counted (the report's `msgs_dropped`; the Robot does the same for any source).
//! - "Reach goal" (2.2, optional): the user wants the robot to reach the Manager's goals, so
//!   Planning (2.2), the Servo-controller (2.2.1) and their own providers run under Human
//!   control. Without a Planning module the Interface still serves teleoperation (its Q is
//!   lowered by the need's penalty).
//! - "Video" (2.3, optional): the camera's frames for the operator; counted (a display would
//!   show them).
//!
//! Quality Q: 1 (aptitude 1): the operator is always there to be served. Checkpoint: counters.

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::ProviderInfo;
use hng_runtime::msg::Twist;
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{decode_state, encode_state, field_error, follow_output};
use crate::robot::ROBOT_CONTROL;

/// Rank of the Interface's "Robot control" need (contract priority `P(interface).1`: 2.1).
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of its "Reach goal" need (2.2).
pub const REACH_GOAL_NEED: u16 = 2;
/// Rank of its "Video" need (2.3).
pub const VIDEO_NEED: u16 = 3;

/// Configuration of `hng module interface`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InterfaceConfig {
    /// The operator's teleoperation commands (default `hng/teleop`).
    pub teleop_in: String,
    /// Ask for "Reach goal", so the Manager's goals are pursued under Human control (default
    /// true).
    pub reach_goal: bool,
    /// Ask for "Video" (default true).
    pub video: bool,
}

impl Default for InterfaceConfig {
    fn default() -> Self {
        InterfaceConfig {
            teleop_in: "hng/teleop".into(),
            reach_goal: true,
            video: true,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct InterfaceState {
    forwarded: u64,
    dropped: u64,
    frames: u64,
    /// Teleoperation commands with a NaN or infinite velocity (dropped).
    invalid: u64,
}

/// The Interface module.
#[derive(Debug)]
pub struct InterfaceModule {
    teleop_in: Subscriber<Twist>,
    /// Commands to the contracted Robot's channel.
    cmd_out: Option<Publisher<Twist>>,
    video: crate::video::VideoInput,
    state: InterfaceState,
    /// The last teleoperation command was not finite (one warning per run of them).
    last_invalid: bool,
}

impl Module for InterfaceModule {
    type Config = InterfaceConfig;

    fn configure(ctx: &mut Context, cfg: InterfaceConfig) -> ModuleResult<Self> {
        if cfg.teleop_in.is_empty() {
            return Err(field_error("teleop_in", "is empty").into());
        }
        ctx.provide(ServiceOffer::new("Human control", ""))
            .need(NeedSpec::required(ROBOT_CONTROL, ROBOT_CONTROL_NEED));
        if cfg.reach_goal {
            ctx.need(NeedSpec::optional("Reach goal", REACH_GOAL_NEED, 0.2));
        }
        if cfg.video {
            ctx.need(NeedSpec::optional("Video", VIDEO_NEED, 0.1));
        }
        ctx.set_quality(true, 1.0);
        Ok(InterfaceModule {
            teleop_in: ctx.subscribe(&cfg.teleop_in, None)?,
            cmd_out: None,
            video: crate::video::VideoInput::new(),
            state: InterfaceState::default(),
            last_invalid: false,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if input == self.teleop_in.id() {
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
                match &self.cmd_out {
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
        } else if self.video.is(input) {
            while self.video.receive()?.is_some() {
                self.state.frames += 1;
            }
        }
        Ok(())
    }

    fn on_provider_changed(
        &mut self,
        ctx: &mut Context,
        need: u16,
        provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        match need {
            ROBOT_CONTROL_NEED => follow_output(ctx, &mut self.cmd_out, provider)?,
            VIDEO_NEED => self.video.follow(ctx, provider)?,
            _ => {}
        }
        Ok(())
    }

    fn checkpoint(&self) -> Option<Vec<u8>> {
        encode_state(&self.state)
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        self.state = decode_state(state)?;
        Ok(())
    }
}
