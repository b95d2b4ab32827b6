//! Fixed-size robotics messages that travel through shared memory without copies.
//!
//! Every message is `#[repr(C)]`, [`ZeroCopySend`] and carries a stable, versioned type name
//! (`hng/<Name>/v<N>`): iceoryx2 matches types across processes by name, size and alignment,
//! so a change of layout must bump the version. Units and frames follow ROS REP-103/105:
//! metres, radians, seconds; frames `map`, `odom`, `base_link`, `laser`.
//!
//! Every message starts with a [`Header`] that the publisher stamps: sequence number, time
//! stamp from the common clock, source module id. The frame id is the author's to set.

use core::fmt;

use iceoryx2::prelude::ZeroCopySend;
use serde::ser::{SerializeStruct, Serializer};
use serde::{Deserialize, Serialize};

use crate::qos::ChannelKind;

mod envelope;
pub use envelope::*;
mod operator;
pub use operator::*;
mod path;
pub use path::*;
mod walls;
pub use walls::*;

/// Length of a frame id, in bytes (NUL-padded UTF-8).
pub const FRAME_ID_LEN: usize = 20;
/// Largest number of beams a [`LaserScan`] carries (a 270 degree scanner at 0.25 degree).
pub const MAX_BEAMS: usize = 1081;
/// Largest number of beacons one [`BeaconObservation`] reports.
pub const MAX_BEACONS: usize = 16;

/// Writes `s` NUL-padded into `dst`, cut on a character boundary to fit.
pub(crate) fn put_str<const N: usize>(dst: &mut [u8; N], s: &str) {
    *dst = [0; N];
    let b = s.as_bytes();
    let mut n = b.len().min(N);
    while n > 0 && !s.is_char_boundary(n) {
        n -= 1;
    }
    dst[..n].copy_from_slice(&b[..n]);
}

/// The text of a NUL-padded field (`?` if it is not UTF-8).
pub(crate) fn get_str(b: &[u8]) -> &str {
    let len = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    core::str::from_utf8(&b[..len]).unwrap_or("?")
}

/// A frame id: a short, fixed-size name such as `map`, `odom`, `base_link`.
#[repr(C)]
#[derive(Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
pub struct FrameId([u8; FRAME_ID_LEN]);

impl FrameId {
    /// The global, fixed frame.
    pub const MAP: FrameId = FrameId::from_static("map");
    /// The odometry frame: continuous, drifts.
    pub const ODOM: FrameId = FrameId::from_static("odom");
    /// The robot's body frame.
    pub const BASE_LINK: FrameId = FrameId::from_static("base_link");
    /// The lidar's frame.
    pub const LASER: FrameId = FrameId::from_static("laser");
    /// The camera's frame.
    pub const CAMERA: FrameId = FrameId::from_static("camera");

    /// A frame id from a string known at compile time; longer names are cut at
    /// [`FRAME_ID_LEN`] bytes.
    pub const fn from_static(s: &'static str) -> FrameId {
        let b = s.as_bytes();
        let mut out = [0u8; FRAME_ID_LEN];
        let mut i = 0;
        while i < b.len() && i < FRAME_ID_LEN {
            out[i] = b[i];
            i += 1;
        }
        FrameId(out)
    }

    /// A frame id from a run-time string; `None` if it is longer than [`FRAME_ID_LEN`] bytes
    /// or contains a NUL.
    pub fn new(s: &str) -> Option<FrameId> {
        let b = s.as_bytes();
        if b.len() > FRAME_ID_LEN || b.contains(&0) {
            return None;
        }
        let mut out = [0u8; FRAME_ID_LEN];
        out[..b.len()].copy_from_slice(b);
        Some(FrameId(out))
    }

    /// The frame id as text (invalid UTF-8 shows as `?`).
    pub fn as_str(&self) -> &str {
        let len = self.0.iter().position(|&c| c == 0).unwrap_or(FRAME_ID_LEN);
        core::str::from_utf8(&self.0[..len]).unwrap_or("?")
    }
}

impl Default for FrameId {
    fn default() -> Self {
        FrameId([0; FRAME_ID_LEN])
    }
}

impl fmt::Debug for FrameId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl Serialize for FrameId {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// A stable 32-bit id of a module, derived from its name (FNV-1a).
pub fn module_id(name: &str) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for b in name.as_bytes() {
        h ^= u32::from(*b);
        h = h.wrapping_mul(0x0100_0193);
    }
    h
}

