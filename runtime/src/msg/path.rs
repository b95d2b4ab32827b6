//! A planned path: the whole route Planning intends to follow, for operators and recorders.

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;

use super::Header;
use crate::qos::ChannelKind;

/// Where Planning publishes the path to its current goal (latest kept for late joiners).
pub const PLANNED_PATH_CHANNEL: &str = "planning/path";

/// User header of a planned path; the payload is the path's poses in `map`, start first.
///
/// An empty payload means "no path" (goal reached, refused or cancelled).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/PathInfo/v1")]
pub struct PathInfo {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// The goal this path leads to (0: none).
    pub goal_id: u32,
    /// Length of the path along its poses, m.
    pub length_m: f64,
}
crate::impl_slice_message!(PathInfo, super::Pose2D, ChannelKind::StateBulk);
