//! The operator's messages: orders of every level (adjustable autonomy), their status, the
//! designated beacon, the tracked beacon and the behaviours attention offers.
//!
//! Orders travel on [`ORDER_CHANNEL`] from any front end (the `hng order`/`hng teleop`
//! commands, the operator page); the Interface module validates each one and answers on
//! [`ORDER_STATUS_CHANNEL`] (a state channel: late joiners see the order in force). Remote
//! control itself stays on the teleop channel (`hng/teleop`, [`super::Twist`]), with a deadman.

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;
use serde::ser::{SerializeStruct, Serializer};

use super::{Header, Pose2D, get_str, put_str};
use crate::qos::ChannelKind;

/// Where orders are published (any number of front ends).
pub const ORDER_CHANNEL: &str = "operator/order";
/// Where the Interface answers every order and says which one is in force.
pub const ORDER_STATUS_CHANNEL: &str = "operator/order_status";
/// The beacon the operator designated (the trackers' "Designation").
pub const DESIGNATION_CHANNEL: &str = "operator/designation";
/// The operator's estimate of the robot's pose (ROS `/initialpose`: a
/// [`super::PoseWithCovariance`] in `map`): Localization restarts its filter there, SLAM
/// starts a new map there.
pub const INITIAL_POSE_CHANNEL: &str = "operator/initial_pose";
/// The behaviours attention offers now.
pub const BEHAVIOURS_CHANNEL: &str = "hng/behaviours";

/// Most points one order carries (waypoints).
pub const MAX_ORDER_POINTS: usize = 16;
/// Most behaviours one [`Behaviours`] lists.
pub const MAX_BEHAVIOURS: usize = 16;
/// Length of a reason text, bytes (NUL-padded UTF-8).
pub const REASON_LEN: usize = 96;

/// The level of an order, from remote control to "reach that beacon".
#[repr(u32)]
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, strum::FromRepr, strum::IntoStaticStr,
)]
#[serde(rename_all = "snake_case")]
#[strum(serialize_all = "snake_case")]
pub enum OrderKind {
    /// Software emergency stop: the robot stops and every operator order ends.
    Stop = 0,
    /// Remote control: the teleop channel's commands drive the robot (deadman 0.5 s).
    Teleop = 1,
    /// Drive through `points` in order.
    Waypoints = 2,
    /// Reach `points[0]`.
    Goal = 3,
    /// Reach beacon `beacon_id`, stopping `distance_m` short of it.
    ReachBeacon = 4,
    /// Follow the wall on `side`, `distance_m` from it.
    FollowWall = 5,
    /// Hand the robot back to autonomy (the Manager's mission).
    Release = 6,
}

impl OrderKind {
    /// From the wire value.
    pub fn from_u32(v: u32) -> Option<OrderKind> {
        Self::from_repr(v)
    }

    /// The order's name as the CLI and the operator page spell it.
    pub fn name(self) -> &'static str {
        self.into()
    }
}

/// Which wall to follow: +1 left, -1 right (REP-103: y to the left).
pub const SIDE_LEFT: i32 = 1;
/// See [`SIDE_LEFT`].
pub const SIDE_RIGHT: i32 = -1;

/// One operator order. Unused fields are zero; the Interface validates every field and
/// refuses with a reason on [`ORDER_STATUS_CHANNEL`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("hng/Order/v1")]
pub struct Order {
    /// Header.
    pub header: Header,
    /// The sender's number for this order (echoed in [`OrderStatus::seq`]); a front end
    /// picks a random start so two front ends rarely collide.
    pub seq: u32,
    /// [`OrderKind`] as a number.
    pub kind: u32,
    /// Beacon id (`ReachBeacon`).
    pub beacon_id: u32,
    /// [`SIDE_LEFT`] or [`SIDE_RIGHT`] (`FollowWall`).
    pub side: i32,
    /// Stop distance from the beacon, or distance to keep from the wall, m (0: the module's
    /// default).
    pub distance_m: f64,
    /// Position tolerance, m (`Goal`, `Waypoints`; 0: the default).
    pub tolerance_m: f64,
    /// Valid entries in `points`.
    pub count: u32,
    /// Target points in `map` (theta ignored).
    pub points: [Pose2D; MAX_ORDER_POINTS],
}
crate::impl_message!(Order, ChannelKind::Control);

impl Order {
    /// A new order of `kind` (other fields zero).
    pub fn new(kind: OrderKind) -> Order {
        Order {
            kind: kind as u32,
            ..Default::default()
        }
    }

    /// The meaningful points.
    pub fn points(&self) -> &[Pose2D] {
        &self.points[..(self.count as usize).min(MAX_ORDER_POINTS)]
    }
}

impl Serialize for Order {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Order", 8)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("seq", &self.seq)?;
        st.serialize_field("kind", &OrderKind::from_u32(self.kind).map(OrderKind::name))?;
        st.serialize_field("beacon_id", &self.beacon_id)?;
        st.serialize_field("side", &self.side)?;
        st.serialize_field("distance_m", &self.distance_m)?;
        st.serialize_field("tolerance_m", &self.tolerance_m)?;
        st.serialize_field("points", self.points())?;
        st.end()
    }
}