/// The header every message carries.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize)]
#[type_name("hng/Header/v1")]
pub struct Header {
    /// Per-publisher sequence number, starting at 1; gaps mean lost messages.
    pub seq: u64,
    /// Time stamp in nanoseconds of the common clock (see [`crate::clock`]).
    pub stamp_ns: u64,
    /// Id of the module that published the message ([`module_id`] of its name).
    pub source: u32,
    /// Coordinate frame the data is expressed in.
    pub frame_id: FrameId,
    /// The lockstep round in which the publisher sent the message (0: outside lockstep).
    /// A module in lockstep handles in round `r` only messages sent before `r` opened; one
    /// sent in `r` waits for the next round, however the processes were scheduled (see
    /// [`crate::clock::lockstep`]). Set by the publisher; not part of the message's content
    /// (left out of its serialisation).
    #[serde(skip)]
    pub round: u32,
}

/// A message type that can travel on an hng channel.
///
/// # Safety
/// Implied by [`ZeroCopySend`]: the type must be self-contained (no pointers) and `#[repr(C)]`.
pub trait Message: ZeroCopySend + fmt::Debug + Copy + Default + Serialize + 'static {
    /// The kind of channel this message travels on by default; it fixes the QoS.
    const KIND: ChannelKind;
    /// The message's header.
    fn header(&self) -> &Header;
    /// The message's header, to stamp it.
    fn header_mut(&mut self) -> &mut Header;
}

/// The user header of a variable-size channel: the payload is a slice of `Elem`.
pub trait SliceMessage: ZeroCopySend + fmt::Debug + Copy + Default + Serialize + 'static {
    /// Element type of the payload slice.
    type Elem: ZeroCopySend + fmt::Debug + Copy + Default + 'static;
    /// The kind of channel (fixes the QoS).
    const KIND: ChannelKind;
    /// The header.
    fn header(&self) -> &Header;
    /// The header, to stamp it.
    fn header_mut(&mut self) -> &mut Header;
}

/// Implements [`Message`] for a `#[repr(C)]`, `ZeroCopySend` struct with a `header: Header`
/// field: `hng_runtime::impl_message!(MyType, ChannelKind::State);`.
#[macro_export]
macro_rules! impl_message {
    ($t:ty, $kind:expr) => {
        impl $crate::msg::Message for $t {
            const KIND: $crate::qos::ChannelKind = $kind;
            fn header(&self) -> &$crate::msg::Header {
                &self.header
            }
            fn header_mut(&mut self) -> &mut $crate::msg::Header {
                &mut self.header
            }
        }
    };
}

/// Implements [`SliceMessage`] for a slice header type with a `header: Header` field:
/// `hng_runtime::impl_slice_message!(MyInfo, u8, ChannelKind::Bulk);`.
#[macro_export]
macro_rules! impl_slice_message {
    ($t:ty, $elem:ty, $kind:expr) => {
        impl $crate::msg::SliceMessage for $t {
            type Elem = $elem;
            const KIND: $crate::qos::ChannelKind = $kind;
            fn header(&self) -> &$crate::msg::Header {
                &self.header
            }
            fn header_mut(&mut self) -> &mut $crate::msg::Header {
                &mut self.header
            }
        }
    };
}

/// A planar pose: position in metres, heading in radians (counter-clockwise from x).
///
/// The one pose type of hng: messages, world files (`theta` may be left out there: 0) and the
/// simulator all use it.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pose2D {
    /// x in metres.
    pub x: f64,
    /// y in metres.
    pub y: f64,
    /// Heading in radians.
    #[serde(default)]
    pub theta: f64,
}

impl Pose2D {
    /// A pose from its parts.
    #[must_use]
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }
}

/// Wraps an angle (radians) to (-π, π].
#[must_use]
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = (a + PI).rem_euclid(TAU) - PI;
    if w <= -PI { w + TAU } else { w }
}

/// The point of segment `a`-`b` closest to `p`: its parameter `t` in [0, 1] (0 at `a`, and
/// for a segment of no length) and its distance from `p`, m.
#[must_use]
pub fn closest_on_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> (f64, f64) {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (t, (a[0] + t * dx - p[0]).hypot(a[1] + t * dy - p[1]))
}

