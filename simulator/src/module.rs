//! The simulator as an hng module: `hng module simulator`.
//!
//! [`SimulatorModule`] owns a [`Simulator`], steps it on a fixed time step paced against the
//! wall clock ([`Speed`]: real time, a factor, or as fast as possible), publishes every sensor
//! output on its channel stamped with simulated time, drives the simulation clock
//! ([`CLOCK_CHANNEL`]) and takes velocity commands from `sim/cmd_vel`.
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

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use hng_runtime::channel::InputId;
use hng_runtime::clock::{CLOCK_CHANNEL, Clock, ClockMode};
use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{
    self, Beacon as MsgBeacon, BeaconObservation, FrameId, GridInfo, Header, LaserScan,
    MAX_BEACONS, MAX_BEAMS, ModuleReport, PoseWithCovariance, Twist, Velocity2D,
};
use hng_runtime::qos::ChannelKind;
use hng_runtime::{
    Context, Module, ModuleResult, Node, NodeOptions, Publisher, RunOptions, SlicePublisher,
    Subscriber, TimerId, run_module_with,
};
use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Deserializer, Serialize};

use crate::map::{OccupancyGrid, grid_from_world};
use crate::pacing::{Pacer, Speed};
use crate::sensors::{GpsStatus, SensorKind, SensorOutput};
use crate::sim::{Simulator, secs_to_ns};
use crate::snapshot::SimSnapshot;
use crate::world::{Pose2D, World};

/// Longest a tick keeps stepping before it returns to the executor.
const TICK_BUDGET: Duration = Duration::from_millis(2);
/// Period of [`SimStatus`] messages, wall clock.
const STATUS_PERIOD: Duration = Duration::from_millis(100);

/// Counters and pacing of the simulator, published on `sim/status` (a state channel: late
/// joiners get the latest). Header stamp: simulated time.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-simulator/SimStatus/v1")]
pub struct SimStatus {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// Simulated time, ns.
    pub sim_time_ns: u64,
    /// Physics steps taken.
    pub steps: u64,
    /// Contacts begun between the robot and an obstacle.
    pub collisions: u64,
    /// Velocity commands rejected because they were NaN or infinite (the robot was stopped).
    pub rejected_commands: u64,
    /// Velocity commands accepted.
    pub accepted_commands: u64,
    /// Times the robot stopped because commands stopped coming.
    pub command_timeouts: u64,
    /// GPS readings not published because the robot was in an outage zone.
    pub gps_no_fix: u64,
    /// Smallest gap seen between robot and obstacle, m (+inf if none).
    pub min_clearance: f64,
    /// Simulated seconds per wall second over the last status period.
    pub realtime_factor: f64,
    /// The speed asked for (0 means as fast as possible).
    pub target_factor: f64,
}

hng_runtime::impl_message!(SimStatus, ChannelKind::State);

/// A collision began (published on `sim/collisions`). Header stamp: simulated time.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-simulator/SimCollision/v1")]
pub struct SimCollision {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// Robot x, m.
    pub x: f64,
    /// Robot y, m.
    pub y: f64,
    /// Gap between robot and obstacle, m (≤ 0: penetration).
    pub clearance: f64,
    /// Collisions so far, this one included.
    pub count: u64,
}

hng_runtime::impl_message!(SimCollision, ChannelKind::Sensor);

/// Per-sensor switches; `None` keeps the world file's setting. A sensor switched off publishes
/// nothing and does not even open its channel, so a real driver or a log replay can provide it
/// (hybrid simulation).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorSwitches {
    /// Lidar on `channels.scan`.
    pub lidar: Option<bool>,
    /// Odometry on `channels.odom`.
    pub odometry: Option<bool>,
    /// GPS on `channels.gps`.
    pub gps: Option<bool>,
    /// Beacon camera on `channels.camera`.
    pub camera: Option<bool>,
    /// Ground truth on `channels.ground_truth`.
    pub ground_truth: Option<bool>,
}

