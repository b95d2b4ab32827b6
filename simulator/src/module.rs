//! The simulator as an hng module: `hng module simulator`.
//!
//! [`SimulatorModule`] owns a [`Simulator`], steps it on a fixed time step paced against the
//! wall clock ([`Speed`]: real time, a factor, or as fast as possible), publishes every sensor
//! output on its channel stamped with simulated time, drives the simulation clock
//! ([`CLOCK_CHANNEL`]) and takes velocity commands from `sim/cmd_vel`.
//!
//! Teleport: a [`SimTeleport`] on `sim/teleport` puts the robot elsewhere at rest, between two
//! steps (to start another scenario in the same world without restarting the system: `hng
//! eval nav`'s problems, a test). The odometry does not see the jump (tell Localization and
//! SLAM with an operator pose estimate, `operator/initial_pose`), the true path does not
//! count it, and the least clearance in [`SimStatus`] counts again from the new place. A pose
//! that is not finite or overlaps an obstacle is refused, logged and counted.
//!
//! Stepping: a timer of one wall-clock step period (`dt / speed`; 1 ns at `max`) calls
//! [`Module::on_tick`], which takes every step that is due, at most `max_steps_per_tick` of them
//! and for at most 2 ms of wall time. Between ticks the executor handles commands and SIGTERM,
//! so even at `max` speed commands are read at least every `max_steps_per_tick` steps.
//!
//! Time stamps: sensor messages, the map and [`SimStatus`] come from a node of their own whose
//! clock is the simulated time, so their header stamps are simulated nanoseconds. The
//! [`msg::Clock`] samples go through the module's own node (stamped with the wall clock, as the
//! message documents). The module itself runs on the wall clock: [`main`] ignores `HNG_CLOCK=sim`
//! (which `hng run` sets for every module of a simulated system).
//!
//! Paused start: with `wait_for = ["laser", "robot", ...]` simulated time stays at its start
//! until each of these modules has sent its first report on `hng/report` (it is up: configured,
//! started, its contract agent running), so a system whose processes take a while to start
//! (a loaded machine, an accelerated simulation) does not lose simulated seconds to it and
//! runs repeat. After `wait_timeout_s` of wall time it starts anyway and names who is missing.
//!
//! Lockstep: with `lockstep = [...]`, each step's data and then a clock sample carrying a
//! barrier round go out, and the next step waits until every listed module has acknowledged
//! a round in which none of them was busy ([`hng_runtime::clock::lockstep`], glue in
//! `module/lockstep.rs`). A restored simulator publishes its clock only once it knows, from
//! the reports of the modules following it, that it is not behind them.

use std::collections::BTreeSet;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use hng_runtime::channel::InputId;
use hng_runtime::clock::{CLOCK_CHANNEL, Clock, ClockMode};
use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{self, ModuleReport, Twist};
use hng_runtime::{
    Context, Module, ModuleResult, Node, NodeOptions, Publisher, RunOptions, Subscriber, TimerId,
    run_module_with,
};

use crate::map::{OccupancyGrid, grid_from_world};
use crate::pacing::{Pacer, Speed};
use crate::sensors::SensorOutput;
use crate::sim::{Simulator, secs_to_ns};
use crate::snapshot::SimSnapshot;

mod camera;
mod config;
mod lockstep;
mod messages;
mod outputs;

pub use camera::SimLighting;
use config::config_error;
pub use config::{Channels, SensorSwitches, SimModuleConfig};
use lockstep::Lockstep;
pub use messages::{SimCollision, SimStatus, SimTeleport};
use outputs::Outputs;

/// Longest a tick keeps stepping before it returns to the executor.
const TICK_BUDGET: Duration = Duration::from_millis(2);
/// Longest a restarted simulator waits for the reports of the modules following its clock.
const RESTART_WAIT: Duration = Duration::from_secs(2);
/// Period of [`SimStatus`] messages, wall clock.
const STATUS_PERIOD: Duration = Duration::from_millis(100);