/// A planar velocity in the body frame: m/s and rad/s.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
pub struct Velocity2D {
    /// Forward speed, m/s.
    pub vx: f64,
    /// Sideways speed, m/s (zero for a differential drive).
    pub vy: f64,
    /// Turn rate, rad/s.
    pub wz: f64,
}

/// A velocity command (ROS `geometry_msgs/Twist`, planar part), in `base_link`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/Twist/v1")]
pub struct Twist {
    /// Header.
    pub header: Header,
    /// Forward speed, m/s.
    pub linear_x: f64,
    /// Sideways speed, m/s.
    pub linear_y: f64,
    /// Turn rate, rad/s.
    pub angular_z: f64,
}
crate::impl_message!(Twist, ChannelKind::Command);

impl Twist {
    /// A command of forward speed `linear_x` (m/s) and turn rate `angular_z` (rad/s), with
    /// an empty header and no sideways speed.
    #[must_use]
    pub fn new(linear_x: f64, angular_z: f64) -> Twist {
        Twist {
            linear_x,
            angular_z,
            ..Twist::default()
        }
    }
}

/// Odometry (ROS `nav_msgs/Odometry`, planar): pose in `odom`, twist in `base_link`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/Odometry/v1")]
pub struct Odometry {
    /// Header; `frame_id` is `odom`.
    pub header: Header,
    /// Frame of the twist, normally `base_link`.
    pub child_frame_id: FrameId,
    /// Pose in the header's frame.
    pub pose: Pose2D,
    /// Velocity in the child frame.
    pub twist: Velocity2D,
    /// Row-major 3x3 covariance of (x, y, theta).
    pub pose_covariance: [f64; 9],
    /// Row-major 3x3 covariance of (vx, vy, wz).
    pub twist_covariance: [f64; 9],
}
crate::impl_message!(Odometry, ChannelKind::Sensor);

/// A pose with covariance (ROS `PoseWithCovarianceStamped`, planar): a localization output.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/PoseWithCovariance/v1")]
pub struct PoseWithCovariance {
    /// Header; `frame_id` is normally `map`.
    pub header: Header,
    /// The pose.
    pub pose: Pose2D,
    /// Row-major 3x3 covariance of (x, y, theta).
    pub covariance: [f64; 9],
}
crate::impl_message!(PoseWithCovariance, ChannelKind::State);

/// A planar laser scan (ROS `sensor_msgs/LaserScan`), up to [`MAX_BEAMS`] beams.
///
/// Beam `i` points at `angle_min + i * angle_increment` in the header's frame. Ranges outside
/// `[range_min, range_max]` mean no return (by convention `f32::INFINITY` for "nothing hit").
#[repr(C)]
#[derive(Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hng/LaserScan/v1")]
pub struct LaserScan {
    /// Header; `frame_id` is the lidar's frame.
    pub header: Header,
    /// Angle of the first beam, rad.
    pub angle_min: f32,
    /// Angle between beams, rad.
    pub angle_increment: f32,
    /// Time between beams, s.
    pub time_increment: f32,
    /// Time between scans, s.
    pub scan_time: f32,
    /// Smallest valid range, m.
    pub range_min: f32,
    /// Largest valid range, m.
    pub range_max: f32,
    /// Number of valid entries in `ranges`.
    pub count: u32,
    /// Ranges in metres; only the first `count` are meaningful.
    pub ranges: [f32; MAX_BEAMS],
}
crate::impl_message!(LaserScan, ChannelKind::Sensor);

impl LaserScan {
    /// The meaningful ranges (the first `count`, capped at [`MAX_BEAMS`]).
    pub fn ranges(&self) -> &[f32] {
        let n = (self.count as usize).min(MAX_BEAMS);
        &self.ranges[..n]
    }

    /// Angle of beam `i`, rad.
    pub fn angle(&self, i: usize) -> f32 {
        self.angle_min + self.angle_increment * i as f32
    }

