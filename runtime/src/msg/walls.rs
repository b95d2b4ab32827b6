//! Walls detected in a laser scan ("Detect wall") and the wall-following request the Interface
//! gives the Wall follower ("Follow wall").

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;
use serde::ser::{SerializeStruct, Serializer};

use super::Header;
use crate::qos::ChannelKind;

/// Most walls one [`Walls`] message carries (the longest first).
pub const MAX_WALLS: usize = 16;
/// Where the Interface says which wall to follow.
pub const FOLLOW_WALL_CHANNEL: &str = "operator/follow_wall";

/// One straight wall in `base_link` (REP-103: x forward, y left).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
pub struct WallSegment {
    /// Perpendicular distance from the robot to the wall's line, m.
    pub distance: f64,
    /// Bearing of the foot of that perpendicular, rad.
    pub normal_bearing: f64,
    /// Direction of the wall in the robot frame, rad, in (-pi/2, pi/2].
    pub angle: f64,
    /// Length of the seen segment, m.
    pub length: f64,
    /// +1 left, -1 right ([`super::SIDE_LEFT`], [`super::SIDE_RIGHT`]).
    pub side: i32,
    /// 1 if the segment runs beside the robot (its extent covers the robot's x).
    pub beside: u8,
    /// First end point, m (x, y).
    pub start: [f64; 2],
    /// Second end point, m (x, y).
    pub end: [f64; 2],
    /// Fit residual (root mean square), m.
    pub rmse: f32,
}

/// The walls of one scan.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("hng/Walls/v1")]
pub struct Walls {
    /// Header; `frame_id` is `base_link`, the stamp the scan's.
    pub header: Header,
    /// Valid entries in `walls`.
    pub count: u32,
    /// Free distance straight ahead (the shortest return within +-15 degrees), m; infinite
    /// when nothing is seen.
    pub front: f64,
    /// The walls, longest first.
    pub walls: [WallSegment; MAX_WALLS],
}
crate::impl_message!(Walls, ChannelKind::Sensor);

impl Walls {
    /// The meaningful entries.
    pub fn walls(&self) -> &[WallSegment] {
        &self.walls[..(self.count as usize).min(MAX_WALLS)]
    }

    /// True when a wall runs beside the robot on `side` (+1 left, -1 right) within
    /// `max_distance` m.
    pub fn beside(&self, side: i32, max_distance: f64) -> bool {
        self.walls()
            .iter()
            .any(|w| w.side == side && w.beside != 0 && w.distance <= max_distance)
    }
}

impl Serialize for Walls {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Walls", 3)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("front", &self.front)?;
        st.serialize_field("walls", self.walls())?;
        st.end()
    }
}

/// What the Wall follower is asked to do: which side, at what distance (a state channel,
/// [`FOLLOW_WALL_CHANNEL`]; late joiners get the order in force).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/FollowWallRequest/v1")]
pub struct FollowWallRequest {
    /// Header.
    pub header: Header,
    /// +1 left, -1 right.
    pub side: i32,
    /// Distance to keep, m (0: the follower's default).
    pub distance_m: f64,
    /// 1 while a follow-wall order is in force.
    pub active: u8,
}
crate::impl_message!(FollowWallRequest, ChannelKind::State);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walls_are_bounded_and_beside_looks_at_side_and_distance() {
        let mut w = Walls {
            count: 99,
            ..Default::default()
        };
        assert_eq!(w.walls().len(), MAX_WALLS);
        w.count = 1;
        w.walls[0] = WallSegment {
            distance: 0.6,
            side: 1,
            beside: 1,
            ..Default::default()
        };
        assert!(w.beside(1, 1.0));
        assert!(!w.beside(-1, 1.0));
        assert!(!w.beside(1, 0.5));
    }
}