/// The simulator module. See the [module documentation](self).
pub struct SimulatorModule {
    sim: Simulator,
    out: Vec<SensorOutput>,
    speed: Speed,
    pacer: Pacer,
    end_ns: Option<u64>,
    max_steps: u32,
    clock_every: u32,
    steps_since_clock: u32,
    accepted: u64,
    gps_no_fix: u64,
    odom_distance: f64,
    last_odom: Option<(f64, f64)>,
    /// True path length, m, and the last true position.
    true_path_m: f64,
    last_true: Option<(f64, f64)>,
    scan_time: f32,
    map_grid: Option<OccupancyGrid>,
    last_status: Instant,
    last_status_sim_ns: u64,
    cmd: Subscriber<Twist>,
    teleport: Option<Subscriber<SimTeleport>>,
    /// Teleports refused (not finite, or into an obstacle).
    teleports: u64,
    teleports_refused: u64,
    /// Paused start: the modules not heard from yet, their reports, and the wall deadline.
    waiting: Option<(BTreeSet<String>, Subscriber<ModuleReport>, Instant)>,
    /// Modules on the simulation clock (waited for or in lockstep): their reports carry their
    /// simulated time, which a restarted simulator must not go back behind.
    followers: BTreeSet<String>,
    /// Highest simulated time a follower reported during the paused start, ns.
    followers_ns: u64,
    /// Restored from a checkpoint (the clock is published only after the paused start).
    restored: bool,
    /// Lockstep barrier, when configured.
    lockstep: Option<Lockstep>,
    clock_pub: Publisher<msg::Clock>,
    outputs: Outputs,
    sim_clock: Clock,
    // Dropped last: the ports above belong to it.
    node: Node,
}

impl std::fmt::Debug for SimulatorModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimulatorModule")
            .field("sim", &self.sim)
            .field("speed", &self.speed)
            .finish_non_exhaustive()
    }
}

impl Module for SimulatorModule {
    type Config = SimModuleConfig;

    /// A clean start in the middle of a run would put the robot back at its start and the
    /// clock back to 0: with neither checkpoint usable the simulator refuses to start.
    const CLEAN_START_AFTER_BAD_CHECKPOINT: bool = false;

    /// 2: the snapshot is a serde value (1 was a hand-written byte layout).
    const STATE_VERSION: u32 = 2;

    fn configure(ctx: &mut Context, cfg: SimModuleConfig) -> ModuleResult<Self> {
        if ctx.clock().is_sim() {
            return Err(
                "the simulator drives the simulation clock itself and must run on the wall \
                 clock: start it with `hng module simulator`, which ignores HNG_CLOCK"
                    .into(),
            );
        }
        let world = cfg.build_world()?;
        let lidar_rate = world.sensors.lidar.rate;
        let map_grid = if cfg.channels.map.is_empty() {
            None
        } else {
            match grid_from_world(&world, cfg.map_resolution) {
                Ok(g) => Some(g),
                Err(e) => {
                    tracing::warn!("ground-truth map not published: {e}");
                    None
                }
            }
        };
        let sim = Simulator::new(world)?;
        let sim_clock = Clock::sim();
        let node = Node::new(
            NodeOptions::new(ctx.name())
                .prefix(ctx.node().prefix())
                .clock(sim_clock.clone()),
        )?;
        let ch = &cfg.channels;
        let outputs = Outputs::open(ctx, &node, &sim, ch, map_grid.as_ref())?;
        let cmd = ctx.subscribe::<Twist>(&ch.cmd_vel, None)?;
        let teleport = if ch.teleport.is_empty() {
            None
        } else {
            Some(ctx.subscribe::<SimTeleport>(&ch.teleport, None)?)
        };
        let lockstep = if cfg.lockstep.is_empty() {
            None
        } else {
            // In lockstep the commands are read when a round closes quiet, before the next
            // step (`lockstep_advance`): a command does not need to wake us (the robot sends
            // up to three per odometry step, each a wake-up for nothing).
            ctx.unsubscribe(cmd.id())?;
            node.track_writes(true);
            Some(Lockstep::new(
                ctx,
                &node,
                &cfg.lockstep,
                (cfg.lockstep_timeout_s, cfg.lockstep_idle_s),
                &cfg.lockstep_outside,
            )?)
        };
        let followers: BTreeSet<String> =
            cfg.wait_for.iter().chain(&cfg.lockstep).cloned().collect();
        let waiting = if cfg.wait_for.is_empty() {
            None
        } else {
            if !(cfg.wait_timeout_s.is_finite() && cfg.wait_timeout_s > 0.0) {
                return Err(config_error("wait_timeout_s", "must be > 0"));
            }
            let reports = ctx.subscribe::<ModuleReport>(REPORT_CHANNEL, None)?;
            let deadline = Instant::now() + Duration::from_secs_f64(cfg.wait_timeout_s);
            Some((cfg.wait_for.iter().cloned().collect(), reports, deadline))
        };
        let clock_pub = ctx.publisher::<msg::Clock>(CLOCK_CHANNEL)?;
        let dt = sim.dt_ns();
        let period_ns = match cfg.speed {
            // In lockstep, answers wake the simulator; the timer only starts it and looks
            // for silent participants.
            Speed::Unlimited if lockstep.is_some() => 1_000_000,
            Speed::Unlimited => 1,
            Speed::RealTime => dt,
            Speed::Factor(f) => ((dt as f64 / f) as u64).max(1),
        };
        ctx.add_timer(Duration::from_nanos(period_ns));
        Ok(Self {
            out: Vec::new(),
            speed: cfg.speed,
            pacer: Pacer::new(cfg.speed, 0),
            end_ns: cfg.duration_s.map(secs_to_ns),
            max_steps: cfg.max_steps_per_tick,
            clock_every: cfg.clock_every_steps,
            steps_since_clock: 0,
            accepted: 0,
            gps_no_fix: 0,
            odom_distance: 0.0,
            last_odom: None,
            true_path_m: 0.0,
            last_true: None,
            scan_time: (1.0 / lidar_rate) as f32,
            map_grid,
            last_status: Instant::now(),
            last_status_sim_ns: 0,
            cmd,
            teleport,
            teleports: 0,
            teleports_refused: 0,
            waiting,
            followers,
            followers_ns: 0,
            restored: false,
            lockstep,
            clock_pub,
            outputs,
            sim_clock,
            sim,
            node,
        })
    }

