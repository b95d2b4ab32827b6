//! The operator's orders: validation of every field, and the order in force.
//!
//! An [`Order`] either becomes a [`Mode`] (what the Interface puts in force) or is refused
//! with a reason naming the field. Only the fields an order's kind uses may be set: a `stop`
//! with points, a `goal` with a side, are refused rather than half-read.

use hng_runtime::msg::{MAX_ORDER_POINTS, Order, OrderKind, SIDE_LEFT, SIDE_RIGHT};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

/// Bounds of the orders' fields.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct OrderLimits {
    /// Largest |x| or |y| of a target point, m (map frame).
    #[default(1000.0)]
    pub max_coordinate_m: f64,
    /// Tolerance of a goal or waypoint given as 0, m.
    #[default(0.2)]
    pub default_tolerance_m: f64,
    /// Largest tolerance accepted, m.
    #[default(5.0)]
    pub max_tolerance_m: f64,
    /// Wall distance bounds, m (0 means the follower's default).
    #[default((0.2, 3.0))]
    pub wall_distance_m: (f64, f64),
    /// Largest stop distance from a beacon, m.
    #[default(5.0)]
    pub max_beacon_distance_m: f64,
}

/// What the Interface has in force.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub enum Mode {
    /// No operator order: the Manager's mission runs (teleop commands still override it).
    #[default]
    Autonomy,
    /// Software emergency stop: zero commands at the Interface's priority (2.1).
    Stop,
    /// Remote control with a deadman.
    Teleop,
    /// A goal (one point) or waypoints, reached one after the other by Planning and Servo.
    Goals {
        /// Waypoints (true) or a goal.
        waypoints: bool,
        /// The points, map frame, m.
        points: Vec<(f64, f64)>,
        /// Position tolerance, m.
        tolerance_m: f64,
        /// Index of the point being reached.
        next: usize,
    },
    /// Follow the wall on `side` at `distance_m` (0: the follower's default).
    FollowWall {
        /// +1 left, -1 right.
        side: i32,
        /// Distance, m.
        distance_m: f64,
    },
    /// Reach beacon `id`, stopping `distance_m` short (0: the reacher's default).
    ReachBeacon {
        /// Beacon id.
        id: u32,
        /// Stop distance, m.
        distance_m: f64,
    },
}

impl Mode {
    /// The order kind this mode puts in force (`None`: autonomy).
    pub fn kind(&self) -> Option<OrderKind> {
        Some(match self {
            Mode::Autonomy => return None,
            Mode::Stop => OrderKind::Stop,
            Mode::Teleop => OrderKind::Teleop,
            Mode::Goals {
                waypoints: true, ..
            } => OrderKind::Waypoints,
            Mode::Goals { .. } => OrderKind::Goal,
            Mode::FollowWall { .. } => OrderKind::FollowWall,
            Mode::ReachBeacon { .. } => OrderKind::ReachBeacon,
        })
    }

    /// The attention parameter of the mode (side or beacon id).
    pub fn param(&self) -> i64 {
        match self {
            Mode::FollowWall { side, .. } => i64::from(*side),
            Mode::ReachBeacon { id, .. } => i64::from(*id),
            _ => 0,
        }
    }
}

fn side_name(side: i32) -> &'static str {
    if side == SIDE_LEFT { "left" } else { "right" }
}

