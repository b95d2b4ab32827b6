//! The operator's requests as the page sends them (JSON), checked before anything is
//! published: shape (unknown fields and unknown order kinds are refused), and ranges (finite
//! numbers, bounded sizes). What only the system can judge (is that goal reachable, is that
//! beacon known, is that behaviour available now) is the Interface's to decide: it answers on
//! [`hng_runtime::msg::ORDER_STATUS_CHANNEL`], and the page shows its answer.

use hng_runtime::msg::{
    Designation, MAX_ORDER_POINTS, Order, OrderKind, Pose2D, SIDE_LEFT, SIDE_RIGHT, Twist,
};
use serde::Deserialize;

/// Largest coordinate accepted, m (a world is far smaller; this only refuses nonsense).
pub const MAX_COORD_M: f64 = 1e4;
/// Largest tolerance or distance accepted, m.
pub const MAX_DISTANCE_M: f64 = 100.0;
/// Largest forward speed a teleop command may ask for, m/s (the Robot clamps to its base).
pub const MAX_TELEOP_SPEED: f64 = 2.0;
/// Largest turn rate a teleop command may ask for, rad/s.
pub const MAX_TELEOP_TURN: f64 = 4.0;

/// Why a request is refused: the HTTP status and the message the page shows.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Invalid {
    /// Not JSON, or not the expected shape (400).
    #[error("{0}")]
    Malformed(String),
    /// The right shape, a value out of range (422).
    #[error("{0}")]
    Range(String),
}

impl Invalid {
    /// The HTTP status for this refusal.
    pub fn status(&self) -> u16 {
        match self {
            Invalid::Malformed(_) => 400,
            Invalid::Range(_) => 422,
        }
    }
}

fn parse<'a, T: Deserialize<'a>>(body: &'a [u8], what: &str) -> Result<T, Invalid> {
    serde_json::from_slice(body).map_err(|e| Invalid::Malformed(format!("{what}: {e}")))
}

/// A point of an order.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointReq {
    /// x in `map`, m.
    pub x: f64,
    /// y in `map`, m.
    pub y: f64,
}

/// Side of a wall to follow.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SideReq {
    /// The wall on the robot's left.
    Left,
    /// The wall on the robot's right.
    Right,
}

/// The order kinds, as the page spells them ([`OrderKind::name`]).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum KindReq {
    /// [`OrderKind::Stop`].
    Stop,
    /// [`OrderKind::Teleop`].
    Teleop,
    /// [`OrderKind::Waypoints`].
    Waypoints,
    /// [`OrderKind::Goal`].
    Goal,
    /// [`OrderKind::ReachBeacon`].
    ReachBeacon,
    /// [`OrderKind::FollowWall`].
    FollowWall,
    /// [`OrderKind::Release`].
    Release,
}

impl KindReq {
    fn kind(self) -> OrderKind {
        match self {
            KindReq::Stop => OrderKind::Stop,
            KindReq::Teleop => OrderKind::Teleop,
            KindReq::Waypoints => OrderKind::Waypoints,
            KindReq::Goal => OrderKind::Goal,
            KindReq::ReachBeacon => OrderKind::ReachBeacon,
            KindReq::FollowWall => OrderKind::FollowWall,
            KindReq::Release => OrderKind::Release,
        }
    }
}

/// `POST /api/order`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OrderReq {
    /// The order's level.
    pub kind: KindReq,
    /// Goal (one) or waypoints (1 to [`MAX_ORDER_POINTS`]).
    #[serde(default)]
    pub points: Vec<PointReq>,
    /// Position tolerance, m (0 or absent: the module's default).
    #[serde(default)]
    pub tolerance_m: f64,
    /// Beacon to reach.
    #[serde(default)]
    pub beacon_id: Option<u32>,
    /// Wall side to follow.
    #[serde(default)]
    pub side: Option<SideReq>,
    /// Stop distance from the beacon, or distance to keep from the wall, m (0: default).
    #[serde(default)]
    pub distance_m: f64,
}

fn check_distance(v: f64, field: &str) -> Result<(), Invalid> {
    if !v.is_finite() || !(0.0..=MAX_DISTANCE_M).contains(&v) {
        return Err(Invalid::Range(format!(
            "{field} {v}: expected a finite number of metres in [0, {MAX_DISTANCE_M}]"
        )));
    }
    Ok(())
}