    fn start(&mut self, ctx: &mut Context) -> ModuleResult {
        let now = self.sim.now_ns();
        self.sim_clock.set_sim_ns(now);
        self.pacer = Pacer::new(self.speed, now);
        self.last_status_sim_ns = now;
        if self.restored && !self.followers.is_empty() {
            // A restarted simulator: the modules following the clock may be ahead of the
            // checkpoint. Their reports say where they are; the clock is published once
            // that is known (end of the paused start), never behind it.
            let reports = match self.waiting.take() {
                Some((_, reports, _)) => reports,
                None => ctx.subscribe::<ModuleReport>(REPORT_CHANNEL, None)?,
            };
            let deadline = Instant::now() + RESTART_WAIT;
            self.waiting = Some((self.followers.clone(), reports, deadline));
        } else {
            self.publish_clock()?;
        }
        if let (Some(grid), Some(publisher)) = (self.map_grid.take(), &self.outputs.map) {
            publisher.publish_copy(grid.info(), grid.data())?;
        }
        self.publish_status(ctx)?;
        tracing::info!(
            module = ctx.name(),
            world = %self.sim.world().name,
            seed = self.sim.world().seed,
            speed = ?self.speed,
            sim_time_s = now as f64 * 1e-9,
            "simulating"
        );
        Ok(())
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if let Some((missing, reports, _)) = &mut self.waiting
            && reports.id() == input
        {
            while let Some(r) = reports.receive()? {
                if self.followers.contains(r.name()) {
                    self.followers_ns = self.followers_ns.max(r.header.stamp_ns);
                }
                missing.remove(r.name());
            }
            if missing.is_empty() {
                tracing::info!(
                    module = ctx.name(),
                    "every module is up: simulated time starts"
                );
                self.end_wait(ctx)?;
            }
            return Ok(());
        }
        if let Some(l) = &mut self.lockstep
            && l.owns(input)
        {
            l.read(ctx)?;
            return self.lockstep_advance(ctx);
        }
        if self.teleport.as_ref().is_some_and(|t| t.id() == input) {
            return self.read_teleports(ctx);
        }
        if let (Some(l), Some(cam)) = (&self.outputs.lighting, &mut self.outputs.image)
            && l.id() == input
        {
            while let Some(m) = l.receive()? {
                cam.set_lighting(m.lighting);
            }
            return Ok(());
        }
        self.read_commands(ctx)
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        if let Some((missing, _, deadline)) = &self.waiting {
            if Instant::now() < *deadline {
                return Ok(());
            }
            let missing: Vec<&str> = missing.iter().map(String::as_str).collect();
            tracing::warn!(
                module = ctx.name(),
                ?missing,
                "modules still not up after wait_timeout_s: simulated time starts anyway"
            );
            self.end_wait(ctx)?;
        }
        if self.lockstep.is_some() {
            self.lockstep_advance(ctx)?;
            self.node.update_connections();
            if self.last_status.elapsed() >= STATUS_PERIOD {
                self.publish_status(ctx)?;
            }
            return Ok(());
        }
        let started = Instant::now();
        for _ in 0..self.max_steps {
            if self.end_ns.is_some_and(|end| self.sim.now_ns() >= end) {
                tracing::info!(module = ctx.name(), "duration reached: stopping");
                ctx.request_stop();
                break;
            }
            let next = self.sim.now_ns().saturating_add(self.sim.dt_ns());
            if !self.pacer.delay_until(next).is_zero() {
                break;
            }
            self.step_and_publish()?;
            if started.elapsed() >= TICK_BUDGET {
                break;
            }
        }
        self.node.update_connections();
        if self.last_status.elapsed() >= STATUS_PERIOD {
            self.publish_status(ctx)?;
        }
        Ok(())
    }

