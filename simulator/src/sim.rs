//! The simulator: a differential-drive robot in a rapier2d world, stepped explicitly.

use std::f64::consts::TAU;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rapier2d::prelude::{
    ColliderBuilder, ColliderHandle, PhysicsWorld, Pose, QueryFilter, Ray, RigidBodyBuilder,
    RigidBodyHandle, Rotation, Vector,
};

use crate::error::{Result, SimError};
use crate::sensors::{
    BeaconDetection, CameraFrame, CollisionEvent, GpsReading, GpsStatus, GroundTruth, LidarScan,
    Odometry, SensorKind, SensorOutput, SimStats,
};
use crate::snapshot::SimSnapshot;
use crate::world::{BoxObstacle, GpsZoneKind, Pose2D, World};

mod events;

/// The fixed collider of a box obstacle.
fn box_collider(b: &BoxObstacle) -> ColliderBuilder {
    ColliderBuilder::cuboid((b.size[0] / 2.0) as f32, (b.size[1] / 2.0) as f32)
        .position(Pose::new(
            Vector::new(b.center[0] as f32, b.center[1] as f32),
            b.angle as f32,
        ))
        .friction(0.0)
        .restitution(0.0)
}

/// A contact begins when the gap between robot and obstacle falls below this, metres (and ends
/// when it exceeds twice this).
pub const CONTACT_MARGIN: f64 = 0.005;

/// Converts seconds to nanoseconds (rounded; negative and NaN give 0).
#[must_use]
pub fn secs_to_ns(secs: f64) -> u64 {
    if secs.is_finite() && secs > 0.0 {
        (secs * 1e9).round() as u64
    } else {
        0
    }
}

pub use hng_runtime::msg::wrap_angle;

/// Fires at a fixed period on the simulated clock.
#[derive(Debug, Clone)]
struct Timer {
    enabled: bool,
    period_ns: u64,
    next_ns: u64,
}

impl Timer {
    fn new(enabled: bool, rate: f64) -> Self {
        let period_ns = secs_to_ns(1.0 / rate).max(1);
        // Fires at whole multiples of the period: a 10 Hz sensor at 0.1 s, 0.2 s, ...
        Self {
            enabled,
            period_ns,
            next_ns: period_ns,
        }
    }

    fn due(&mut self, now_ns: u64) -> bool {
        if !self.enabled || now_ns < self.next_ns {
            return false;
        }
        self.next_ns += self.period_ns;
        if self.next_ns <= now_ns {
            // Slower than the physics step: fire once per step, no bursts.
            self.next_ns = now_ns + self.period_ns;
        }
        true
    }
}

fn noise(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    if sigma == 0.0 {
        0.0
    } else {
        sigma * rng.sample::<f64, _>(StandardNormal)
    }
}

fn stream(seed: u64, id: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(id);
    rng
}

/// Velocity command state with limits.
#[derive(Debug, Clone, Default)]
struct Drive {
    target_v: f64,
    target_w: f64,
    v: f64,
    w: f64,
    last_cmd_ns: Option<u64>,
    timed_out: bool,
}

#[derive(Debug, Clone, Copy)]
struct TruePose {
    x: f64,
    y: f64,
    theta: f64,
}

/// A deterministic 2D robot simulation. Create it from a [`World`], send velocity commands
/// with [`set_cmd_vel`](Self::set_cmd_vel) and advance it with [`step`](Self::step) or
/// [`run_until`](Self::run_until); each step returns the sensor outputs that became due.
pub struct Simulator {
    world: World,
    phys: PhysicsWorld,
    robot: RigidBodyHandle,
    dt_ns: u64,
    now_ns: u64,
    drive: Drive,
    pose: TruePose,
    true_twist: (f64, f64),
    stats: SimStats,
    in_contact: bool,
    last_clearance: f64,
    // Lidar: unit beam directions relative to the heading, as angles.
    lidar_timer: Timer,
    lidar_angles: Vec<f64>,
    lidar_dirs: Vec<(f64, f64)>,
    lidar_increment: f64,
    lidar_rng: ChaCha8Rng,
    odom_timer: Timer,
    odom_rng: ChaCha8Rng,
    odom_pose: TruePose,
    odom_twist: (f64, f64),
    gps_timer: Timer,
    gps_rng: ChaCha8Rng,
    camera_timer: Timer,
    camera_rng: ChaCha8Rng,
    gt_timer: Timer,
    // World script (crate::script): the next event to apply, the global lighting factor and
    // the boxes scripts added, by name.
    next_event: usize,
    lighting: f64,
    script_boxes: Vec<(String, ColliderHandle, BoxObstacle)>,
}