    /// A scan of `ranges` (the first [`MAX_BEAMS`]) spread evenly over the full circle
    /// counter-clockwise from -π, valid from `range_min` to `range_max` metres.
    pub fn full_circle(ranges: &[f32], range_min: f32, range_max: f32) -> LaserScan {
        let n = ranges.len().min(MAX_BEAMS);
        let mut s = LaserScan {
            angle_min: -std::f32::consts::PI,
            angle_increment: std::f32::consts::TAU / n.max(1) as f32,
            range_min,
            range_max,
            count: n as u32,
            ..LaserScan::default()
        };
        s.ranges[..n].copy_from_slice(&ranges[..n]);
        s
    }
}

impl Default for LaserScan {
    fn default() -> Self {
        LaserScan {
            header: Header::default(),
            angle_min: 0.0,
            angle_increment: 0.0,
            time_increment: 0.0,
            scan_time: 0.0,
            range_min: 0.0,
            range_max: 0.0,
            count: 0,
            ranges: [0.0; MAX_BEAMS],
        }
    }
}

impl fmt::Debug for LaserScan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LaserScan")
            .field("header", &self.header)
            .field("angle_min", &self.angle_min)
            .field("angle_increment", &self.angle_increment)
            .field("range_min", &self.range_min)
            .field("range_max", &self.range_max)
            .field("count", &self.count)
            .finish_non_exhaustive()
    }
}

impl Serialize for LaserScan {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("LaserScan", 9)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("angle_min", &self.angle_min)?;
        st.serialize_field("angle_increment", &self.angle_increment)?;
        st.serialize_field("time_increment", &self.time_increment)?;
        st.serialize_field("scan_time", &self.scan_time)?;
        st.serialize_field("range_min", &self.range_min)?;
        st.serialize_field("range_max", &self.range_max)?;
        st.serialize_field("count", &self.count)?;
        st.serialize_field("ranges", self.ranges())?;
        st.end()
    }
}

/// The two band colours (top, bottom) [r, g, b] of the marker of beacon `id`: the appearance
/// shared by the simulator's camera and the visual trackers. Six saturated hues; beacons with
/// different ids (below 36) differ in at least one band.
#[must_use]
pub fn beacon_colors(id: u32) -> ([u8; 3], [u8; 3]) {
    const PALETTE: [[u8; 3]; 6] = [
        [230, 40, 40],  // red
        [40, 200, 60],  // green
        [50, 90, 235],  // blue
        [240, 220, 40], // yellow
        [220, 60, 220], // magenta
        [40, 220, 230], // cyan
    ];
    let n = PALETTE.len() as u32;
    let top = PALETTE[(id % n) as usize];
    let bottom = PALETTE[((id / n + id + 1) % n) as usize];
    (top, bottom)
}

/// One beacon seen by a camera or fiducial finder, in the sensor's frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
pub struct Beacon {
    /// Beacon id.
    pub id: u32,
    /// Bearing, rad, counter-clockwise from the sensor's x axis.
    pub bearing: f64,
    /// Distance, m.
    pub range: f64,
}

/// The beacons seen in one camera frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/BeaconObservation/v1")]
pub struct BeaconObservation {
    /// Header; `frame_id` is the camera's frame.
    pub header: Header,
    /// Number of valid entries in `beacons`.
    pub count: u32,
    /// The beacons; only the first `count` are meaningful.
    pub beacons: [Beacon; MAX_BEACONS],
}
crate::impl_message!(BeaconObservation, ChannelKind::Sensor);

impl BeaconObservation {
    /// The meaningful entries.
    pub fn beacons(&self) -> &[Beacon] {
        &self.beacons[..(self.count as usize).min(MAX_BEACONS)]
    }
}

/// A navigation goal in `map`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/Goal/v1")]
pub struct Goal {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// Goal id, unique within a mission.
    pub id: u32,
    /// Target pose (theta is ignored when `use_theta` is 0).
    pub pose: Pose2D,
    /// Position tolerance, m.
    pub tolerance_m: f64,
    /// 1 if the final heading matters.
    pub use_theta: u8,
}
crate::impl_message!(Goal, ChannelKind::State);

/// A waypoint on the way to a goal, in `map`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/Waypoint/v1")]
pub struct Waypoint {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// The goal this waypoint leads to.
    pub goal_id: u32,
    /// Index of the waypoint on its path.
    pub index: u32,
    /// Target pose.
    pub pose: Pose2D,
    /// Suggested speed, m/s.
    pub speed: f64,
    /// 1 if this is the goal itself.
    pub is_final: u8,
}
crate::impl_message!(Waypoint, ChannelKind::State);