/// The Interface's answer to the last order, and the order in force.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hng/OrderStatus/v1")]
pub struct OrderStatus {
    /// Header.
    pub header: Header,
    /// `seq` of the order this answers.
    pub seq: u32,
    /// 1 if that order was accepted, 0 if refused (`reason` says why).
    pub accepted: u8,
    /// 1 while an operator order is in force (0: autonomy has the robot).
    pub active: u8,
    /// [`OrderKind`] of the order in force (meaningful when `active` is 1).
    pub in_force: u32,
    /// Why the order was refused, or how the order in force ended (NUL-padded).
    pub reason: [u8; REASON_LEN],
}
crate::impl_message!(OrderStatus, ChannelKind::State);

impl Default for OrderStatus {
    fn default() -> Self {
        OrderStatus {
            header: Header::default(),
            seq: 0,
            accepted: 0,
            active: 0,
            in_force: 0,
            reason: [0; REASON_LEN],
        }
    }
}

impl OrderStatus {
    /// The reason as text.
    pub fn reason(&self) -> &str {
        get_str(&self.reason)
    }

    /// Sets the reason (cut on a character boundary to [`REASON_LEN`] bytes).
    pub fn set_reason(&mut self, reason: &str) {
        put_str(&mut self.reason, reason);
    }
}

impl Serialize for OrderStatus {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("OrderStatus", 6)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("seq", &self.seq)?;
        st.serialize_field("accepted", &(self.accepted != 0))?;
        st.serialize_field("active", &(self.active != 0))?;
        st.serialize_field(
            "in_force",
            &OrderKind::from_u32(self.in_force).map(OrderKind::name),
        )?;
        st.serialize_field("reason", self.reason())?;
        st.end()
    }
}

/// The beacon the operator designated (paper: designation data only a person can give).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/Designation/v1")]
pub struct Designation {
    /// Header.
    pub header: Header,
    /// The designated beacon's id.
    pub beacon_id: u32,
    /// 1 while a beacon is designated, 0 when the designation is withdrawn.
    pub active: u8,
}
crate::impl_message!(Designation, ChannelKind::State);

/// Track state: the beacon is not seen and not predicted.
pub const TRACK_LOST: u8 = 0;
/// Track state: the beacon is seen in the current image.
pub const TRACK_SEEN: u8 = 1;
/// Track state: the beacon is hidden; bearing and range are predicted.
pub const TRACK_PREDICTED: u8 = 2;

/// A tracked beacon, in the camera's frame ("Track beacon").
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/BeaconTrack/v1")]
pub struct BeaconTrack {
    /// Header; `frame_id` is the camera's frame, the stamp the image's.
    pub header: Header,
    /// The tracked beacon's id.
    pub beacon_id: u32,
    /// [`TRACK_LOST`], [`TRACK_SEEN`] or [`TRACK_PREDICTED`].
    pub state: u8,
    /// Bearing, rad, counter-clockwise from the camera's x axis.
    pub bearing: f64,
    /// Estimated distance, m.
    pub range: f64,
    /// The tracker's own quality of this estimate, in [0, 1].
    pub quality: f32,
}
crate::impl_message!(BeaconTrack, ChannelKind::Sensor);

/// One behaviour attention offers: an order the operator can give now.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct Behaviour {
    /// The [`OrderKind`] that starts it.
    pub kind: u32,
    /// Its parameter: the beacon id (`ReachBeacon`), the side (`FollowWall`), else 0.
    pub param: i32,
    /// The best provider's quality for it, in [-1, 1].
    pub quality: f32,
}

impl Serialize for Behaviour {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Behaviour", 3)?;
        st.serialize_field("kind", &OrderKind::from_u32(self.kind).map(OrderKind::name))?;
        st.serialize_field("param", &self.param)?;
        st.serialize_field("quality", &self.quality)?;
        st.end()
    }
}

/// The behaviours available now (attention), on [`BEHAVIOURS_CHANNEL`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("hng/Behaviours/v1")]
pub struct Behaviours {
    /// Header.
    pub header: Header,
    /// Valid entries in `items`.
    pub count: u32,
    /// The behaviours.
    pub items: [Behaviour; MAX_BEHAVIOURS],
}
crate::impl_message!(Behaviours, ChannelKind::State);

impl Behaviours {
    /// The meaningful entries.
    pub fn items(&self) -> &[Behaviour] {
        &self.items[..(self.count as usize).min(MAX_BEHAVIOURS)]
    }
}

impl Serialize for Behaviours {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Behaviours", 2)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("items", self.items())?;
        st.end()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_kinds_round_trip_and_unknown_ones_are_none() {
        for v in 0..7 {
            let k = OrderKind::from_u32(v).expect("known kind");
            assert_eq!(k as u32, v);
            // The name is the one serde writes (the page and the CLI spell it so).
            assert_eq!(
                serde_json::to_value(k).ok(),
                Some(serde_json::Value::from(k.name()))
            );
        }
        assert_eq!(OrderKind::from_u32(7), None);
        assert_eq!(OrderKind::ReachBeacon.name(), "reach_beacon");
        assert_eq!(OrderKind::FollowWall.name(), "follow_wall");
    }

    #[test]
    fn order_points_are_bounded_by_the_array() {
        let mut o = Order::new(OrderKind::Waypoints);
        o.count = u32::MAX;
        assert_eq!(o.points().len(), MAX_ORDER_POINTS);
    }

    #[test]
    fn order_status_reason_round_trips() {
        let mut s = OrderStatus::default();
        s.set_reason("beacon 9 is not known");
        assert_eq!(s.reason(), "beacon 9 is not known");
    }
}