impl std::fmt::Debug for Simulator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulator")
            .field("world", &self.world.name)
            .field("now_ns", &self.now_ns)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl Simulator {
    /// Builds the physics world. Fails if the world does not validate.
    pub fn new(world: World) -> Result<Self> {
        world.validate()?;
        let mut phys = PhysicsWorld::new();
        phys.gravity = Vector::ZERO;
        phys.integration_parameters.dt = world.dt_s as f32;
        for b in world.obstacle_boxes() {
            phys.insert_collider(box_collider(&b), None);
        }
        let r = &world.robot;
        let body = RigidBodyBuilder::dynamic()
            .translation(Vector::new(r.start.x as f32, r.start.y as f32))
            .rotation(r.start.theta as f32)
            .ccd_enabled(true)
            .can_sleep(false);
        let collider = ColliderBuilder::ball(r.radius as f32)
            .friction(0.0)
            .restitution(0.0)
            .density(1.0);
        let (robot, _) = phys.insert(body, collider);
        // Fill the spatial index so sensors work before the first step.
        phys.detect_collisions(&(), &());

        let s = &world.sensors;
        let l = &s.lidar;
        let beams = l.beams as usize;
        let full_circle = l.fov >= TAU - 1e-9;
        let lidar_increment = if beams <= 1 {
            0.0
        } else if full_circle {
            l.fov / beams as f64
        } else {
            l.fov / (beams - 1) as f64
        };
        let angle_min = if beams <= 1 { 0.0 } else { -l.fov / 2.0 };
        let lidar_angles: Vec<f64> = (0..beams)
            .map(|i| angle_min + i as f64 * lidar_increment)
            .collect();
        let seed = world.seed;
        let pose = TruePose {
            x: r.start.x,
            y: r.start.y,
            theta: wrap_angle(r.start.theta),
        };
        let mut sim = Self {
            dt_ns: secs_to_ns(world.dt_s).max(1),
            now_ns: 0,
            drive: Drive::default(),
            pose,
            true_twist: (0.0, 0.0),
            stats: SimStats::default(),
            in_contact: false,
            last_clearance: f64::INFINITY,
            lidar_timer: Timer::new(l.enabled, l.rate),
            lidar_dirs: lidar_angles.iter().map(|a| (a.cos(), a.sin())).collect(),
            lidar_angles,
            lidar_increment,
            lidar_rng: stream(seed, 1),
            odom_timer: Timer::new(s.odometry.enabled, s.odometry.rate),
            odom_rng: stream(seed, 2),
            odom_pose: TruePose {
                x: 0.0,
                y: 0.0,
                theta: 0.0,
            },
            odom_twist: (0.0, 0.0),
            gps_timer: Timer::new(s.gps.enabled, s.gps.rate),
            gps_rng: stream(seed, 3),
            camera_timer: Timer::new(s.camera.enabled, s.camera.rate),
            camera_rng: stream(seed, 4),
            gt_timer: Timer::new(s.ground_truth.enabled, s.ground_truth.rate),
            next_event: 0,
            lighting: 1.0,
            script_boxes: Vec::new(),
            phys,
            robot,
            world,
        };
        sim.apply_due_events();
        sim.pose = sim.body_pose();
        sim.update_clearance();
        if sim.last_clearance < 0.0 {
            tracing::warn!(
                world = %sim.world.name,
                clearance = sim.last_clearance,
                "robot starts overlapping an obstacle"
            );
        }
        Ok(sim)
    }

    /// The world this simulator was built from.
    #[must_use]
    pub fn world(&self) -> &World {
        &self.world
    }

    /// Simulated time, ns.
    #[must_use]
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// Physics step, ns.
    #[must_use]
    pub fn dt_ns(&self) -> u64 {
        self.dt_ns
    }

    /// Counters: steps, collisions, rejected commands, timeouts, minimum clearance.
    #[must_use]
    pub fn stats(&self) -> SimStats {
        self.stats
    }

    /// Gap between the robot disc and the nearest obstacle now, metres (negative when
    /// penetrating; +inf when nothing within 1 km).
    #[must_use]
    pub fn clearance(&self) -> f64 {
        self.last_clearance
    }

    /// Gap between the robot disc, were it centred at (`x`, `y`), and the nearest obstacle,
    /// metres (negative when it would overlap one; +inf when nothing within 1 km).
    #[must_use]
    pub fn clearance_at(&self, x: f64, y: f64) -> f64 {
        let p = Vector::new(x as f32, y as f32);
        let proj = self.phys.project_point(
            p,
            1000.0,
            false,
            QueryFilter::default().exclude_rigid_body(self.robot),
        );
        match proj {
            Some((_, proj)) => {
                let d = f64::from((proj.point - p).length());
                let signed = if proj.is_inside { -d } else { d };
                signed - self.world.robot.radius
            }
            None => f64::INFINITY,
        }
    }

    /// The true pose and twist now (evaluation only).
    #[must_use]
    pub fn ground_truth(&self) -> GroundTruth {
        GroundTruth {
            stamp_ns: self.now_ns,
            x: self.pose.x,
            y: self.pose.y,
            theta: self.pose.theta,
            linear_x: self.true_twist.0,
            angular_z: self.true_twist.1,
        }
    }

    /// Switches a simulated sensor on or off (off: a real driver or a log provides it).
    pub fn set_sensor_enabled(&mut self, kind: SensorKind, enabled: bool) {
        let timer = match kind {
            SensorKind::Lidar => &mut self.lidar_timer,
            SensorKind::Odometry => &mut self.odom_timer,
            SensorKind::Gps => &mut self.gps_timer,
            SensorKind::Camera => &mut self.camera_timer,
            SensorKind::GroundTruth => &mut self.gt_timer,
        };
        if enabled && !timer.enabled {
            timer.next_ns = self.now_ns;
        }
        timer.enabled = enabled;
    }

    /// Whether a simulated sensor is on.
    #[must_use]
    pub fn sensor_enabled(&self, kind: SensorKind) -> bool {
        match kind {
            SensorKind::Lidar => self.lidar_timer.enabled,
            SensorKind::Odometry => self.odom_timer.enabled,
            SensorKind::Gps => self.gps_timer.enabled,
            SensorKind::Camera => self.camera_timer.enabled,
            SensorKind::GroundTruth => self.gt_timer.enabled,
        }
    }

    /// Commands a twist: forward speed (m/s) and turn rate (rad/s), clamped to the robot's
    /// limits and reached at its maximum accelerations. A NaN or infinite value is rejected:
    /// the robot is told to stop, the rejected-command counter grows and an error is returned.
    pub fn set_cmd_vel(&mut self, linear_x: f64, angular_z: f64) -> Result<()> {
        self.drive.last_cmd_ns = Some(self.now_ns);
        self.drive.timed_out = false;
        if !(linear_x.is_finite() && angular_z.is_finite()) {
            self.drive.target_v = 0.0;
            self.drive.target_w = 0.0;
            self.stats.rejected_commands += 1;
            tracing::warn!(linear_x, angular_z, "rejected non-finite velocity command");
            return Err(SimError::RejectedCommand {
                linear_x,
                angular_z,
            });
        }
        let r = &self.world.robot;
        self.drive.target_v = linear_x.clamp(-r.max_linear_speed, r.max_linear_speed);
        self.drive.target_w = angular_z.clamp(-r.max_angular_speed, r.max_angular_speed);
        Ok(())
    }

    /// Moves the robot to `pose` at rest (e.g. to reset a scenario). Odometry does not see the
    /// jump.
    pub fn teleport(&mut self, pose: Pose2D) -> Result<()> {
        if !(pose.x.is_finite() && pose.y.is_finite() && pose.theta.is_finite()) {
            return Err(SimError::invalid("pose", "must be finite"));
        }
        if let Some(body) = self.phys.bodies.get_mut(self.robot) {
            body.set_position(
                Pose::new(Vector::new(pose.x as f32, pose.y as f32), pose.theta as f32),
                true,
            );
            body.set_linvel(Vector::ZERO, true);
            body.set_angvel(0.0, true);
        }
        self.drive.v = 0.0;
        self.drive.w = 0.0;
        self.drive.target_v = 0.0;
        self.drive.target_w = 0.0;
        self.pose = self.body_pose();
        self.true_twist = (0.0, 0.0);
        self.update_clearance();
        Ok(())
    }

    /// The least clearance counts again from the robot's clearance now (after a teleport:
    /// the old trajectory's close passes are not the new one's).
    pub fn reset_min_clearance(&mut self) {
        self.stats.min_clearance = self.last_clearance;
    }

    /// The restorable state now (see [`SimSnapshot`] for what is and is not kept).
    #[must_use]
    pub fn snapshot(&self) -> SimSnapshot {
        let pose = |p: TruePose| Pose2D::new(p.x, p.y, p.theta);
        let body = self.phys.bodies.get(self.robot).map_or(
            [
                self.pose.x as f32,
                self.pose.y as f32,
                self.pose.theta.cos() as f32,
                self.pose.theta.sin() as f32,
            ],
            |b| {
                let (t, r) = (b.translation(), b.rotation());
                [t.x, t.y, r.re, r.im]
            },
        );
        SimSnapshot {
            now_ns: self.now_ns,
            pose: pose(self.pose),
            body,
            odom: pose(self.odom_pose),
            stats: self.stats,
            next_due_ns: [
                self.lidar_timer.next_ns,
                self.odom_timer.next_ns,
                self.gps_timer.next_ns,
                self.camera_timer.next_ns,
                self.gt_timer.next_ns,
            ],
            rng_word_pos: [
                self.lidar_rng.get_word_pos(),
                self.odom_rng.get_word_pos(),
                self.gps_rng.get_word_pos(),
                self.camera_rng.get_word_pos(),
                0,
            ],
        }
    }

    /// Resumes from a snapshot of a simulator built from the same world: simulated time,
    /// poses, counters, sensor schedule and noise streams. The robot resumes at rest.
    pub fn restore(&mut self, snap: &SimSnapshot) -> Result<()> {
        self.teleport(snap.pose)?;
        let [x, y, re, im] = snap.body;
        if let Some(body) = self.phys.bodies.get_mut(self.robot) {
            body.set_position(
                Pose::from_parts(Vector::new(x, y), Rotation::from_cos_sin_unchecked(re, im)),
                true,
            );
        }
        self.now_ns = snap.now_ns;
        self.replay_events();
        self.pose = self.body_pose();
        self.update_clearance();
        self.odom_pose = TruePose {
            x: snap.odom.x,
            y: snap.odom.y,
            theta: wrap_angle(snap.odom.theta),
        };
        self.odom_twist = (0.0, 0.0);
        self.stats = snap.stats;
        self.drive.last_cmd_ns = None;
        self.drive.timed_out = false;
        let timers = [
            &mut self.lidar_timer,
            &mut self.odom_timer,
            &mut self.gps_timer,
            &mut self.camera_timer,
            &mut self.gt_timer,
        ];
        for (t, next) in timers.into_iter().zip(snap.next_due_ns) {
            t.next_ns = next.max(snap.now_ns);
        }
        self.lidar_rng.set_word_pos(snap.rng_word_pos[0]);
        self.odom_rng.set_word_pos(snap.rng_word_pos[1]);
        self.gps_rng.set_word_pos(snap.rng_word_pos[2]);
        self.camera_rng.set_word_pos(snap.rng_word_pos[3]);
        self.in_contact = self.last_clearance < 2.0 * CONTACT_MARGIN;
        Ok(())
    }

    /// Advances one physics step and returns the outputs that became due.
    pub fn step(&mut self) -> Vec<SensorOutput> {
        let mut out = Vec::new();
        self.step_into(&mut out);
        out
    }

    /// Steps until the simulated time reaches `t_ns`, returning all outputs in order.
    pub fn run_until(&mut self, t_ns: u64) -> Vec<SensorOutput> {
        let mut out = Vec::new();
        while self.now_ns < t_ns {
            self.step_into(&mut out);
        }
        out
    }

    /// Advances one physics step, appending the outputs that became due to `out`.
    pub fn step_into(&mut self, out: &mut Vec<SensorOutput>) {
        self.apply_drive();
        self.phys.step();
        self.now_ns += self.dt_ns;
        self.stats.steps += 1;
        self.apply_due_events();

        let prev = self.pose;
        self.pose = self.body_pose();
        let dt = self.dt_ns as f64 * 1e-9;
        let (c, s) = (prev.theta.cos(), prev.theta.sin());
        let (dx, dy) = (self.pose.x - prev.x, self.pose.y - prev.y);
        let local = (c * dx + s * dy, -s * dx + c * dy);
        let dtheta = wrap_angle(self.pose.theta - prev.theta);
        self.true_twist = (local.0 / dt, dtheta / dt);
        self.integrate_odometry(local, dtheta, dt);

        self.update_clearance();
        // Hysteresis: a contact ends only once the gap exceeds twice the margin, so sliding
        // along a wall counts as one collision.
        let touching = if self.in_contact {
            self.last_clearance < 2.0 * CONTACT_MARGIN
        } else {
            self.last_clearance < CONTACT_MARGIN
        };
        if touching && !self.in_contact {
            self.stats.collisions += 1;
            out.push(SensorOutput::Collision(CollisionEvent {
                stamp_ns: self.now_ns,
                x: self.pose.x,
                y: self.pose.y,
                clearance: self.last_clearance,
            }));
        }
        self.in_contact = touching;

        let now = self.now_ns;
        if self.gt_timer.due(now) {
            out.push(SensorOutput::GroundTruth(self.ground_truth()));
        }
        if self.odom_timer.due(now) {
            out.push(SensorOutput::Odometry(Odometry {
                stamp_ns: now,
                x: self.odom_pose.x,
                y: self.odom_pose.y,
                theta: self.odom_pose.theta,
                linear_x: self.odom_twist.0,
                angular_z: self.odom_twist.1,
            }));
        }
        if self.lidar_timer.due(now) {
            out.push(SensorOutput::Lidar(self.scan_lidar()));
        }
        if self.gps_timer.due(now) {
            out.push(SensorOutput::Gps(self.read_gps()));
        }
        if self.camera_timer.due(now) {
            out.push(SensorOutput::Camera(self.read_camera()));
        }
    }

    /// Casts a ray from `origin` at `angle` (map frame), ignoring the robot; the distance to
    /// the first obstacle within `max_range`, if any.
    #[must_use]
    pub fn cast_ray(&self, origin: [f64; 2], angle: f64, max_range: f64) -> Option<f64> {
        let ray = Ray::new(
            Vector::new(origin[0] as f32, origin[1] as f32),
            Vector::new(angle.cos() as f32, angle.sin() as f32),
        );
        self.phys
            .query_pipeline_with_filter(QueryFilter::default().exclude_rigid_body(self.robot))
            .cast_ray(&ray, max_range as f32, true)
            .map(|(_, toi)| f64::from(toi))
    }

    /// Takes a lidar scan now (whether or not the lidar is due or enabled).
    pub fn scan_lidar(&mut self) -> LidarScan {
        let cfg = &self.world.sensors.lidar;
        let origin = Vector::new(self.pose.x as f32, self.pose.y as f32);
        let max = cfg.max_range as f32;
        let min = cfg.min_range as f32;
        let sigma = cfg.range_sigma;
        let query = self
            .phys
            .query_pipeline_with_filter(QueryFilter::default().exclude_rigid_body(self.robot));
        let (ts, tc) = self.pose.theta.sin_cos();
        let rng = &mut self.lidar_rng;
        let colliders = &self.phys.colliders;
        // Neighbouring beams mostly hit the same wall: cast against it first and use that
        // distance to bound the full query, which prunes most of the tree. Same result.
        let mut last_hit: Option<ColliderHandle> = None;
        let ranges = self
            .lidar_dirs
            .iter()
            .map(|&(bc, bs)| {
                // Beam direction = heading rotated by the beam angle (f64, then f32).
                let (c, s) = (tc * bc - ts * bs, ts * bc + tc * bs);
                let ray = Ray::new(origin, Vector::new(c as f32, s as f32));
                let guess = last_hit.and_then(|h| {
                    let co = colliders.get(h)?;
                    co.shape()
                        .cast_ray(co.position(), &ray, max, true)
                        .map(|toi| (h, toi))
                });
                let hit = query
                    .cast_ray(&ray, guess.map_or(max, |(_, toi)| toi), true)
                    .or(guess);
                last_hit = hit.map(|(h, _)| h);
                match hit {
                    None => f32::INFINITY,
                    Some((_, toi)) if toi < min => f32::NEG_INFINITY,
                    Some((_, toi)) => {
                        let r = f64::from(toi) + noise(rng, sigma);
                        (r as f32).clamp(min, max)
                    }
                }
            })
            .collect();
        LidarScan {
            stamp_ns: self.now_ns,
            angle_min: self.lidar_angles.first().copied().unwrap_or(0.0) as f32,
            angle_increment: self.lidar_increment as f32,
            range_min: min,
            range_max: max,
            ranges,
        }
    }

    fn read_gps(&mut self) -> GpsReading {
        let cfg = &self.world.sensors.gps;
        let (x, y) = (self.pose.x, self.pose.y);
        let mut outage = false;
        let mut multiplier: f64 = 1.0;
        for z in cfg.zones.iter().filter(|z| z.contains(x, y)) {
            match z.kind {
                GpsZoneKind::Outage => outage = true,
                GpsZoneKind::Degraded => multiplier = multiplier.max(z.noise_multiplier),
            }
        }
        if outage {
            return GpsReading {
                stamp_ns: self.now_ns,
                status: GpsStatus::NoFix,
                x: 0.0,
                y: 0.0,
                yaw: 0.0,
                position_sigma: 0.0,
                yaw_sigma: 0.0,
            };
        }
        let ps = cfg.position_sigma * multiplier;
        let ys = cfg.yaw_sigma * multiplier;
        let rng = &mut self.gps_rng;
        GpsReading {
            stamp_ns: self.now_ns,
            status: if multiplier > 1.0 {
                GpsStatus::Degraded
            } else {
                GpsStatus::Fix
            },
            x: x + noise(rng, ps),
            y: y + noise(rng, ps),
            yaw: wrap_angle(self.pose.theta + noise(rng, ys)),
            position_sigma: ps,
            yaw_sigma: ys,
        }
    }

    fn read_camera(&mut self) -> CameraFrame {
        let cfg = &self.world.sensors.camera;
        let query = self
            .phys
            .query_pipeline_with_filter(QueryFilter::default().exclude_rigid_body(self.robot));
        let origin = Vector::new(self.pose.x as f32, self.pose.y as f32);
        let mut detections = Vec::new();
        for b in &self.world.beacons {
            let (dx, dy) = (b.position[0] - self.pose.x, b.position[1] - self.pose.y);
            let distance = dx.hypot(dy);
            if distance > cfg.max_range {
                continue;
            }
            let bearing = wrap_angle(dy.atan2(dx) - self.pose.theta);
            if bearing.abs() > cfg.fov / 2.0 {
                continue;
            }
            if distance > b.radius {
                let dir = Vector::new((dx / distance) as f32, (dy / distance) as f32);
                let ray = Ray::new(origin, dir);
                if query
                    .cast_ray(&ray, (distance - b.radius) as f32, true)
                    .is_some()
                {
                    continue;
                }
            }
            detections.push(BeaconDetection {
                id: b.id,
                bearing: wrap_angle(bearing + noise(&mut self.camera_rng, cfg.bearing_sigma)),
                distance: (distance + noise(&mut self.camera_rng, cfg.range_sigma)).max(0.0),
            });
        }
        CameraFrame {
            stamp_ns: self.now_ns,
            detections,
        }
    }

    fn integrate_odometry(&mut self, local: (f64, f64), dtheta: f64, dt: f64) {
        let cfg = &self.world.sensors.odometry;
        let dist = local.0.hypot(local.1);
        let rng = &mut self.odom_rng;
        let k = 1.0 + cfg.linear_scale_error + noise(rng, cfg.linear_noise);
        let (lx, ly) = (local.0 * k, local.1 * k);
        let dth = dtheta * (1.0 + cfg.angular_scale_error)
            + cfg.heading_drift * local.0
            + noise(
                rng,
                cfg.angular_noise * dtheta.abs() + cfg.angular_noise_per_metre * dist,
            );
        let o = &mut self.odom_pose;
        let (s, c) = o.theta.sin_cos();
        o.x += c * lx - s * ly;
        o.y += s * lx + c * ly;
        o.theta = wrap_angle(o.theta + dth);
        self.odom_twist = (lx / dt, dth / dt);
    }

    fn apply_drive(&mut self) {
        let r = &self.world.robot;
        let d = &mut self.drive;
        let idle_ns = self.now_ns.saturating_sub(d.last_cmd_ns.unwrap_or(0));
        if idle_ns as f64 * 1e-9 > r.cmd_timeout_s && (d.target_v != 0.0 || d.target_w != 0.0) {
            d.target_v = 0.0;
            d.target_w = 0.0;
            if !d.timed_out {
                d.timed_out = true;
                self.stats.command_timeouts += 1;
                tracing::debug!(now_ns = self.now_ns, "command timeout: stopping");
            }
        }
        let dt = self.dt_ns as f64 * 1e-9;
        let dv = r.max_linear_accel * dt;
        let dw = r.max_angular_accel * dt;
        d.v += (d.target_v - d.v).clamp(-dv, dv);
        d.w += (d.target_w - d.w).clamp(-dw, dw);
        // Heading at mid-step, so a constant twist traces the exact arc to second order.
        let (v, w) = (d.v, d.w);
        let (s, c) = (self.pose.theta + w * dt / 2.0).sin_cos();
        if let Some(body) = self.phys.bodies.get_mut(self.robot) {
            body.set_linvel(Vector::new((v * c) as f32, (v * s) as f32), true);
            body.set_angvel(w as f32, true);
        }
    }

    fn body_pose(&self) -> TruePose {
        self.phys.bodies.get(self.robot).map_or(self.pose, |b| {
            let t = b.translation();
            TruePose {
                x: f64::from(t.x),
                y: f64::from(t.y),
                theta: f64::from(b.rotation().angle()),
            }
        })
    }

    fn update_clearance(&mut self) {
        self.last_clearance = self.clearance_at(self.pose.x, self.pose.y);
        self.stats.min_clearance = self.stats.min_clearance.min(self.last_clearance);
    }
}
