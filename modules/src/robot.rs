//! Robot: the driver of the mobile base (Table 1: provides "Robot control" and "Odometry";
//! data in: commands, data out: odometry).
//!
//! It obeys one commanding client at a time, by priority (paper 5.6 "Drivers"): commands from
//! every configured source go through a [`CommandMux`]; the accepted ones are forwarded to the
//! base (`cmd_out`, the simulator's `sim/cmd_vel` here, a hardware bridge on a real robot) after
//! clamping to the base's limits. When the client in control goes silent and no other is live,
//! one stop is sent. Odometry from the base is relayed on `odom_out`.
//!
//! Quality Q: 1 while odometry flows and the last command was well formed; 0.5 after a
//! non-finite command was replaced by a stop; -1 (aptitude 0) when odometry stops (the base
//! is gone or not answering).

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::msg::{Odometry, Twist};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::{Deserialize, Serialize};

use crate::common::{
    CommandMux, CommandSource, MuxAction, decode_state, encode_state, positive, seconds,
};

/// Configuration of `hng module robot`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    /// Clients that may command the base, with their priorities. Default: `security/cmd_vel`
    /// (1.1), `teleop/cmd_vel` (2.1), `servo/cmd_vel` (2.2.1.1), the paper's 5.8 example.
    pub sources: Vec<CommandSource>,
    /// A client loses control after this long without a command, s (default 0.5).
    pub freshness_s: f64,
    /// Where accepted commands go (default `sim/cmd_vel`).
    pub cmd_out: String,
    /// Odometry from the base (default `sim/odom`).
    pub odom_in: String,
    /// Odometry relayed to clients (default `robot/odom`).
    pub odom_out: String,
    /// Odometry silent this long means the base is gone, s (default 0.5).
    pub odom_timeout_s: f64,
    /// Forward/backward speed limit of the base, m/s (default 1.0).
    pub max_linear_speed: f64,
    /// Turn rate limit of the base, rad/s (default 2.0).
    pub max_angular_speed: f64,
}

impl Default for RobotConfig {
    fn default() -> Self {
        RobotConfig {
            sources: vec![
                CommandSource::new("security/cmd_vel", "1.1"),
                CommandSource::new("teleop/cmd_vel", "2.1"),
                CommandSource::new("servo/cmd_vel", "2.2.1.1"),
            ],
            freshness_s: 0.5,
            cmd_out: "sim/cmd_vel".into(),
            odom_in: "sim/odom".into(),
            odom_out: "robot/odom".into(),
            odom_timeout_s: 0.5,
            max_linear_speed: 1.0,
            max_angular_speed: 2.0,
        }
    }
}

/// Clamps a command to the base's limits.
pub fn clamp_command(cmd: &Twist, max_linear: f64, max_angular: f64) -> Twist {
    Twist {
        header: cmd.header,
        linear_x: cmd.linear_x.clamp(-max_linear, max_linear),
        linear_y: 0.0,
        angular_z: cmd.angular_z.clamp(-max_angular, max_angular),
    }
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct RobotState {
    forwarded: u64,
    stops: u64,
    invalid: u64,
}

/// The Robot driver module.
pub struct RobotModule {
    sources: Vec<Subscriber<Twist>>,
    mux: CommandMux,
    cmd_out: Publisher<Twist>,
    odom_in: Subscriber<Odometry>,
    odom_out: Publisher<Odometry>,
    max_linear: f64,
    max_angular: f64,
    state: RobotState,
    odom_ok: bool,
}

impl std::fmt::Debug for RobotModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotModule")
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

impl RobotModule {
    fn send(&mut self, cmd: &Twist) -> ModuleResult {
        let out = clamp_command(cmd, self.max_linear, self.max_angular);
        self.cmd_out.publish(Twist {
            header: Default::default(),
            ..out
        })?;
        self.state.forwarded += 1;
        Ok(())
    }

    fn update_quality(&self, ctx: &mut Context) {
        if !self.odom_ok {
            ctx.set_quality(false, -1.0);
        } else if self.state.invalid > 0 {
            ctx.set_quality(true, 0.5);
        } else {
            ctx.set_quality(true, 1.0);
        }
    }
}

impl Module for RobotModule {
    type Config = RobotConfig;

    fn configure(ctx: &mut Context, cfg: RobotConfig) -> ModuleResult<Self> {
        let freshness = seconds("freshness_s", cfg.freshness_s)?;
        let odom_timeout = seconds("odom_timeout_s", cfg.odom_timeout_s)?;
        positive("max_linear_speed", cfg.max_linear_speed)?;
        positive("max_angular_speed", cfg.max_angular_speed)?;
        // CONTRACTS: `ctx.provide("Robot control")` and `ctx.provide("Odometry")` go here, and
        // the arbiter's holders then come from the client contracts (see `CommandMux`).
        let mux = CommandMux::new(&cfg.sources, freshness)?;
        let mut sources = Vec::with_capacity(cfg.sources.len());
        for s in &cfg.sources {
            sources.push(ctx.subscribe::<Twist>(&s.channel, None)?);
        }
        ctx.add_timer((freshness / 4).max(Duration::from_millis(10)));
        Ok(RobotModule {
            sources,
            mux,
            cmd_out: ctx.publisher(&cfg.cmd_out)?,
            odom_in: ctx.subscribe(&cfg.odom_in, Some(odom_timeout))?,
            odom_out: ctx.publisher(&cfg.odom_out)?,
            max_linear: cfg.max_linear_speed,
            max_angular: cfg.max_angular_speed,
            state: RobotState::default(),
            odom_ok: false,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if input == self.odom_in.id() {
            while let Some(o) = self.odom_in.receive()? {
                self.odom_out.publish(*o)?;
            }
            self.odom_ok = true;
            self.update_quality(ctx);
            return Ok(());
        }
        let Some(i) = self.sources.iter().position(|s| s.id() == input) else {
            return Ok(());
        };
        let now = ctx.now();
        while let Some(cmd) = self.sources[i].receive()? {
            let finite = [cmd.linear_x, cmd.linear_y, cmd.angular_z]
                .iter()
                .all(|v| v.is_finite());
            if let MuxAction::Send(out) = self.mux.on_command(i as u32, &cmd, now) {
                if !finite {
                    self.state.invalid += 1;
                    tracing::warn!(
                        module = ctx.name(),
                        source = self.sources[i].channel(),
                        "non-finite command replaced by a stop"
                    );
                    self.update_quality(ctx);
                }
                self.send(&out)?;
            }
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        if let MuxAction::Send(stop) = self.mux.on_tick(ctx.now()) {
            tracing::debug!(module = ctx.name(), "commanding client went silent: stop");
            self.state.stops += 1;
            self.send(&stop)?;
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no odometry from the base");
        self.odom_ok = false;
        self.update_quality(ctx);
        Ok(())
    }

    fn checkpoint(&self) -> Option<Vec<u8>> {
        encode_state(&self.state)
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        self.state = decode_state(state)?;
        Ok(())
    }

    fn stop(&mut self, _ctx: &mut Context) {
        // Leave the base stopped.
        let _ = self.send(&Twist::default());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_are_clamped_to_the_base_limits() {
        let c = clamp_command(
            &Twist {
                linear_x: 3.0,
                linear_y: 1.0,
                angular_z: -9.0,
                ..Default::default()
            },
            1.0,
            2.0,
        );
        assert_eq!((c.linear_x, c.linear_y, c.angular_z), (1.0, 0.0, -2.0));
    }
}