    hng_runtime::checkpoint_with!(Self::save_state, Self::load_state);

    fn stop(&mut self, ctx: &mut Context) {
        if let Err(e) = self.publish_status(ctx) {
            tracing::warn!("final status: {e}");
        }
        let s = self.sim.stats();
        tracing::info!(
            module = ctx.name(),
            sim_time_s = self.sim.now_ns() as f64 * 1e-9,
            steps = s.steps,
            collisions = s.collisions,
            rejected_commands = s.rejected_commands,
            realtime_factor = self.pacer.achieved_factor(self.sim.now_ns()),
            lockstep_rounds = self.lockstep.as_ref().map_or(0, |l| l.rounds),
            lockstep_extra_rounds = self.lockstep.as_ref().map_or(0, |l| l.extra_rounds),
            lockstep_steps_without_round =
                self.lockstep.as_ref().map_or(0, |l| l.steps_without_round),
            lockstep_calls = self.lockstep.as_ref().map_or(0, |l| l.members),
            images_published = self.outputs.image.as_ref().map_or(0, |c| c.published),
            images_skipped_unread = self.outputs.image.as_ref().map_or(0, |c| c.skipped),
            "simulator stopped"
        );
    }
}

/// The simulator process (`hng module simulator`): [`run_module_with`] with the options from the
/// environment, except that the simulator always runs on the wall clock, since it is the source
/// of the simulation clock (a launch file with `clock = "sim"` sets `HNG_CLOCK=sim` for every
/// module).
pub fn main() -> ExitCode {
    hng_runtime::module::init_tracing();
    let mut opts = match RunOptions::from_env("simulator") {
        Ok(o) => o,
        Err(e) => {
            tracing::error!("{e}");
            return ExitCode::from(2);
        }
    };
    opts.clock = ClockMode::Wall;
    let env_wait = std::env::var("HNG_WAIT").ok();
    if let Some(w) = config::wait_mode(&opts.config_toml, env_wait.as_deref()) {
        opts.wait = w;
    }
    match run_module_with::<SimulatorModule>(&opts) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!(module = %opts.name, "{e}");
            ExitCode::from(1)
        }
    }
}

impl SimulatorModule {
    fn save_state(&self) -> SimSnapshot {
        self.sim.snapshot()
    }

    fn load_state(&mut self, snap: SimSnapshot) -> ModuleResult {
        snap.validate()?;
        self.sim.restore(&snap)?;
        if let Some(cam) = &mut self.outputs.image {
            cam.resume_at(snap.now_ns);
        }
        self.restored = true;
        tracing::info!(
            sim_time_s = snap.now_ns as f64 * 1e-9,
            x = snap.pose.x,
            y = snap.pose.y,
            "resuming from checkpoint"
        );
        Ok(())
    }

