//! hng-simulator: a deterministic 2D robot simulator for hng.
//!
//! A differential-drive disc robot moves among walls in a [rapier2d] world. The simulator is a
//! library stepped explicitly: no threads, no wall clock. Each [`Simulator::step`] advances the
//! fixed physics step and returns the [`SensorOutput`]s that became due: lidar, odometry,
//! GPS/IMU-like pose, beacon camera, ground truth and collision events, each stamped with the
//! simulated time in nanoseconds. Noise is seeded from the world seed, so the same seed and the
//! same commands give bit-identical streams.
//!
//! Worlds come from TOML files ([`World::load`]), ROS map_server maps
//! ([`World::from_occupancy_map`]) or [`World::default_world`]. Most fields have defaults (see
//! each struct); unknown fields are errors, and errors name the file, line and field. This is
//! `simulator/worlds/example.toml`:
//!
//! ```toml
#![doc = include_str!("../worlds/example.toml")]
//! ```

pub mod bench;
mod error;
pub mod generate;
pub mod map;
pub mod module;
mod pacing;
pub mod render;
pub mod script;
mod sensors;
mod sim;
mod snapshot;
mod world;

pub use error::{Result, SimError};
pub use map::{OccupancyGrid, grid_boxes, grid_from_world};
pub use module::{SimModuleConfig, SimStatus, SimulatorModule};
pub use pacing::{Pacer, Speed};
pub use sensors::{
    BeaconDetection, CameraFrame, CollisionEvent, GpsReading, GpsStatus, GroundTruth, LidarScan,
    Odometry, PoseTwist, SensorKind, SensorOutput, SimStats,
};
pub use sim::{CONTACT_MARGIN, Simulator, secs_to_ns, wrap_angle};
pub use snapshot::SimSnapshot;
pub use world::{
    Beacon, BoxObstacle, CameraConfig, Circle, GpsConfig, GpsZone, GpsZoneKind, GroundTruthConfig,
    LidarConfig, MapRef, OdometryConfig, Pose2D, Rect, RobotConfig, SensorsConfig, Wall, World,
};