/// The simulation clock, published by the simulator on [`crate::clock::CLOCK_CHANNEL`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/Clock/v2")]
pub struct Clock {
    /// Header (its stamp is the wall clock of the publisher).
    pub header: Header,
    /// Simulated time, ns since the start of the simulation.
    pub sim_time_ns: u64,
    /// Lockstep barrier round (0: no lockstep, no acknowledgement wanted). Every module on
    /// the simulation clock acknowledges each new round on
    /// [`crate::clock::lockstep::ACK_CHANNEL`] once it has handled its inputs (see
    /// [`crate::clock::lockstep`]).
    pub round: u64,
}
crate::impl_message!(Clock, ChannelKind::State);

/// Life-cycle state of a module, as reported in its [`ModuleReport`].
#[repr(u8)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, strum::FromRepr)]
pub enum ModuleState {
    /// Configured, not started.
    #[default]
    Configured = 0,
    /// Running: serving its contracts.
    Running = 1,
    /// Alive but not working (no contract, or stopped by degraded mode).
    Idle = 2,
    /// Stopping.
    Stopping = 3,
}

/// Length of a module name in a report.
pub const MODULE_NAME_LEN: usize = 32;

/// The periodic report (heartbeat) every module publishes on [`crate::module::REPORT_CHANNEL`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("hng/ModuleReport/v1")]
pub struct ModuleReport {
    /// Header; `stamp_ns` is when the report was sent (the RM measures communication delay
    /// from it).
    pub header: Header,
    /// Module name (NUL-padded).
    pub name: [u8; MODULE_NAME_LEN],
    /// Process id.
    pub pid: u32,
    /// [`ModuleState`] as a byte.
    pub state: u8,
    /// Aptitude f: 1 if able to do its task.
    pub aptitude: u8,
    /// 1 if the module waits for resources to answer a query (paper 5.3).
    pub waiting_for_resources: u8,
    /// Self-evaluated quality Q in [-1, 1].
    pub quality: f32,
    /// Report period, ns (the watchdog's hang timeout derives from it).
    pub period_ns: u64,
    /// Messages received on all inputs.
    pub msgs_in: u64,
    /// Messages published on all outputs.
    pub msgs_out: u64,
    /// Messages lost on inputs (sequence gaps and overflow).
    pub msgs_dropped: u64,
    /// Input deadlines missed.
    pub deadline_misses: u64,
    /// Checkpoints written.
    pub checkpoints: u64,
}
crate::impl_message!(ModuleReport, ChannelKind::Report);

impl ModuleReport {
    /// The module name as text.
    pub fn name(&self) -> &str {
        get_str(&self.name)
    }

    /// Sets the module name (cut on a character boundary to [`MODULE_NAME_LEN`] bytes).
    pub fn set_name(&mut self, name: &str) {
        put_str(&mut self.name, name);
    }
}

impl Serialize for ModuleReport {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("ModuleReport", 12)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("name", self.name())?;
        st.serialize_field("pid", &self.pid)?;
        st.serialize_field("state", &ModuleState::from_repr(self.state))?;
        st.serialize_field("aptitude", &self.aptitude)?;
        st.serialize_field("quality", &self.quality)?;
        st.serialize_field("waiting_for_resources", &self.waiting_for_resources)?;
        st.serialize_field("msgs_in", &self.msgs_in)?;
        st.serialize_field("msgs_out", &self.msgs_out)?;
        st.serialize_field("msgs_dropped", &self.msgs_dropped)?;
        st.serialize_field("deadline_misses", &self.deadline_misses)?;
        st.serialize_field("checkpoints", &self.checkpoints)?;
        st.end()
    }
}

/// User header of an occupancy grid (ROS `nav_msgs/OccupancyGrid`); the payload is
/// `width * height` cells, row-major from the origin cell, each -1 (unknown) or 0..=100.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/GridInfo/v1")]
pub struct GridInfo {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// Cell size, m.
    pub resolution: f32,
    /// Cells along x.
    pub width: u32,
    /// Cells along y.
    pub height: u32,
    /// Pose of cell (0, 0)'s corner in the header's frame.
    pub origin: Pose2D,
}
crate::impl_slice_message!(GridInfo, i8, ChannelKind::StateBulk);