    /// Ends the paused start: simulated time runs from now on. A restored simulator first
    /// moves its clock up to the latest time a module following it reported, so that time
    /// never goes back for anyone.
    fn end_wait(&mut self, ctx: &mut Context) -> ModuleResult {
        if let Some((_, reports, _)) = self.waiting.take() {
            ctx.unsubscribe(reports.id())?;
        }
        if self.restored {
            let from = self.sim.now_ns();
            if self.followers_ns > from {
                self.skip_time_to(self.followers_ns)?;
                tracing::warn!(
                    module = ctx.name(),
                    checkpoint_s = from as f64 * 1e-9,
                    resumed_s = self.followers_ns as f64 * 1e-9,
                    "the modules were ahead of the checkpoint: the clock resumes at their time \
                     (the world is as at the checkpoint)"
                );
            }
            self.sim_clock.set_sim_ns(self.sim.now_ns());
            self.publish_clock()?;
            self.publish_status(ctx)?;
        }
        self.pacer = Pacer::new(self.speed, self.sim.now_ns());
        Ok(())
    }

    /// Moves simulated time forward to `ns` without stepping the world (sensor schedules
    /// move along).
    fn skip_time_to(&mut self, ns: u64) -> ModuleResult {
        let mut snap = self.sim.snapshot();
        let delta = ns.saturating_sub(snap.now_ns);
        snap.now_ns = ns;
        for d in &mut snap.next_due_ns {
            *d = d.saturating_add(delta);
        }
        self.sim.restore(&snap)?;
        Ok(())
    }

    /// Applies the wheel commands received (a rejected one is published in the status).
    fn read_commands(&mut self, ctx: &mut Context) -> ModuleResult {
        let mut rejected = false;
        while let Some(t) = self.cmd.receive()? {
            match self.sim.set_cmd_vel(t.linear_x, t.angular_z) {
                Ok(()) => self.accepted += 1,
                Err(_) => rejected = true, // logged and counted by the simulator
            }
        }
        if rejected {
            self.publish_status(ctx)?;
        }
        Ok(())
    }

    /// Moves the robot as each [`SimTeleport`] says (between two steps: in lockstep, between
    /// two rounds); a refused one is logged and counted.
    fn read_teleports(&mut self, ctx: &mut Context) -> ModuleResult {
        let Some(sub) = &self.teleport else {
            return Ok(());
        };
        let (mut moved, mut answered) = (false, false);
        while let Some(t) = sub.receive()? {
            answered = true;
            // Checked before the robot moves: a refused teleport leaves it as it was, moving.
            // (A pose that is not finite is the simulator's to refuse.)
            let finite = t.pose.x.is_finite() && t.pose.y.is_finite();
            let refused = if finite && self.sim.clearance_at(t.pose.x, t.pose.y) <= 0.0 {
                Some(format!(
                    "({:.2}, {:.2}) overlaps an obstacle",
                    t.pose.x, t.pose.y
                ))
            } else {
                self.sim.teleport(t.pose).err().map(|e| e.to_string())
            };
            match refused {
                Some(why) => {
                    self.teleports_refused += 1;
                    tracing::warn!(
                        module = ctx.name(),
                        refused = self.teleports_refused,
                        "teleport refused: {why}"
                    );
                }
                None => {
                    moved = true;
                    self.teleports += 1;
                    self.sim.reset_min_clearance();
                    tracing::info!(
                        module = ctx.name(),
                        x = t.pose.x,
                        y = t.pose.y,
                        theta = t.pose.theta,
                        "robot teleported"
                    );
                }
            }
        }
        if moved {
            // The jump is not a path.
            self.last_true = None;
        }
        if answered {
            // The sender learns at once whether the robot moved.
            self.publish_status(ctx)?;
        }
        Ok(())
    }