/// Parses and checks an order; `seq` is the sender's number for it.
pub fn order(body: &[u8], seq: u32) -> Result<Order, Invalid> {
    let req: OrderReq = parse(body, "order")?;
    let kind = req.kind.kind();
    let mut o = Order::new(kind);
    o.seq = seq;
    check_distance(req.tolerance_m, "tolerance_m")?;
    check_distance(req.distance_m, "distance_m")?;
    o.tolerance_m = req.tolerance_m;
    o.distance_m = req.distance_m;
    let wants_points = matches!(kind, OrderKind::Goal | OrderKind::Waypoints);
    if wants_points {
        let (lo, hi) = if kind == OrderKind::Goal {
            (1, 1)
        } else {
            (1, MAX_ORDER_POINTS)
        };
        if req.points.len() < lo || req.points.len() > hi {
            return Err(Invalid::Range(format!(
                "{}: {} point(s), expected {}",
                kind.name(),
                req.points.len(),
                if lo == hi {
                    format!("{lo}")
                } else {
                    format!("{lo} to {hi}")
                }
            )));
        }
    } else if !req.points.is_empty() {
        return Err(Invalid::Range(format!(
            "{}: takes no points ({} given)",
            kind.name(),
            req.points.len()
        )));
    }
    for (i, p) in req.points.iter().enumerate() {
        for (name, v) in [("x", p.x), ("y", p.y)] {
            if !v.is_finite() || v.abs() > MAX_COORD_M {
                return Err(Invalid::Range(format!(
                    "points[{i}].{name} {v}: expected a finite coordinate in metres (|v| <= {MAX_COORD_M})"
                )));
            }
        }
        o.points[i] = Pose2D::new(p.x, p.y, 0.0);
    }
    o.count = req.points.len() as u32;
    match kind {
        OrderKind::ReachBeacon => {
            o.beacon_id = req
                .beacon_id
                .ok_or_else(|| Invalid::Range("reach_beacon: beacon_id is required".to_owned()))?;
        }
        OrderKind::FollowWall => {
            o.side = match req.side {
                Some(SideReq::Left) => SIDE_LEFT,
                Some(SideReq::Right) => SIDE_RIGHT,
                None => {
                    return Err(Invalid::Range(
                        "follow_wall: side (\"left\" or \"right\") is required".to_owned(),
                    ));
                }
            };
        }
        _ => {
            if req.beacon_id.is_some() || req.side.is_some() {
                return Err(Invalid::Range(format!(
                    "{}: beacon_id and side are for reach_beacon and follow_wall",
                    kind.name()
                )));
            }
        }
    }
    Ok(o)
}

/// `POST /api/teleop` (and the page's teleop messages on the WebSocket).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeleopReq {
    /// Forward speed, m/s.
    pub linear_x: f64,
    /// Turn rate, rad/s.
    #[serde(default)]
    pub angular_z: f64,
}

/// Checks a teleop request.
pub fn teleop_checked(req: TeleopReq) -> Result<Twist, Invalid> {
    if !req.linear_x.is_finite() || req.linear_x.abs() > MAX_TELEOP_SPEED {
        return Err(Invalid::Range(format!(
            "linear_x {}: expected a finite speed in [-{MAX_TELEOP_SPEED}, {MAX_TELEOP_SPEED}] m/s",
            req.linear_x
        )));
    }
    if !req.angular_z.is_finite() || req.angular_z.abs() > MAX_TELEOP_TURN {
        return Err(Invalid::Range(format!(
            "angular_z {}: expected a finite turn rate in [-{MAX_TELEOP_TURN}, {MAX_TELEOP_TURN}] rad/s",
            req.angular_z
        )));
    }
    Ok(Twist {
        linear_x: req.linear_x,
        angular_z: req.angular_z,
        ..Default::default()
    })
}

/// Parses and checks a teleop command.
pub fn teleop(body: &[u8]) -> Result<Twist, Invalid> {
    teleop_checked(parse(body, "teleop")?)
}

/// `POST /api/designate`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct DesignateReq {
    beacon_id: u32,
    #[serde(default = "yes")]
    active: bool,
}

fn yes() -> bool {
    true
}

/// Parses a designation.
pub fn designation(body: &[u8]) -> Result<Designation, Invalid> {
    let r: DesignateReq = parse(body, "designation")?;
    Ok(Designation {
        beacon_id: r.beacon_id,
        active: u8::from(r.active),
        ..Default::default()
    })
}

/// What the page may ask of the supervisor.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ModuleOp {
    /// Send a signal (fault injection).
    Kill,
    /// Maintenance restart.
    Restart,
    /// Start a stopped or deactivated module.
    Start,
    /// Stop the module.
    Stop,
}

/// `POST /api/module`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleReq {
    /// What to do.
    pub op: ModuleOp,
    /// To which module.
    pub module: String,
    /// Signal for `kill` (default KILL): a name or a number.
    #[serde(default)]
    pub signal: Option<String>,
}

/// Signals the page may send, by name.
const SIGNALS: &[(&str, i32)] = &[
    ("KILL", 9),
    ("TERM", 15),
    ("SEGV", 11),
    ("STOP", 19),
    ("CONT", 18),
    ("INT", 2),
    ("HUP", 1),
    ("ABRT", 6),
    ("BUS", 7),
];

