//! Robot: the driver of the mobile base (Table 1: provides "Robot control" and "Odometry";
//! data in: commands, data out: odometry).
//!
//! It is a driver (paper 5.6 "Drivers"): its clients hold "Robot control" contracts and send
//! their commands on its data channel `cmd_in` (`robot/cmd_vel`, named in its proposals); it
//! obeys only the live contract holder with the most important priority
//! (`ctx.drive` + `ctx.command_verdict`: Security 1.1 over the operator's Interface 2.1 over
//! the Servo-controller 2.2.1.1); commands of the others are ignored and counted
//! (`commands_preempted`, `commands_no_contract` in its contract table). The election is made
//! here only: the commands of the client the most important holder supervises (the live one
//! elected among the others, `ctx.supervised_client`) are also published on
//! [`supervised_channel`]`(cmd_in)` (`robot/cmd_vel/supervised`), where Security reads the
//! command it limits before sending its own at 1.1. The accepted ones are
//! forwarded to the base (`cmd_out`, the simulator's `sim/cmd_vel` here, a hardware bridge on a
//! real robot) after clamping to the base's limits. When the client in control goes silent
//! and no other takes over, one stop is sent. Odometry from the base is provided as
//! "Odometry" on `odom_out` (`robot/odom`).
//!
//! Without contracts (benches, systems without a Manager) `sources` wires clients statically,
//! each with a configured priority ([`CommandMux`]).
//!
//! Quality Q: 1 while odometry flows and the last command was well formed; 0.5 after a
//! non-finite command was replaced by a stop; -1 (aptitude 0) when odometry stops (the base
//! is gone or not answering).

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{ModuleId, ServiceOffer, Verdict};
use hng_runtime::msg::{Odometry, Twist};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{CommandMux, CommandSource, MuxAction, check_fields, positive, seconds};

/// Configuration of `hng module robot`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    /// The "Robot control" data channel: contracted clients send their commands here
    /// (default `robot/cmd_vel`).
    #[default("robot/cmd_vel".into())]
    pub cmd_in: String,
    /// Static clients, each with a configured priority, for systems without contracts
    /// (default none: only contract holders command the base).
    pub sources: Vec<CommandSource>,
    /// A client loses control after this long without a command, s (default 0.5).
    #[default(0.5)]
    pub freshness_s: f64,
    /// Where accepted commands go (default `sim/cmd_vel`).
    #[default("sim/cmd_vel".into())]
    pub cmd_out: String,
    /// Odometry from the base (default `sim/odom`).
    #[default("sim/odom".into())]
    pub odom_in: String,
    /// Odometry relayed to clients (default `robot/odom`).
    #[default("robot/odom".into())]
    pub odom_out: String,
    /// Odometry silent this long means the base is gone, s (default 0.5).
    #[default(0.5)]
    pub odom_timeout_s: f64,
    /// Forward/backward speed limit of the base, m/s (default 1.0).
    #[default(1.0)]
    pub max_linear_speed: f64,
    /// Turn rate limit of the base, rad/s (default 2.0).
    #[default(2.0)]
    pub max_angular_speed: f64,
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

/// The "Robot control" service.
pub const ROBOT_CONTROL: &str = "Robot control";

/// Where a driver whose commands come in on `control_channel` publishes the commands of the
/// client its most important contract holder supervises (`robot/cmd_vel/supervised`).
pub fn supervised_channel(control_channel: &str) -> String {
    format!("{control_channel}/supervised")
}

/// The Robot driver module.
#[derive(Debug)]
pub struct RobotModule {
    cmd_in: Subscriber<Twist>,
    /// The supervised client's commands, for the supervisor (Security).
    supervised_out: Publisher<Twist>,
    /// When the last contracted command was obeyed (`None`: nobody in control).
    obeyed_at: Option<Duration>,
    freshness: Duration,
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

    /// Forwards `cmd` (a stop if it is not finite), counting invalid commands.
    fn obey(&mut self, ctx: &mut Context, cmd: &Twist, from: &str) -> ModuleResult {
        let finite = [cmd.linear_x, cmd.linear_y, cmd.angular_z]
            .iter()
            .all(|v| v.is_finite());
        if finite {
            return self.send(cmd);
        }
        self.state.invalid += 1;
        // Counted where every tool sees it too: the report's msgs_dropped.
        let c = &ctx.node().counters().msgs_dropped;
        c.set(c.get() + 1);
        tracing::warn!(
            module = ctx.name(),
            source = from,
            "non-finite command replaced by a stop"
        );
        self.update_quality(ctx);
        self.send(&Twist::default())
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
        check_fields!(positive, cfg; max_linear_speed, max_angular_speed)?;
        if cfg.cmd_in.is_empty() {
            return Err(crate::common::field_error("cmd_in", "is empty").into());
        }
        // Provides "Robot control" (commands in on `cmd_in`, obeyed by contract priority) and
        // "Odometry" (on `odom_out`).
        let mut control = ServiceOffer::new(ROBOT_CONTROL, "hng/Twist/v1");
        control.channel = cfg.cmd_in.clone();
        let mut odometry = ServiceOffer::new("Odometry", "hng/Odometry/v1");
        odometry.channel = cfg.odom_out.clone();
        ctx.provide(control)
            .provide(odometry)
            .drive(ROBOT_CONTROL, freshness);
        let mux = CommandMux::new(&cfg.sources, freshness)?;
        let mut sources = Vec::with_capacity(cfg.sources.len());
        for s in &cfg.sources {
            sources.push(ctx.subscribe::<Twist>(&s.channel, None)?);
        }
        ctx.add_timer((freshness / 4).max(Duration::from_millis(10)));
        Ok(RobotModule {
            cmd_in: ctx.subscribe(&cfg.cmd_in, None)?,
            supervised_out: ctx.publisher(&supervised_channel(&cfg.cmd_in))?,
            obeyed_at: None,
            freshness,
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
        if input == self.cmd_in.id() {
            // Contract holders: only the live one with the most important priority is obeyed.
            while let Some(cmd) = self.cmd_in.receive()? {
                let cmd = *cmd;
                let verdict = ctx.command_verdict(ROBOT_CONTROL, &cmd.header);
                if ctx.supervised_client(ROBOT_CONTROL) == Some(ModuleId(cmd.header.source)) {
                    // Stamped afresh by the publisher (source: the Robot).
                    self.supervised_out.publish(Twist {
                        header: Default::default(),
                        ..cmd
                    })?;
                }
                if verdict == Verdict::Accept {
                    self.obeyed_at = Some(ctx.now());
                    self.obey(ctx, &cmd, "contract")?;
                }
            }
            return Ok(());
        }
        let Some(i) = self.sources.iter().position(|s| s.id() == input) else {
            return Ok(());
        };
        let now = ctx.now();
        while let Some(cmd) = self.sources[i].receive()? {
            let cmd = *cmd;
            if let MuxAction::Send(_) = self.mux.on_command(i as u32, &cmd, now) {
                let from = self.sources[i].channel().to_string();
                self.obey(ctx, &cmd, &from)?;
            }
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        // The contracted client in control went silent and nobody took over: one stop.
        let now = ctx.now();
        if self
            .obeyed_at
            .is_some_and(|t| now.saturating_sub(t) >= self.freshness)
        {
            self.obeyed_at = None;
            tracing::debug!(module = ctx.name(), "commanding client went silent: stop");
            self.state.stops += 1;
            self.send(&Twist::default())?;
        }
        if let MuxAction::Send(stop) = self.mux.on_tick(now) {
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

    hng_runtime::checkpoint_field!(state);

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
