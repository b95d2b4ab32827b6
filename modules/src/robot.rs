//! Robot: the driver of the mobile base (Table 1: provides "Robot control" and "Odometry";
//! data in: commands, data out: odometry).
//!
//! It is a driver (paper 5.6 "Drivers"): its clients hold "Robot control" contracts and send
//! their commands on its data channel `cmd_in` (`robot/cmd_vel`, named in its proposals); it
//! obeys only the live contract holder with the most important priority
//! (`ctx.drive` + `ctx.command_verdict`: the operator's Interface 2.1 over the
//! Servo-controller 2.2.1.1); commands of the others are ignored and counted
//! (`commands_preempted`, `commands_no_contract` in its contract table). This is the only
//! election of a wheel command. The elected command is then limited by the speed-limit
//! envelope ([`SpeedEnvelope`]) of the most important holder, Security (1.1, paper 5.8: it
//! may invalidate the others' commands), which publishes one per scan on
//! [`envelope_channel`]`(cmd_in)` (`robot/cmd_vel/envelope`) and sends no commands: a speed
//! the envelope does not allow at the command's curvature is reduced, keeping the curvature
//! (turning in place stays allowed). Every new envelope limits the command in force again. An
//! envelope older than `freshness_s` (by its scan's stamp), or none yet from a holder that
//! published one before, means stop. A holder that never published an envelope limits
//! nothing, and when Security's contract ends (Security dead: under `hng run` at once, on the
//! supervisor's `Died` event; or not yet re-contracted after a restart) the elected client
//! drives unlimited until Security is back, as before the envelope (docs/fault-matrix.md). The accepted commands are forwarded to the base
//! (`cmd_out`, the simulator's `sim/cmd_vel` here, a hardware bridge on a real robot) after
//! clamping to the base's limits. When the client in control goes silent and no other takes
//! over, one stop is sent. Odometry from the base is provided as "Odometry" on `odom_out`
//! (`robot/odom`).
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
use hng_runtime::msg::{Odometry, SpeedEnvelope, Twist};
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
    /// Commands changed by the guard's envelope (or stopped without a fresh one).
    #[serde(default)]
    guarded: u64,
}

/// The "Robot control" service.
pub const ROBOT_CONTROL: &str = "Robot control";

/// Where the safety client of a driver whose commands come in on `control_channel` publishes
/// its speed-limit envelope ([`SpeedEnvelope`], `robot/cmd_vel/envelope`).
pub fn envelope_channel(control_channel: &str) -> String {
    format!("{control_channel}/envelope")
}

/// What limits the elected command before it goes to the base.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Guard<'a> {
    /// The most important contract holder publishes no envelope (no Security in the system,
    /// or Security's contract ended: dead, or not yet back): the command goes as it is.
    None,
    /// The holder's fresh envelope.
    Limit(&'a SpeedEnvelope),
    /// The holder guards but its envelope is missing or stale: stop.
    Stop,
}

/// The guard rule: `top` (the most important holder) limits commands only if it is one of
/// `guards` (it published envelopes); then by its `envelope` if that is its own and its scan
/// younger than `freshness`, else by a stop.
fn guard_of<'a>(
    top: Option<ModuleId>,
    guards: &[ModuleId],
    envelope: Option<&'a SpeedEnvelope>,
    now: Duration,
    freshness: Duration,
) -> Guard<'a> {
    let Some(top) = top.filter(|t| guards.contains(t)) else {
        return Guard::None;
    };
    match envelope {
        Some(e)
            if e.header.source == top.0
                && now.saturating_sub(Duration::from_nanos(e.scan_stamp_ns)) < freshness =>
        {
            Guard::Limit(e)
        }
        _ => Guard::Stop,
    }
}

