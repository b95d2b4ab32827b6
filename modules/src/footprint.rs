//! The robot's footprint: one place for the radius that Planning (its costmap's lethal band),
//! Security (its swept disc) and the Servo-controller's recovery motions use.
//!
//! The simulated robot is a disc of radius 0.2 m (`hng_simulator::RobotConfig::radius`'s
//! default, which the simulator owns: it does not depend on this crate).

/// The robot's radius, m.
pub const ROBOT_RADIUS_M: f64 = 0.2;

/// Margin around the disc that nothing may enter, m: Security sweeps a disc of
/// `ROBOT_RADIUS_M + FOOTPRINT_MARGIN_M` along each command, and Planning's costmap makes
/// every cell whose centre is closer than that to an obstacle lethal, so a planned path is
/// one Security lets the robot drive.
pub const FOOTPRINT_MARGIN_M: f64 = 0.05;

/// The radius of the disc that must stay clear of obstacles, m.
pub const fn footprint_radius() -> f64 {
    ROBOT_RADIUS_M + FOOTPRINT_MARGIN_M
}