/// Checks every field of `o` and returns the mode it asks for, or why it is refused.
pub fn validate(o: &Order, lim: &OrderLimits) -> Result<Mode, String> {
    let Some(kind) = OrderKind::from_u32(o.kind) else {
        return Err(format!("unknown order kind {}", o.kind));
    };
    let name = kind.name();
    let count = o.count as usize;
    if count > MAX_ORDER_POINTS {
        return Err(format!(
            "{name}: count {count} is over the {MAX_ORDER_POINTS} points an order carries"
        ));
    }
    for (field, v) in [("distance_m", o.distance_m), ("tolerance_m", o.tolerance_m)] {
        if !v.is_finite() || v < 0.0 {
            return Err(format!("{name}: {field} {v} must be finite and >= 0"));
        }
    }
    let uses_points = matches!(kind, OrderKind::Goal | OrderKind::Waypoints);
    if !uses_points && count != 0 {
        return Err(format!("{name} takes no points (count {count})"));
    }
    if !uses_points && o.tolerance_m != 0.0 {
        return Err(format!("{name} takes no tolerance_m"));
    }
    if kind != OrderKind::FollowWall && o.side != 0 {
        return Err(format!("{name} takes no side (side {})", o.side));
    }
    if kind != OrderKind::ReachBeacon && o.beacon_id != 0 {
        return Err(format!("{name} takes no beacon_id"));
    }
    if !matches!(kind, OrderKind::FollowWall | OrderKind::ReachBeacon) && o.distance_m != 0.0 {
        return Err(format!("{name} takes no distance_m"));
    }
    Ok(match kind {
        OrderKind::Stop => Mode::Stop,
        OrderKind::Teleop => Mode::Teleop,
        OrderKind::Release => Mode::Autonomy,
        OrderKind::Goal | OrderKind::Waypoints => {
            let waypoints = kind == OrderKind::Waypoints;
            if count == 0 || (!waypoints && count != 1) {
                return Err(if waypoints {
                    "waypoints: give 1 to 16 points".to_string()
                } else {
                    format!("goal: give exactly one point (count {count})")
                });
            }
            let mut points = Vec::with_capacity(count);
            for (i, p) in o.points().iter().enumerate() {
                for (axis, v) in [("x", p.x), ("y", p.y)] {
                    if !v.is_finite() {
                        return Err(format!("{name}: point {} {axis} is not finite", i + 1));
                    }
                    if v.abs() > lim.max_coordinate_m {
                        return Err(format!(
                            "{name}: point {} {axis} = {v} is beyond +-{} m",
                            i + 1,
                            lim.max_coordinate_m
                        ));
                    }
                }
                points.push((p.x, p.y));
            }
            let tolerance_m = if o.tolerance_m == 0.0 {
                lim.default_tolerance_m
            } else if o.tolerance_m > lim.max_tolerance_m {
                return Err(format!(
                    "{name}: tolerance_m {} is over {} m",
                    o.tolerance_m, lim.max_tolerance_m
                ));
            } else {
                o.tolerance_m
            };
            Mode::Goals {
                waypoints,
                points,
                tolerance_m,
                next: 0,
            }
        }
        OrderKind::FollowWall => {
            if o.side != SIDE_LEFT && o.side != SIDE_RIGHT {
                return Err(format!(
                    "follow_wall: side {} is neither 1 (left) nor -1 (right)",
                    o.side
                ));
            }
            let (lo, hi) = lim.wall_distance_m;
            if o.distance_m != 0.0 && !(lo..=hi).contains(&o.distance_m) {
                return Err(format!(
                    "follow_wall {}: distance_m {} is outside {lo}..{hi} m",
                    side_name(o.side),
                    o.distance_m
                ));
            }
            Mode::FollowWall {
                side: o.side,
                distance_m: o.distance_m,
            }
        }
        OrderKind::ReachBeacon => {
            if o.distance_m > lim.max_beacon_distance_m {
                return Err(format!(
                    "reach_beacon: distance_m {} is over {} m",
                    o.distance_m, lim.max_beacon_distance_m
                ));
            }
            Mode::ReachBeacon {
                id: o.beacon_id,
                distance_m: o.distance_m,
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::msg::Pose2D;

    fn goal(x: f64, y: f64) -> Order {
        let mut o = Order::new(OrderKind::Goal);
        o.count = 1;
        o.points[0] = Pose2D::new(x, y, 0.0);
        o
    }

    fn refused(o: &Order) -> String {
        validate(o, &OrderLimits::default()).unwrap_err()
    }

    #[test]
    fn good_orders_become_modes() {
        let lim = OrderLimits::default();
        assert_eq!(validate(&Order::new(OrderKind::Stop), &lim), Ok(Mode::Stop));
        assert_eq!(
            validate(&Order::new(OrderKind::Release), &lim),
            Ok(Mode::Autonomy)
        );
        assert_eq!(
            validate(&goal(3.0, 4.0), &lim),
            Ok(Mode::Goals {
                waypoints: false,
                points: vec![(3.0, 4.0)],
                tolerance_m: 0.2,
                next: 0
            })
        );
        let mut w = Order::new(OrderKind::FollowWall);
        w.side = SIDE_RIGHT;
        w.distance_m = 0.6;
        assert_eq!(
            validate(&w, &lim),
            Ok(Mode::FollowWall {
                side: -1,
                distance_m: 0.6
            })
        );
        let mut b = Order::new(OrderKind::ReachBeacon);
        b.beacon_id = 3;
        assert_eq!(
            validate(&b, &lim).unwrap().kind(),
            Some(OrderKind::ReachBeacon)
        );
    }

    #[test]
    fn malformed_orders_are_refused_naming_the_field() {
        let e = refused(&goal(f64::NAN, 1.0));
        assert!(e.contains("point 1 x is not finite"), "{e}");
        let e = refused(&goal(1.0, 1e9));
        assert!(e.contains("point 1 y = 1000000000 is beyond"), "{e}");
        let e = refused(&Order {
            kind: 99,
            ..Default::default()
        });
        assert!(e.contains("unknown order kind 99"), "{e}");
        let mut o = goal(1.0, 1.0);
        o.count = 2;
        assert!(refused(&o).contains("exactly one point"));
        o.count = 17;
        assert!(refused(&o).contains("over the 16 points"));
        let mut w = Order::new(OrderKind::Waypoints);
        assert!(refused(&w).contains("1 to 16 points"));
        w.count = 1;
        w.tolerance_m = f64::INFINITY;
        assert!(refused(&w).contains("tolerance_m inf must be finite"));
        let mut f = Order::new(OrderKind::FollowWall);
        f.side = 2;
        assert!(refused(&f).contains("side 2 is neither"));
        f.side = 1;
        f.distance_m = 9.0;
        assert!(refused(&f).contains("distance_m 9 is outside"));
        let mut s = Order::new(OrderKind::Stop);
        s.count = 1;
        assert!(refused(&s).contains("stop takes no points"));
        let mut t = Order::new(OrderKind::Teleop);
        t.side = 1;
        assert!(refused(&t).contains("teleop takes no side"));
        let mut b = Order::new(OrderKind::ReachBeacon);
        b.distance_m = -1.0;
        assert!(refused(&b).contains("must be finite and >= 0"));
    }
}