/// The Robot driver module.
#[derive(Debug)]
pub struct RobotModule {
    cmd_in: Subscriber<Twist>,
    /// The envelopes of the safety client (Security).
    envelope_in: Subscriber<SpeedEnvelope>,
    /// The newest envelope.
    envelope: Option<SpeedEnvelope>,
    /// Clients that published an envelope: while one of them holds the most important
    /// contract, its fresh envelope limits every command.
    guards: Vec<ModuleId>,
    /// When the last contracted command was obeyed (`None`: nobody in control).
    obeyed_at: Option<Duration>,
    /// The elected client's last command, as it sent it, and when (limited again by every
    /// new envelope while younger than `freshness_s`).
    in_force: Option<(Duration, Twist)>,
    /// The last command sent to the base, after clamping.
    sent: Option<Twist>,
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
        let out = Twist {
            header: Default::default(),
            ..clamp_command(cmd, self.max_linear, self.max_angular)
        };
        self.cmd_out.publish(out)?;
        self.sent = Some(out);
        self.state.forwarded += 1;
        Ok(())
    }

    /// What limits commands now ([`guard_of`]): the guard is the most important "Robot
    /// control" holder; without a contract plane (the static wiring), the publisher of the
    /// newest envelope.
    fn guard(&self, ctx: &Context) -> Guard<'_> {
        let top = match ctx.contracts() {
            Some(agent) => agent
                .client_contracts()
                .filter(|c| c.service == ROBOT_CONTROL)
                .min_by_key(|c| (c.priority, c.client))
                .map(|c| c.client),
            None => self.envelope.map(|e| ModuleId(e.header.source)),
        };
        guard_of(
            top,
            &self.guards,
            self.envelope.as_ref(),
            ctx.now(),
            self.freshness,
        )
    }

    /// Obeys the elected command `cmd` (from `from`) within the guard's envelope.
    fn obey_guarded(&mut self, ctx: &mut Context, cmd: &Twist, from: &str) -> ModuleResult {
        self.in_force = Some((ctx.now(), *cmd));
        let finite = [cmd.linear_x, cmd.linear_y, cmd.angular_z]
            .iter()
            .all(|v| v.is_finite());
        match self.guard(ctx) {
            // A non-finite command is counted and reported as invalid, then a stop.
            Guard::None => self.obey(ctx, cmd, from),
            Guard::Limit(_) if !finite => self.obey(ctx, cmd, from),
            Guard::Stop => {
                self.state.guarded += 1;
                self.send(&Twist::default())
            }
            Guard::Limit(e) => {
                let (limited, changed) = e.limit(cmd);
                if changed {
                    self.state.guarded += 1;
                }
                self.send(&limited)
            }
        }
    }

    /// A new envelope, or a tick: the command in force (the elected client's last, younger
    /// than `freshness_s`) is limited again, and sent if that changes what the base was told
    /// (a stop once the guard's envelope is stale).
    fn reguard(&mut self, ctx: &mut Context) -> ModuleResult {
        let Some((at, cmd)) = self.in_force else {
            return Ok(());
        };
        if ctx.now().saturating_sub(at) >= self.freshness {
            self.in_force = None;
            return Ok(());
        }
        let out = match self.guard(ctx) {
            Guard::None => return Ok(()),
            Guard::Stop => Twist::default(),
            Guard::Limit(e) => e.limit(&cmd).0,
        };
        let out = Twist {
            header: Default::default(),
            ..clamp_command(&out, self.max_linear, self.max_angular)
        };
        if self.sent != Some(out) {
            self.state.guarded += 1;
            self.send(&out)?;
        }
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
            envelope_in: ctx.subscribe(&envelope_channel(&cfg.cmd_in), None)?,
            envelope: None,
            guards: Vec::new(),
            obeyed_at: None,
            in_force: None,
            sent: None,
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
                if ctx.command_verdict(ROBOT_CONTROL, &cmd.header) == Verdict::Accept {
                    self.obeyed_at = Some(ctx.now());
                    self.obey_guarded(ctx, &cmd, "contract")?;
                }
            }
            return Ok(());
        }
        if input == self.envelope_in.id() {
            let mut got = false;
            while let Some(e) = self.envelope_in.receive()? {
                let source = ModuleId(e.header.source);
                if !self.guards.contains(&source) {
                    self.guards.push(source);
                }
                self.envelope = Some(*e);
                got = true;
            }
            if got {
                self.reguard(ctx)?;
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
                self.obey_guarded(ctx, &cmd, &from)?;
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
        // The guard's envelope went stale under a moving command: stop.
        self.reguard(ctx)?;
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
    use hng_runtime::harness::Harness;
    use hng_runtime::msg::ENVELOPE_BINS;

    fn cmd(v: f64, w: f64) -> Twist {
        Twist {
            linear_x: v,
            angular_z: w,
            ..Default::default()
        }
    }

    /// An envelope allowing `fwd` forward at every curvature and anything backward.
    fn envelope(source: u32, scan_stamp_ns: u64, fwd: f64) -> SpeedEnvelope {
        let mut e = SpeedEnvelope {
            scan_stamp_ns,
            stop: 0,
            turn_in_place: f64::INFINITY,
            forward: [fwd; ENVELOPE_BINS],
            backward: [2.0; ENVELOPE_BINS],
            ..Default::default()
        };
        e.header.source = source;
        e
    }

    #[test]
    fn only_a_guarding_top_holder_limits_and_its_stale_or_missing_envelope_stops() {
        let (sec, gui) = (ModuleId(1), ModuleId(2));
        let s = Duration::from_secs;
        let fresh = envelope(1, s(10).as_nanos() as u64, 0.3);
        fn g<'a>(
            top: Option<ModuleId>,
            guards: &[ModuleId],
            e: Option<&'a SpeedEnvelope>,
            now: Duration,
        ) -> Guard<'a> {
            guard_of(top, guards, e, now, Duration::from_millis(500))
        }
        assert_eq!(
            g(Some(sec), &[sec], Some(&fresh), s(10)),
            Guard::Limit(&fresh)
        );
        assert_eq!(
            g(Some(sec), &[sec], Some(&fresh), s(11)),
            Guard::Stop,
            "stale"
        );
        assert_eq!(g(Some(sec), &[sec], None, s(10)), Guard::Stop, "none yet");
        let other = envelope(2, s(10).as_nanos() as u64, 0.3);
        assert_eq!(g(Some(sec), &[sec, gui], Some(&other), s(10)), Guard::Stop);
        // Security's contract ended (dead, or not back yet): the elected client drives.
        assert_eq!(g(Some(gui), &[sec], Some(&fresh), s(10)), Guard::None);
        assert_eq!(g(None, &[sec], Some(&fresh), s(10)), Guard::None);
        // A holder that never published an envelope limits nothing.
        assert_eq!(g(Some(sec), &[], None, s(10)), Guard::None);
    }

    /// The module's own loop (in-process harness, the static wiring: without a contract
    /// plane the envelope's publisher guards): a command the envelope forbids is limited, at
    /// once when a new envelope comes under a command in force; backing away is not; a stale
    /// envelope stops the robot, turning included.
    #[test]
    fn the_module_limits_commands_by_the_envelope_and_stops_on_a_stale_one() {
        let mut h = Harness::new("robot").unwrap();
        let input = h.input::<Twist>("test/cmd").unwrap();
        let env_in = h
            .input::<SpeedEnvelope>(&envelope_channel("robot/cmd_vel"))
            .unwrap();
        let mut wheels = h.output::<Twist>("test/wheels").unwrap();
        // A freshness far longer than the test: no silence stop of the client interferes.
        h.start::<RobotModule>(
            "sources = [{ channel = \"test/cmd\", priority = \"2.1\" }]\n\
             cmd_out = \"test/wheels\"\nodom_in = \"test/odom\"\nfreshness_s = 30.0",
        )
        .unwrap();
        let wait = Duration::from_secs(5);
        let now = || hng_runtime::clock::Clock::wall().now_ns();

        // Far from everything: nothing limited.
        env_in.publish(envelope(7, now(), 2.0)).unwrap();
        input.publish(cmd(1.0, 0.0)).unwrap();
        h.wait_for(&mut wheels, wait, |c| c.linear_x == 1.0)
            .unwrap();

        // A wall comes near: the command in force is limited at once, curvature kept.
        input.publish(cmd(1.0, 0.4)).unwrap();
        h.wait_for(&mut wheels, wait, |c| c.angular_z == 0.4)
            .unwrap();
        env_in.publish(envelope(7, now(), 0.3)).unwrap();
        let limited = h.wait_for(&mut wheels, wait, |c| c.linear_x < 1.0).unwrap();
        assert!(
            (limited.linear_x - 0.3).abs() < 1e-12 && (limited.angular_z - 0.12).abs() < 1e-12,
            "{limited:?}"
        );
        // Away from it: not limited.
        input.publish(cmd(-0.5, 0.2)).unwrap();
        let back = h.wait_for(&mut wheels, wait, |c| c.linear_x < 0.0).unwrap();
        assert_eq!((back.linear_x, back.angular_z), (-0.5, 0.2));

        // The envelope goes stale (its scan a minute old): the moving robot is stopped, and
        // a new command moves nothing, not even a turn.
        input.publish(cmd(0.2, 0.0)).unwrap();
        h.wait_for(&mut wheels, wait, |c| c.linear_x == 0.2)
            .unwrap();
        let old = now().saturating_sub(60_000_000_000);
        env_in.publish(envelope(7, old, 0.3)).unwrap();
        h.wait_for(&mut wheels, wait, |c| {
            c.linear_x == 0.0 && c.angular_z == 0.0
        })
        .unwrap();
        let n = wheels.samples.len();
        input.publish(cmd(0.3, 0.5)).unwrap();
        h.wait_for(&mut wheels, wait, |_| true).unwrap();
        let after: Vec<_> = wheels.samples[n..].iter().map(|c| c.msg).collect();
        assert!(
            after
                .iter()
                .all(|c| c.linear_x == 0.0 && c.angular_z == 0.0),
            "stale envelope: only stops {after:?}"
        );
        h.finish().unwrap();
    }

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