/// Channel names.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Channels {
    /// Lidar, `LaserScan` in `laser` (default `sim/scan`).
    pub scan: String,
    /// Odometry, `Odometry` odom → base_link (default `sim/odom`).
    pub odom: String,
    /// GPS/IMU pose, `PoseWithCovariance` in `map` (default `sim/gps`).
    pub gps: String,
    /// Beacon camera, `BeaconObservation` in `camera` (default `sim/camera`).
    pub camera: String,
    /// True pose, `PoseWithCovariance` in `map`, evaluation only (default `sim/ground_truth`).
    pub ground_truth: String,
    /// Collision events, [`SimCollision`] (default `sim/collisions`).
    pub collisions: String,
    /// Counters, [`SimStatus`] (default `sim/status`).
    pub status: String,
    /// Velocity commands in, `Twist` (default `sim/cmd_vel`).
    pub cmd_vel: String,
    /// Ground-truth occupancy grid, `GridInfo` + `[i8]`, published once (default `sim/map`;
    /// empty: not published).
    pub map: String,
}

impl Default for Channels {
    fn default() -> Self {
        Self {
            scan: "sim/scan".into(),
            odom: "sim/odom".into(),
            gps: "sim/gps".into(),
            camera: "sim/camera".into(),
            ground_truth: "sim/ground_truth".into(),
            collisions: "sim/collisions".into(),
            status: "sim/status".into(),
            cmd_vel: "sim/cmd_vel".into(),
            map: "sim/map".into(),
        }
    }
}

/// Configuration of `hng module simulator` (the `config` table of its launch-file entry).
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimModuleConfig {
    /// World file: a TOML world, or a map_server YAML (`.yaml`/`.yml`, then `start` is needed).
    /// Default: the built-in world.
    pub world: Option<PathBuf>,
    /// Robot start pose, overriding the world's.
    pub start: Option<Pose2D>,
    /// `"realtime"` (default), a factor such as `10`, or `"max"`.
    #[serde(deserialize_with = "de_speed")]
    pub speed: Speed,
    /// Noise seed, overriding the world's.
    pub seed: Option<u64>,
    /// Stop cleanly after this many simulated seconds.
    pub duration: Option<f64>,
    /// Sensor switches (hybrid simulation).
    pub sensors: SensorSwitches,
    /// Channel names.
    pub channels: Channels,
    /// Cell size of the published ground-truth map, m (default 0.05).
    pub map_resolution: f64,
    /// Most physics steps per tick before commands and signals are looked at (default 10).
    pub max_steps_per_tick: u32,
    /// Publish the clock every this many steps (default 1), and always with sensor data.
    pub clock_every_steps: u32,
    /// Modules whose first report simulated time waits for (default none: it starts at once).
    pub wait_for: Vec<String>,
    /// Longest wait for them, s of wall time (default 10).
    pub wait_timeout_s: f64,
}

impl Default for SimModuleConfig {
    fn default() -> Self {
        Self {
            world: None,
            start: None,
            speed: Speed::RealTime,
            seed: None,
            duration: None,
            sensors: SensorSwitches::default(),
            channels: Channels::default(),
            map_resolution: 0.05,
            max_steps_per_tick: 10,
            clock_every_steps: 1,
            wait_for: Vec::new(),
            wait_timeout_s: 10.0,
        }
    }
}

fn de_speed<'de, D: Deserializer<'de>>(d: D) -> Result<Speed, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Raw {
        Number(f64),
        Text(String),
    }
    let text = match Raw::deserialize(d)? {
        Raw::Number(f) => f.to_string(),
        Raw::Text(s) => s,
    };
    text.parse().map_err(serde::de::Error::custom)
}

fn config_error(
    field: &str,
    message: impl std::fmt::Display,
) -> Box<dyn std::error::Error + Send + Sync> {
    format!("simulator config: field `{field}`: {message}").into()
}