    /// The simulator (tests drive the module by hand).
    #[must_use]
    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }

    fn publish_clock(&mut self) -> ModuleResult {
        self.steps_since_clock = 0;
        self.clock_pub.publish(msg::Clock {
            sim_time_ns: self.sim.now_ns(),
            round: self.lockstep.as_ref().map_or(0, Lockstep::round),
            ..Default::default()
        })?;
        Ok(())
    }

    fn step_and_publish(&mut self) -> ModuleResult {
        let mut out = std::mem::take(&mut self.out);
        out.clear();
        self.sim.step_into(&mut out);
        self.sim_clock.set_sim_ns(self.sim.now_ns());
        let gt = self.sim.ground_truth();
        if let Some((x, y)) = self.last_true {
            self.true_path_m += (gt.x - x).hypot(gt.y - y);
        }
        self.last_true = Some((gt.x, gt.y));
        self.steps_since_clock += 1;
        let result = if self.lockstep.is_some() {
            // Lockstep: the step's data first, then the clock sample that opens the round.
            // Modules hold their inputs until they see the round, so they handle the whole
            // step together, at its time. A step that sends nothing the modules read (ground
            // truth is for evaluation) and reaches no module's deadline needs no round.
            // The step's readers are the round's members: what it writes is noted.
            let _ = self.node.take_written();
            let images = self.outputs.image.as_ref().map(|c| c.published);
            let sent = out
                .iter()
                .try_for_each(|o| self.publish(o))
                .and_then(|()| self.publish_image());
            let image_sent = images != self.outputs.image.as_ref().map(|c| c.published);
            let data = out
                .iter()
                .any(|o| !matches!(o, SensorOutput::GroundTruth(_)));
            let written = self.node.take_written();
            let now = self.sim.now_ns();
            let wants = self
                .lockstep
                .as_mut()
                .is_some_and(|l| l.step_wants_round(now, &written, data || image_sent));
            let quiet_until = self.quiet_until_ns();
            match self.lockstep.as_mut() {
                Some(l) if wants && sent.is_ok() => {
                    l.open(now, false, quiet_until)?;
                    self.publish_clock()
                }
                Some(l) => {
                    l.steps_without_round += 1;
                    sent
                }
                None => sent,
            }
        } else if self.steps_since_clock >= self.clock_every || !out.is_empty() {
            // The clock goes first, so a module woken by sensor data already has the new time.
            self.publish_clock()
                .and_then(|()| out.iter().try_for_each(|o| self.publish(o)))
                .and_then(|()| self.publish_image())
        } else {
            Ok(())
        };
        self.out = out;
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<SimModuleConfig, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn config_parses_speeds_switches_and_overrides() -> ModuleResult {
        assert_eq!(parse("")?.speed, Speed::RealTime);
        assert_eq!(parse("speed = \"max\"")?.speed, Speed::Unlimited);
        assert_eq!(parse("speed = 10")?.speed, Speed::Factor(10.0));
        assert_eq!(parse("speed = 2.5")?.speed, Speed::Factor(2.5));
        assert!(parse("speed = -1").is_err());
        assert!(parse("speed = \"fast\"").is_err());
        let c = parse(
            "seed = 9\nstart = { x = 3.0, y = 4.0 }\n[sensors]\nlidar = false\n[channels]\nscan = \"a/scan\"",
        )?;
        let w = c.build_world()?;
        assert_eq!(w.seed, 9);
        assert_eq!((w.robot.start.x, w.robot.start.y), (3.0, 4.0));
        assert!(!w.sensors.lidar.enabled && w.sensors.odometry.enabled);
        assert_eq!(c.channels.scan, "a/scan");
        assert_eq!(c.channels.odom, "sim/odom");
        Ok(())
    }

    #[test]
    fn bad_configs_name_the_field() {
        fn error<T, E: std::fmt::Display>(r: Result<T, E>) -> String {
            r.err().map(|e| e.to_string()).unwrap_or_default()
        }
        let e = error(parse("sped = 1"));
        assert!(e.contains("sped"), "{e}");
        let e = error(parse("[sensors]\nlidar = 1"));
        assert!(e.contains("lidar"), "{e}");
        let e = error(
            SimModuleConfig {
                world: Some("map.yaml".into()),
                ..Default::default()
            }
            .build_world(),
        );
        assert!(e.contains("`start`"), "{e}");
        let e = error(
            SimModuleConfig {
                duration_s: Some(f64::NAN),
                ..Default::default()
            }
            .build_world(),
        );
        assert!(e.contains("`duration_s`"), "{e}");
    }
}
