//! The modules of HNG v1.0 (paper, Table 1) and their algorithm cores.
//!
//! Algorithm libraries without I/O: [`planning`] (occupancy grids, A*, MovingAI validation)
//! and [`slam`] (CARMEN logs, scan matching, occupancy mapping, a SLAM front end).
//!
//! Modules (each a [`hng_runtime::Module`], run as `hng module <name>`; each keeps its logic
//! in a pure, unit-tested core and its I/O in the module struct): [`manager`], [`security`],
//! [`robot`], [`interface`], [`laser`], [`camera`], [`planning_module`], [`servo`], [`slam_module`],
//! [`gps`], [`maps`]. Their messages beyond the runtime's are in [`msgs`]. See
//! `docs/modules.md`.

pub mod attention;
pub mod camera;
pub mod common;
pub mod ekf;
pub mod feedback;
pub mod footprint;
pub mod gps;
pub mod heartbeat;
pub mod initial_pose;
pub mod interface;
pub mod laser;
pub mod localization;
pub mod manager;
pub mod maps;
pub mod msgs;
pub mod planning;
pub mod planning_module;
pub mod reacher;
pub mod reacher_module;
pub mod robot;
pub mod scan;
pub mod security;
pub mod servo;
pub mod slam;
pub mod slam_module;
pub mod tracker;
pub mod tracker_hist;
pub mod tracker_module;
pub mod video;
pub mod wall_follow;
pub mod wall_follower;
pub mod walls;
pub mod walls_module;

/// Re-exported so users of the SLAM API (poses are `nalgebra` types) need not
/// depend on a matching version themselves.
pub use nalgebra;