impl SimModuleConfig {
    /// The world this configuration describes: loaded, with the overrides applied.
    pub fn build_world(&self) -> ModuleResult<World> {
        let mut world = match &self.world {
            None => World::default_world(),
            Some(path) => {
                let is_yaml = path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                    e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml")
                });
                if is_yaml {
                    let start = self.start.ok_or_else(|| {
                        config_error(
                            "start",
                            format!(
                                "a map_server world ({}) has no robot pose: give `start = {{ x = .., y = .. }}`",
                                path.display()
                            ),
                        )
                    })?;
                    World::from_occupancy_map(path, start)?
                } else {
                    World::load(path)?
                }
            }
        };
        if let Some(start) = self.start {
            world.robot.start = start;
        }
        if let Some(seed) = self.seed {
            world.seed = seed;
        }
        let s = &self.sensors;
        let sw = &mut world.sensors;
        for (switch, enabled) in [
            (s.lidar, &mut sw.lidar.enabled),
            (s.odometry, &mut sw.odometry.enabled),
            (s.gps, &mut sw.gps.enabled),
            (s.camera, &mut sw.camera.enabled),
            (s.ground_truth, &mut sw.ground_truth.enabled),
        ] {
            if let Some(on) = switch {
                *enabled = on;
            }
        }
        if world.sensors.lidar.beams as usize > MAX_BEAMS {
            return Err(config_error(
                "sensors.lidar.beams",
                format!(
                    "{} beams do not fit a LaserScan message (at most {MAX_BEAMS})",
                    world.sensors.lidar.beams
                ),
            ));
        }
        if let Some(d) = self.duration
            && !(d.is_finite() && d > 0.0)
        {
            return Err(config_error(
                "duration",
                format!("must be > 0 seconds, got {d}"),
            ));
        }
        if self.max_steps_per_tick == 0 {
            return Err(config_error("max_steps_per_tick", "must be at least 1"));
        }
        if self.clock_every_steps == 0 {
            return Err(config_error("clock_every_steps", "must be at least 1"));
        }
        Ok(world)
    }
}

/// The sensor publishers; `None` for a sensor switched off.
struct Outputs {
    scan: Option<Publisher<LaserScan>>,
    odom: Option<Publisher<msg::Odometry>>,
    gps: Option<Publisher<PoseWithCovariance>>,
    camera: Option<Publisher<BeaconObservation>>,
    ground_truth: Option<Publisher<PoseWithCovariance>>,
    collisions: Publisher<SimCollision>,
    status: Publisher<SimStatus>,
    map: Option<SlicePublisher<GridInfo>>,
}

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
    scan_time: f32,
    map_grid: Option<OccupancyGrid>,
    last_status: Instant,
    last_status_sim_ns: u64,
    cmd: Subscriber<Twist>,
    /// Paused start: the modules not heard from yet, their reports, and the wall deadline.
    waiting: Option<(BTreeSet<String>, Subscriber<ModuleReport>, Instant)>,
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
        let on = |k| sim.sensor_enabled(k);
        let outputs = Outputs {
            scan: on(SensorKind::Lidar)
                .then(|| node.publisher(&ch.scan))
                .transpose()?,
            odom: on(SensorKind::Odometry)
                .then(|| node.publisher(&ch.odom))
                .transpose()?,
            gps: on(SensorKind::Gps)
                .then(|| node.publisher(&ch.gps))
                .transpose()?,
            camera: on(SensorKind::Camera)
                .then(|| node.publisher(&ch.camera))
                .transpose()?,
            ground_truth: on(SensorKind::GroundTruth)
                .then(|| node.publisher(&ch.ground_truth))
                .transpose()?,
            collisions: node.publisher(&ch.collisions)?,
            status: node.publisher(&ch.status)?,
            map: map_grid
                .as_ref()
                .map(|g| node.slice_publisher::<GridInfo>(&ch.map, g.data().len()))
                .transpose()?,
        };
        let cmd = ctx.subscribe::<Twist>(&ch.cmd_vel, None)?;
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
            Speed::Unlimited => 1,
            Speed::RealTime => dt,
            Speed::Factor(f) => ((dt as f64 / f) as u64).max(1),
        };
        ctx.add_timer(Duration::from_nanos(period_ns));
        Ok(Self {
            out: Vec::new(),
            speed: cfg.speed,
            pacer: Pacer::new(cfg.speed, 0),
            end_ns: cfg.duration.map(secs_to_ns),
            max_steps: cfg.max_steps_per_tick,
            clock_every: cfg.clock_every_steps,
            steps_since_clock: 0,
            accepted: 0,
            gps_no_fix: 0,
            odom_distance: 0.0,
            last_odom: None,
            scan_time: (1.0 / lidar_rate) as f32,
            map_grid,
            last_status: Instant::now(),
            last_status_sim_ns: 0,
            cmd,
            waiting,
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
        self.publish_clock()?;
        if let (Some(grid), Some(publisher)) = (self.map_grid.take(), &self.outputs.map) {
            let info = GridInfo {
                header: Header {
                    frame_id: FrameId::MAP,
                    ..Header::default()
                },
                resolution: grid.resolution() as f32,
                width: grid.width(),
                height: grid.height(),
                origin: msg::Pose2D {
                    x: grid.origin()[0],
                    y: grid.origin()[1],
                    theta: grid.origin_yaw(),
                },
            };
            publisher.publish_copy(info, grid.data())?;
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

    fn checkpoint(&self) -> Option<Vec<u8>> {
        Some(self.sim.snapshot().to_bytes())
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        let snap = SimSnapshot::from_bytes(state)?;
        self.sim.restore(&snap)?;
        tracing::info!(
            sim_time_s = snap.now_ns as f64 * 1e-9,
            x = snap.pose.x,
            y = snap.pose.y,
            "resuming from checkpoint"
        );
        Ok(())
    }

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
    match run_module_with::<SimulatorModule>(&opts) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!(module = %opts.name, "{e}");
            ExitCode::from(1)
        }
    }
}

