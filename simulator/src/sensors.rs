//! Sensor outputs: plain structs stamped with simulated time in nanoseconds.
//!
//! Frames (ROS REP-105): `map` is the world frame, `odom` starts at the robot's start pose and
//! drifts, `base_link` is the robot (x forward, y left). Units: metres, radians, seconds.

use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

/// Which sensor; used to switch simulated sensors on and off at run time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum SensorKind {
    /// 2D lidar.
    Lidar,
    /// Wheel odometry.
    Odometry,
    /// GPS/IMU-like absolute pose.
    Gps,
    /// Beacon camera.
    Camera,
    /// Ground-truth pose.
    GroundTruth,
}

/// One lidar scan in `base_link`, like ROS `sensor_msgs/LaserScan`. Beam `i` points at
/// `angle_min + i * angle_increment`. A beam without a return within `range_max` is `+inf`, a
/// return closer than `range_min` is `-inf` (REP-117).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LidarScan {
    /// Simulated time of the scan, ns.
    pub stamp_ns: u64,
    /// Angle of the first beam, radians.
    pub angle_min: f32,
    /// Angle between beams, radians.
    pub angle_increment: f32,
    /// Minimum valid range, metres.
    pub range_min: f32,
    /// Maximum range, metres.
    pub range_max: f32,
    /// Measured ranges, metres.
    pub ranges: Vec<f32>,
}

/// A pose of `base_link` and its twist in `base_link` at a simulated time: [`Odometry`]
/// (in `odom`, as measured) and [`GroundTruth`] (in `map`, true).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseTwist {
    /// Simulated time, ns.
    pub stamp_ns: u64,
    /// x in the frame, metres.
    pub x: f64,
    /// y in the frame, metres.
    pub y: f64,
    /// Heading in the frame, radians in (-π, π].
    pub theta: f64,
    /// Forward speed, m/s (over the last physics step).
    pub linear_x: f64,
    /// Turn rate, rad/s (over the last physics step).
    pub angular_z: f64,
}

/// Odometry: pose of `base_link` in `odom` and the measured twist in `base_link`.
pub type Odometry = PoseTwist;

/// Quality of a GPS fix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum GpsStatus {
    /// Normal noise.
    Fix,
    /// Inside a degraded zone: noise multiplied.
    Degraded,
    /// Inside an outage zone: position and heading are zero and meaningless.
    NoFix,
}

/// GPS/IMU-like pose of `base_link` in `map`, with the standard deviations used for its noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GpsReading {
    /// Simulated time, ns.
    pub stamp_ns: u64,
    /// Fix quality.
    pub status: GpsStatus,
    /// x in the map frame, metres.
    pub x: f64,
    /// y in the map frame, metres.
    pub y: f64,
    /// Heading in the map frame, radians in (-π, π].
    pub yaw: f64,
    /// Standard deviation of x and y, metres (0 without a fix).
    pub position_sigma: f64,
    /// Standard deviation of the heading, radians (0 without a fix).
    pub yaw_sigma: f64,
}

/// A beacon seen by the camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BeaconDetection {
    /// Beacon id.
    pub id: u32,
    /// Bearing in `base_link`, radians, counter-clockwise from forward.
    pub bearing: f64,
    /// Distance from the robot centre to the beacon centre, metres.
    pub distance: f64,
}

/// One camera frame: the visible beacons, in the order of the world's beacon list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraFrame {
    /// Simulated time, ns.
    pub stamp_ns: u64,
    /// Visible beacons.
    pub detections: Vec<BeaconDetection>,
}

/// True pose and twist of the robot in `map` (evaluation only).
pub type GroundTruth = PoseTwist;

/// The robot touched an obstacle (emitted when a contact begins).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CollisionEvent {
    /// Simulated time, ns.
    pub stamp_ns: u64,
    /// Robot x in the map frame, metres.
    pub x: f64,
    /// Robot y in the map frame, metres.
    pub y: f64,
    /// Gap between the robot disc and the nearest obstacle, metres (≤ 0 means penetration).
    pub clearance: f64,
}

/// Anything the simulator produces in a step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum SensorOutput {
    /// A lidar scan.
    Lidar(LidarScan),
    /// An odometry message.
    Odometry(Odometry),
    /// A GPS reading.
    Gps(GpsReading),
    /// A camera frame.
    Camera(CameraFrame),
    /// A ground-truth pose.
    GroundTruth(GroundTruth),
    /// A collision began.
    Collision(CollisionEvent),
}

impl SensorOutput {
    /// Simulated time of the output, ns.
    #[must_use]
    pub fn stamp_ns(&self) -> u64 {
        match self {
            SensorOutput::Lidar(m) => m.stamp_ns,
            SensorOutput::Odometry(m) => m.stamp_ns,
            SensorOutput::Gps(m) => m.stamp_ns,
            SensorOutput::Camera(m) => m.stamp_ns,
            SensorOutput::GroundTruth(m) => m.stamp_ns,
            SensorOutput::Collision(m) => m.stamp_ns,
        }
    }
}

/// Counters kept by the simulator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
pub struct SimStats {
    /// Physics steps taken.
    pub steps: u64,
    /// Contacts begun between the robot and an obstacle.
    pub collisions: u64,
    /// Commands rejected because they were NaN or infinite.
    pub rejected_commands: u64,
    /// Times the robot was stopped because commands stopped arriving.
    pub command_timeouts: u64,
    /// Smallest gap seen between the robot disc and an obstacle, metres (+inf if none in range).
    #[default(f64::INFINITY)]
    pub min_clearance: f64,
}