/// Parses a module command; returns it with the signal number (for `kill`).
pub fn module_command(body: &[u8]) -> Result<(ModuleReq, i32), Invalid> {
    let r: ModuleReq = parse(body, "module command")?;
    if r.module.is_empty() || r.module.len() > 31 || r.module.contains('\0') {
        return Err(Invalid::Range(format!(
            "module {:?}: expected a module name of 1 to 31 bytes",
            r.module
        )));
    }
    let name = r.signal.as_deref().unwrap_or("KILL").trim();
    let up = name.to_ascii_uppercase();
    let up = up.strip_prefix("SIG").unwrap_or(&up);
    let signal = SIGNALS
        .iter()
        .find(|(n, _)| *n == up)
        .map(|(_, v)| *v)
        .or_else(|| name.parse::<i32>().ok().filter(|n| (1..=64).contains(n)))
        .ok_or_else(|| {
            Invalid::Range(format!(
                "signal {name:?}: expected KILL, TERM, SEGV, STOP, CONT, INT, HUP, ABRT, BUS or 1..64"
            ))
        })?;
    Ok((r, signal))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goals_and_waypoints_become_orders() {
        let o = order(br#"{"kind":"goal","points":[{"x":1.5,"y":-2}]}"#, 7).unwrap();
        assert_eq!(o.kind, OrderKind::Goal as u32);
        assert_eq!(o.seq, 7);
        assert_eq!(o.points(), &[Pose2D::new(1.5, -2.0, 0.0)]);
        let o = order(
            br#"{"kind":"waypoints","points":[{"x":1,"y":1},{"x":2,"y":2}],"tolerance_m":0.3}"#,
            8,
        )
        .unwrap();
        assert_eq!(o.count, 2);
        assert_eq!(o.tolerance_m, 0.3);
        let o = order(br#"{"kind":"follow_wall","side":"right"}"#, 9).unwrap();
        assert_eq!(o.side, SIDE_RIGHT);
        let o = order(br#"{"kind":"reach_beacon","beacon_id":3}"#, 9).unwrap();
        assert_eq!(o.beacon_id, 3);
        assert_eq!(
            order(br#"{"kind":"stop"}"#, 1).unwrap().kind,
            OrderKind::Stop as u32
        );
    }

    #[test]
    fn bad_orders_are_refused_with_a_reason() {
        let e = order(b"{not json", 1).unwrap_err();
        assert_eq!(e.status(), 400, "{e}");
        let e = order(br#"{"kind":"fly"}"#, 1).unwrap_err();
        assert_eq!(e.status(), 400);
        assert!(e.to_string().contains("fly"), "{e}");
        let e = order(br#"{"kind":"stop","speed":3}"#, 1).unwrap_err();
        assert!(e.to_string().contains("speed"), "{e}");
        let e = order(br#"{"kind":"goal","points":[]}"#, 1).unwrap_err();
        assert_eq!(e.status(), 422);
        let e = order(br#"{"kind":"goal","points":[{"x":1e300,"y":0}]}"#, 1).unwrap_err();
        assert!(e.to_string().contains("points[0].x"), "{e}");
        let e = order(
            br#"{"kind":"goal","points":[{"x":1,"y":1}],"tolerance_m":-1}"#,
            1,
        )
        .unwrap_err();
        assert!(e.to_string().contains("tolerance_m"), "{e}");
        let many: Vec<String> = (0..17).map(|i| format!(r#"{{"x":{i},"y":0}}"#)).collect();
        let body = format!(r#"{{"kind":"waypoints","points":[{}]}}"#, many.join(","));
        assert_eq!(order(body.as_bytes(), 1).unwrap_err().status(), 422);
        assert!(order(br#"{"kind":"reach_beacon"}"#, 1).is_err());
        assert!(order(br#"{"kind":"follow_wall","side":"up"}"#, 1).is_err());
        assert!(order(br#"{"kind":"stop","points":[{"x":1,"y":1}]}"#, 1).is_err());
    }

    #[test]
    fn teleop_needs_finite_bounded_speeds() {
        let t = teleop(br#"{"linear_x":0.3,"angular_z":-0.5}"#).unwrap();
        assert_eq!((t.linear_x, t.angular_z), (0.3, -0.5));
        assert_eq!(teleop(br#"{"linear_x":5}"#).unwrap_err().status(), 422);
        // JSON has no NaN: a string is a shape error.
        assert_eq!(teleop(br#"{"linear_x":"NaN"}"#).unwrap_err().status(), 400);
        assert!(
            teleop_checked(TeleopReq {
                linear_x: f64::NAN,
                angular_z: 0.0
            })
            .is_err()
        );
    }

    #[test]
    fn module_commands_name_a_module_and_a_known_signal() {
        let (r, s) = module_command(br#"{"op":"kill","module":"slam","signal":"segv"}"#).unwrap();
        assert_eq!((r.op, r.module.as_str(), s), (ModuleOp::Kill, "slam", 11));
        assert_eq!(
            module_command(br#"{"op":"restart","module":"slam"}"#)
                .unwrap()
                .1,
            9
        );
        assert!(module_command(br#"{"op":"kill","module":"slam","signal":"NOPE"}"#).is_err());
        assert!(module_command(br#"{"op":"explode","module":"slam"}"#).is_err());
        assert!(module_command(br#"{"op":"kill","module":""}"#).is_err());
    }
}