fn diag(a: f64, b: f64, c: f64) -> [f64; 9] {
    [a, 0.0, 0.0, 0.0, b, 0.0, 0.0, 0.0, c]
}

impl SimulatorModule {
    /// Ends the paused start: simulated time runs from now on.
    fn end_wait(&mut self, ctx: &mut Context) -> ModuleResult {
        if let Some((_, reports, _)) = self.waiting.take() {
            ctx.unsubscribe(reports.id())?;
        }
        self.pacer = Pacer::new(self.speed, self.sim.now_ns());
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
            ..Default::default()
        })?;
        Ok(())
    }

    fn step_and_publish(&mut self) -> ModuleResult {
        let mut out = std::mem::take(&mut self.out);
        out.clear();
        self.sim.step_into(&mut out);
        self.sim_clock.set_sim_ns(self.sim.now_ns());
        self.steps_since_clock += 1;
        // The clock goes first, so a module woken by sensor data already has the new time.
        let result = if self.steps_since_clock >= self.clock_every || !out.is_empty() {
            self.publish_clock()
        } else {
            Ok(())
        };
        let result = result.and_then(|()| out.iter().try_for_each(|o| self.publish(o)));
        self.out = out;
        result
    }

    fn publish(&mut self, output: &SensorOutput) -> ModuleResult {
        let o = &self.outputs;
        match output {
            SensorOutput::Lidar(scan) => {
                if let Some(p) = &o.scan {
                    let mut m = p.loan()?;
                    let n = scan.ranges.len().min(MAX_BEAMS);
                    m.header.frame_id = FrameId::LASER;
                    m.angle_min = scan.angle_min;
                    m.angle_increment = scan.angle_increment;
                    m.time_increment = 0.0;
                    m.scan_time = self.scan_time;
                    m.range_min = scan.range_min;
                    m.range_max = scan.range_max;
                    m.count = n as u32;
                    m.ranges[..n].copy_from_slice(&scan.ranges[..n]);
                    m.publish()?;
                }
            }
            SensorOutput::Odometry(od) => {
                if let Some((px, py)) = self.last_odom {
                    self.odom_distance += (od.x - px).hypot(od.y - py);
                }
                self.last_odom = Some((od.x, od.y));
                if let Some(p) = &o.odom {
                    let c = &self.sim.world().sensors.odometry;
                    // Indicative 1-sigma growth with the distance driven (see docs/simulator.md).
                    let d = self.odom_distance;
                    let sxy = (c.linear_scale_error.abs() + c.linear_noise) * d;
                    let sth = (c.heading_drift.abs() + c.angular_noise_per_metre) * d;
                    let sv = c.linear_noise * od.linear_x.abs();
                    let sw = c.angular_noise * od.angular_z.abs();
                    p.publish(msg::Odometry {
                        header: Header {
                            frame_id: FrameId::ODOM,
                            ..Header::default()
                        },
                        child_frame_id: FrameId::BASE_LINK,
                        pose: msg::Pose2D {
                            x: od.x,
                            y: od.y,
                            theta: od.theta,
                        },
                        twist: Velocity2D {
                            vx: od.linear_x,
                            vy: 0.0,
                            wz: od.angular_z,
                        },
                        pose_covariance: diag(sxy * sxy, sxy * sxy, sth * sth),
                        twist_covariance: diag(sv * sv, 0.0, sw * sw),
                    })?;
                }
            }
            SensorOutput::Gps(g) => {
                if g.status == GpsStatus::NoFix {
                    self.gps_no_fix += 1;
                } else if let Some(p) = &o.gps {
                    let (ps, ys) = (g.position_sigma, g.yaw_sigma);
                    p.publish(PoseWithCovariance {
                        header: Header {
                            frame_id: FrameId::MAP,
                            ..Header::default()
                        },
                        pose: msg::Pose2D {
                            x: g.x,
                            y: g.y,
                            theta: g.yaw,
                        },
                        covariance: diag(ps * ps, ps * ps, ys * ys),
                    })?;
                }
            }
            SensorOutput::Camera(frame) => {
                if let Some(p) = &o.camera {
                    let mut m = BeaconObservation {
                        header: Header {
                            frame_id: FrameId::CAMERA,
                            ..Header::default()
                        },
                        ..Default::default()
                    };
                    for (slot, d) in m.beacons.iter_mut().zip(&frame.detections) {
                        *slot = MsgBeacon {
                            id: d.id,
                            bearing: d.bearing,
                            range: d.distance,
                        };
                    }
                    m.count = frame.detections.len().min(MAX_BEACONS) as u32;
                    p.publish(m)?;
                }
            }
            SensorOutput::GroundTruth(gt) => {
                if let Some(p) = &o.ground_truth {
                    p.publish(PoseWithCovariance {
                        header: Header {
                            frame_id: FrameId::MAP,
                            ..Header::default()
                        },
                        pose: msg::Pose2D {
                            x: gt.x,
                            y: gt.y,
                            theta: gt.theta,
                        },
                        covariance: [0.0; 9],
                    })?;
                }
            }
            SensorOutput::Collision(c) => {
                o.collisions.publish(SimCollision {
                    header: Header {
                        frame_id: FrameId::MAP,
                        ..Header::default()
                    },
                    x: c.x,
                    y: c.y,
                    clearance: c.clearance,
                    count: self.sim.stats().collisions,
                })?;
            }
        }
        Ok(())
    }

    fn publish_status(&mut self, ctx: &mut Context) -> ModuleResult {
        let now = self.sim.now_ns();
        let wall = self.last_status.elapsed().as_secs_f64();
        let factor = if wall > 0.0 {
            now.saturating_sub(self.last_status_sim_ns) as f64 * 1e-9 / wall
        } else {
            0.0
        };
        self.last_status = Instant::now();
        self.last_status_sim_ns = now;
        let target = match self.speed {
            Speed::Unlimited => 0.0,
            Speed::RealTime => 1.0,
            Speed::Factor(f) => f,
        };
        // Quality: how well the asked-for speed is kept (1 at `max`).
        let quality = if target > 0.0 && wall > 0.05 {
            (factor / target).min(1.0) as f32
        } else {
            1.0
        };
        ctx.set_quality(true, quality);
        let s = self.sim.stats();
        self.outputs.status.publish(SimStatus {
            header: Header {
                frame_id: FrameId::MAP,
                ..Header::default()
            },
            sim_time_ns: now,
            steps: s.steps,
            collisions: s.collisions,
            rejected_commands: s.rejected_commands,
            accepted_commands: self.accepted,
            command_timeouts: s.command_timeouts,
            gps_no_fix: self.gps_no_fix,
            min_clearance: s.min_clearance,
            realtime_factor: factor,
            target_factor: target,
        })?;
        Ok(())
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
        let e = parse("sped = 1")
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("sped"), "{e}");
        let e = parse("[sensors]\nlidar = 1")
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("lidar"), "{e}");
        let c = SimModuleConfig {
            world: Some("map.yaml".into()),
            ..Default::default()
        };
        let e = c
            .build_world()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("`start`"), "{e}");
        let c = SimModuleConfig {
            duration: Some(f64::NAN),
            ..Default::default()
        };
        let e = c
            .build_world()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("`duration`"), "{e}");
    }
}