/// User header of an image; the payload is `step * height` bytes.
///
/// v2 added `hfov`: what a client needs to turn a pixel column into a bearing (a pinhole
/// camera, principal point at the image's centre: column `u` looks at
/// `atan((width / 2 - u) / (width / 2 / tan(hfov / 2)))`, counter-clockwise positive).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/ImageInfo/v2")]
pub struct ImageInfo {
    /// Header; `frame_id` is the camera's frame.
    pub header: Header,
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Bytes per row.
    pub step: u32,
    /// Encoding, e.g. `mono8`, `rgb8` (NUL-padded).
    pub encoding: FrameId,
    /// Horizontal field of view, rad (0: unknown).
    pub hfov: f64,
}

/// The type name of [`ImageInfo`] (what a "Video" offer names as its data type).
pub const IMAGE_INFO_TYPE: &str = "hng/ImageInfo/v2";
crate::impl_slice_message!(ImageInfo, u8, ChannelKind::Bulk);

/// User header of a raw byte payload (benchmarks, opaque data).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/BytesInfo/v1")]
pub struct BytesInfo {
    /// Header.
    pub header: Header,
}
crate::impl_slice_message!(BytesInfo, u8, ChannelKind::Bulk);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_image_type_constant_is_the_type_name() {
        // SAFETY: only unsafe because implementors may lie; this one is derived.
        let name = unsafe { <ImageInfo as iceoryx2::prelude::ZeroCopySend>::type_name() };
        assert_eq!(name, IMAGE_INFO_TYPE);
    }

    #[test]
    fn angles_wrap_to_minus_pi_exclusive_pi_inclusive() {
        use std::f64::consts::{PI, TAU};
        for (a, want) in [
            (0.0, 0.0),
            (PI, PI),
            (-PI, PI),
            (3.0 * PI, PI),
            (TAU + 0.25, 0.25),
            (-TAU - 0.25, -0.25),
            (-1e-3, -1e-3),
        ] {
            let got = wrap_angle(a);
            assert!(
                (got - want).abs() < 1e-12,
                "wrap_angle({a}) = {got}, want {want}"
            );
            assert!(
                got > -PI && got <= PI,
                "wrap_angle({a}) = {got} outside (-π, π]"
            );
        }
    }

    #[test]
    fn the_closest_point_of_a_segment_is_inside_it_or_an_end() {
        let (a, b) = ([0.0, 0.0], [2.0, 0.0]);
        for (p, want) in [
            ([1.0, 1.0], (0.5, 1.0)),
            ([-3.0, 4.0], (0.0, 5.0)),
            ([5.0, -4.0], (1.0, 5.0)),
        ] {
            let (t, d) = closest_on_segment(p, a, b);
            assert!(
                (t - want.0).abs() < 1e-12 && (d - want.1).abs() < 1e-12,
                "{p:?}: ({t}, {d}), want {want:?}"
            );
        }
        assert_eq!(closest_on_segment([3.0, 4.0], a, a), (0.0, 5.0));
    }

    #[test]
    fn frame_ids_round_trip_and_reject_long_names() {
        assert_eq!(FrameId::MAP.as_str(), "map");
        assert_eq!(FrameId::new("base_link"), Some(FrameId::BASE_LINK));
        assert!(FrameId::new("a_frame_name_that_is_too_long").is_none());
        assert!(FrameId::new("nul\0").is_none());
    }

    #[test]
    fn long_names_are_cut_on_a_character_boundary() {
        let mut r = ModuleReport::default();
        // 32 bytes end in the middle of the 16th "é": it is dropped, not cut in half.
        r.set_name(&format!("a{}", "é".repeat(20)));
        assert_eq!(r.name(), format!("a{}", "é".repeat(15)));
    }

    #[test]
    fn module_ids_differ_by_name() {
        assert_ne!(module_id("slam"), module_id("gps"));
        assert_eq!(module_id("slam"), module_id("slam"));
    }

    #[test]
    fn scan_exposes_only_valid_ranges() {
        let mut s = LaserScan {
            count: 3,
            ..Default::default()
        };
        s.ranges[..3].copy_from_slice(&[1.0, 2.0, 3.0]);
        assert_eq!(s.ranges(), &[1.0, 2.0, 3.0]);
        s.count = u32::MAX;
        assert_eq!(s.ranges().len(), MAX_BEAMS);
    }
}
