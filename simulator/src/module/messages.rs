//! The simulator module's own messages: [`SimStatus`], [`SimCollision`] and [`SimTeleport`].

use hng_runtime::msg::{Header, Pose2D};
use hng_runtime::qos::ChannelKind;
use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;

/// Counters and pacing of the simulator, published on `sim/status` (a state channel: late
/// joiners get the latest). Header stamp: simulated time.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-simulator/SimStatus/v4")]
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
    /// Length of the robot's true path since this simulator process started, m (every
    /// physics step counted; a restarted simulator counts from 0 again).
    pub path_length_m: f64,
    /// Lockstep rounds opened so far (0 without lockstep), and of them those opened again
    /// at the same simulated time because a module was still busy.
    pub lockstep_rounds: u64,
    /// See `lockstep_rounds`.
    pub lockstep_extra_rounds: u64,
    /// Participants called to those rounds, summed over the rounds (selective rounds call
    /// only those a round can give work to).
    pub lockstep_calls: u64,
    /// Teleports (`sim/teleport`) carried out since this simulator process started.
    pub teleports: u64,
    /// Teleports refused (the pose not finite, or overlapping an obstacle); a status is
    /// published at once after a teleport is carried out or refused.
    pub teleports_refused: u64,
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

/// Moves the simulated robot (published on `sim/teleport`; Gazebo's `set_pose`, Stage's
/// `setpose`): it is put at `pose` at rest, the odometry does not see the jump, the true path
/// does not count it, and the least clearance starts again from there. One-shot (a command
/// channel: a simulator that starts later does not see it). A pose that is not finite, or
/// whose disc overlaps an obstacle, is refused, logged and counted.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-simulator/SimTeleport/v1")]
pub struct SimTeleport {
    /// Header.
    pub header: Header,
    /// Where the robot goes, `map` frame.
    pub pose: Pose2D,
}

hng_runtime::impl_message!(SimTeleport, ChannelKind::Command);
