//! The simulator module's outputs: its publishers, and what each step's sensor outputs, the
//! camera images and the status become on them.

use std::time::Instant;

use hng_runtime::msg::{
    self, Beacon as MsgBeacon, BeaconObservation, FrameId, GridInfo, Header, LaserScan,
    MAX_BEACONS, MAX_BEAMS, Message, PoseWithCovariance, Velocity2D,
};
use hng_runtime::{Context, ModuleResult, Node, Publisher, SlicePublisher, Subscriber};

use super::camera::ImageCamera;
use super::config::Channels;
use super::{SimCollision, SimLighting, SimStatus, SimulatorModule};
use crate::map::OccupancyGrid;
use crate::pacing::Speed;
use crate::sensors::{GpsStatus, SensorKind, SensorOutput};
use crate::sim::Simulator;

/// The sensor publishers; `None` for a sensor switched off.
pub(super) struct Outputs {
    pub(super) scan: Option<Publisher<LaserScan>>,
    pub(super) odom: Option<Publisher<msg::Odometry>>,
    pub(super) gps: Option<Publisher<PoseWithCovariance>>,
    pub(super) camera: Option<Publisher<BeaconObservation>>,
    pub(super) ground_truth: Option<Publisher<PoseWithCovariance>>,
    pub(super) collisions: Publisher<SimCollision>,
    pub(super) status: Publisher<SimStatus>,
    pub(super) map: Option<SlicePublisher<GridInfo>>,
    /// Camera images, and the lighting input.
    pub(super) image: Option<ImageCamera>,
    pub(super) lighting: Option<Subscriber<SimLighting>>,
}

impl Outputs {
    /// The publishers of the sensors `sim` has on, on `node` (simulated time stamps); the map's
    /// when there is a grid to publish; the lighting input when there is a camera image.
    pub(super) fn open(
        ctx: &mut Context,
        node: &Node,
        sim: &Simulator,
        ch: &Channels,
        map_grid: Option<&OccupancyGrid>,
    ) -> ModuleResult<Outputs> {
        let on = |k| sim.sensor_enabled(k);
        let image = ImageCamera::new(node, sim.world(), &ch.camera_image)?;
        let lighting = match image {
            Some(_) => Some(ctx.subscribe::<SimLighting>(&ch.lighting, None)?),
            None => None,
        };
        Ok(Outputs {
            scan: sensor_publisher(node, on(SensorKind::Lidar), &ch.scan)?,
            odom: sensor_publisher(node, on(SensorKind::Odometry), &ch.odom)?,
            gps: sensor_publisher(node, on(SensorKind::Gps), &ch.gps)?,
            camera: sensor_publisher(node, on(SensorKind::Camera), &ch.camera)?,
            ground_truth: sensor_publisher(node, on(SensorKind::GroundTruth), &ch.ground_truth)?,
            collisions: node.publisher(&ch.collisions)?,
            status: node.publisher(&ch.status)?,
            map: map_grid
                .map(|g| node.slice_publisher::<GridInfo>(&ch.map, g.data().len()))
                .transpose()?,
            image,
            lighting,
        })
    }
}

/// A publisher on `channel` if the sensor is on.
fn sensor_publisher<T: Message>(
    node: &Node,
    on: bool,
    channel: &str,
) -> Result<Option<Publisher<T>>, hng_runtime::Error> {
    on.then(|| node.publisher(channel)).transpose()
}

fn diag(a: f64, b: f64, c: f64) -> [f64; 9] {
    [a, 0.0, 0.0, 0.0, b, 0.0, 0.0, 0.0, c]
}

/// A pose in the map frame.
fn pose_in_map(x: f64, y: f64, theta: f64, covariance: [f64; 9]) -> PoseWithCovariance {
    PoseWithCovariance {
        header: Header {
            frame_id: FrameId::MAP,
            ..Header::default()
        },
        pose: msg::Pose2D { x, y, theta },
        covariance,
    }
}

impl SimulatorModule {
    /// A camera image, when one is due (seen from the true pose).
    pub(super) fn publish_image(&mut self) -> ModuleResult {
        let gt = self.sim.ground_truth();
        let light = self.sim.lighting();
        match &mut self.outputs.image {
            Some(cam) => cam.step(
                gt.stamp_ns,
                crate::Pose2D::new(gt.x, gt.y, gt.theta),
                light,
                self.sim.script_boxes().map(|(_, b)| b),
            ),
            None => Ok(()),
        }
    }

    pub(super) fn publish(&mut self, output: &SensorOutput) -> ModuleResult {
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
                    let covariance = diag(ps * ps, ps * ps, ys * ys);
                    p.publish(pose_in_map(g.x, g.y, g.yaw, covariance))?;
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
                    p.publish(pose_in_map(gt.x, gt.y, gt.theta, [0.0; 9]))?;
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

    pub(super) fn publish_status(&mut self, ctx: &mut Context) -> ModuleResult {
        if self.restored && self.waiting.is_some() {
            // Restarted, not yet at the system's time: no status that would go back.
            return Ok(());
        }
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
            path_length_m: self.true_path_m,
            lockstep_rounds: self.lockstep.as_ref().map_or(0, |l| l.rounds),
            lockstep_extra_rounds: self.lockstep.as_ref().map_or(0, |l| l.extra_rounds),
            lockstep_calls: self.lockstep.as_ref().map_or(0, |l| l.members),
            teleports: self.teleports,
            teleports_refused: self.teleports_refused,
        })?;
        Ok(())
    }
}
