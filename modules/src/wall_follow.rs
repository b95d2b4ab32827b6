//! Wall following: the control law of the Wall follower (Table 1: "Follow wall"), on the walls
//! of [`crate::walls`].
//!
//! The robot keeps `distance` from the wall on the chosen side. On a straight wall the turn rate
//! is `k_angle · angle + s · k_distance · (d − distance)` (`angle` is the wall's direction in the
//! robot frame, `d` its distance, `s` = +1 for a wall on the left and −1 on the right), and the
//! speed falls with the turn rate. An obstacle ahead closer than `distance + front_margin` is an
//! inner corner: the robot turns in place away from the wall. A wall that ends (an outer corner,
//! a door) is followed round: the robot drives an arc of radius `distance` towards its side
//! until the wall is seen again, for at most `max_turn_around` radians; then there is no wall to
//! follow and it stops. Blocked ahead with both sides closer than `distance + front_margin` is a
//! dead end: it stops.

use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::walls::{Side, Wall};

/// Parameters of the follower. Metres, radians, seconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct WallFollowConfig {
    /// Distance to keep from the wall, m (default 0.6).
    #[default(0.6)]
    pub distance: f64,
    /// Which wall to follow: `left` or `right`.
    #[default(Side::Left)]
    pub side: Side,
    /// Cruise speed, m/s (default 0.4).
    #[default(0.4)]
    pub speed: f64,
    /// Turn rate limit, rad/s (default 1.2).
    #[default(1.2)]
    pub max_angular: f64,
    /// Turn rate per metre of distance error, rad/s/m (default 1.5).
    #[default(1.5)]
    pub k_distance: f64,
    /// Turn rate per radian of wall angle, 1/s (default 1.8).
    #[default(1.8)]
    pub k_angle: f64,
    /// An obstacle ahead closer than `distance + front_margin` is a corner, m (default 0.35).
    #[default(0.35)]
    pub front_margin: f64,
    /// How far to turn round an outer corner looking for the wall again, rad (default 3π/2).
    #[default(1.5 * std::f64::consts::PI)]
    pub max_turn_around: f64,
}

impl WallFollowConfig {
    /// Checks the values; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("distance", self.distance),
            ("speed", self.speed),
            ("max_angular", self.max_angular),
            ("k_distance", self.k_distance),
            ("k_angle", self.k_angle),
            ("front_margin", self.front_margin),
            ("max_turn_around", self.max_turn_around),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("field `{field}`: must be finite and > 0, got {v}"));
            }
        }
        if !matches!(self.side, Side::Left | Side::Right) {
            return Err("field `side`: must be left or right".to_owned());
        }
        Ok(())
    }
}

/// What the follower is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FollowState {
    /// Along a wall on the chosen side.
    Following,
    /// Turning in place away from the wall: blocked ahead.
    InnerCorner,
    /// The wall ended: arcing round towards the chosen side to find it again.
    OuterCorner,
    /// Blocked ahead and on both sides: stopped.
    DeadEnd,
    /// No wall on the chosen side (never seen, or lost after turning round): stopped.
    NoWall,
}

/// A velocity command: forward speed (m/s) and turn rate (rad/s), in `base_link`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Command {
    /// Forward speed, m/s.
    pub linear_x: f64,
    /// Turn rate, rad/s.
    pub angular_z: f64,
}

/// The follower: [`WallFollower::step`] once per scan.
#[derive(Debug, Clone)]
pub struct WallFollower {
    cfg: WallFollowConfig,
    /// Radians turned since the wall was lost; `None` while it is seen or was never seen.
    turned_since_lost: Option<f64>,
    seen: bool,
}

impl WallFollower {
    /// A follower with `cfg` (validate it first with [`WallFollowConfig::validate`]).
    #[must_use]
    pub fn new(cfg: WallFollowConfig) -> Self {
        WallFollower {
            cfg,
            turned_since_lost: None,
            seen: false,
        }
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &WallFollowConfig {
        &self.cfg
    }

    /// Forgets the wall (a new order).
    pub fn reset(&mut self) {
        self.turned_since_lost = None;
        self.seen = false;
    }

    /// The command for one scan: `walls` from the detector, `front` the closest obstacle in the
    /// forward sector (m, infinite when none), `dt` the time since the previous step (s).
    pub fn step(&mut self, walls: &[Wall], front: f64, dt: f64) -> (Command, FollowState) {
        let c = &self.cfg;
        let s = if c.side == Side::Left { 1.0 } else { -1.0 };
        let near = c.distance + c.front_margin;
        let side_wall = walls
            .iter()
            .filter(|w| w.side == c.side && w.beside)
            .min_by(|a, b| a.distance.total_cmp(&b.distance));
        let other_side = if c.side == Side::Left {
            Side::Right
        } else {
            Side::Left
        };
        let closed = |side: Side| walls.iter().any(|w| w.side == side && w.distance < near);
        if front < near {
            if closed(c.side) && closed(other_side) {
                return (Command::default(), FollowState::DeadEnd);
            }
            if side_wall.is_some() {
                self.seen = true;
                self.turned_since_lost = None;
            }
            // Turn in place away from the wall side.
            let cmd = Command {
                linear_x: 0.0,
                angular_z: -s * c.max_angular,
            };
            return (cmd, FollowState::InnerCorner);
        }
        if let Some(w) = side_wall {
            self.seen = true;
            self.turned_since_lost = None;
            let error = w.distance - c.distance;
            let w_cmd = (c.k_angle * w.angle + s * c.k_distance * error)
                .clamp(-c.max_angular, c.max_angular);
            let slow = 1.0 - 0.7 * (w_cmd.abs() / c.max_angular);
            let cmd = Command {
                linear_x: c.speed * slow,
                angular_z: w_cmd,
            };
            return (cmd, FollowState::Following);
        }
        if !self.seen {
            return (Command::default(), FollowState::NoWall);
        }
        // Outer corner: arc of radius `distance` towards the side.
        let v = 0.5 * c.speed;
        let w = s * (v / c.distance).min(c.max_angular);
        let turned = self.turned_since_lost.unwrap_or(0.0) + w.abs() * dt.max(0.0);
        if turned > c.max_turn_around {
            self.seen = false;
            self.turned_since_lost = None;
            return (Command::default(), FollowState::NoWall);
        }
        self.turned_since_lost = Some(turned);
        (
            Command {
                linear_x: v,
                angular_z: w,
            },
            FollowState::OuterCorner,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::walls::{WallDetector, WallDetectorConfig};
    use std::f64::consts::PI;

    type Segment = ([f64; 2], [f64; 2]);

    /// Ranges from `pose` (x, y, theta) of a 360-beam lidar in a world of segments.
    fn cast(world: &[Segment], pose: [f64; 3]) -> (f64, f64, Vec<f32>) {
        let inc = 2.0 * PI / 360.0;
        let ranges = (0..360)
            .map(|i| {
                let a = pose[2] - PI + inc * i as f64;
                let (dx, dy) = (a.cos(), a.sin());
                let mut best = f64::INFINITY;
                for &(p, q) in world {
                    let (px, py) = (p[0] - pose[0], p[1] - pose[1]);
                    let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
                    let den = dx * ey - dy * ex;
                    if den.abs() < 1e-12 {
                        continue;
                    }
                    let t = (px * ey - py * ex) / den;
                    let u = (px * dy - py * dx) / den;
                    if t > 0.0 && (0.0..=1.0).contains(&u) {
                        best = best.min(t);
                    }
                }
                best as f32
            })
            .collect();
        (-PI, inc, ranges)
    }

    /// Closed-loop run of detector + follower on a unicycle; returns the distances to the
    /// followed wall (from the detector) and the poses.
    fn drive(
        world: &[Segment],
        start: [f64; 3],
        cfg: WallFollowConfig,
        steps: usize,
    ) -> Vec<([f64; 3], FollowState, Option<f64>)> {
        let mut det = WallDetector::new(WallDetectorConfig::default());
        let mut f = WallFollower::new(cfg);
        let mut walls = Vec::new();
        let mut pose = start;
        let dt = 0.1;
        let mut log = Vec::new();
        for _ in 0..steps {
            let (a0, inc, ranges) = cast(world, pose);
            det.detect(a0, inc, 0.05, &ranges, &mut walls);
            // Forward sector: +-25 degrees around beam 180 (straight ahead).
            let front = ranges[155..=205]
                .iter()
                .map(|&r| f64::from(r))
                .fold(f64::INFINITY, f64::min);
            let (cmd, state) = f.step(&walls, front, dt);
            let d = walls
                .iter()
                .filter(|w| w.side == cfg.side)
                .map(|w| w.distance)
                .fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.min(d))));
            log.push((pose, state, d));
            pose[2] += cmd.angular_z * dt;
            pose[0] += cmd.linear_x * dt * pose[2].cos();
            pose[1] += cmd.linear_x * dt * pose[2].sin();
        }
        log
    }

    #[test]
    fn converges_to_the_set_distance_on_a_straight_wall() {
        // A 20 m wall on the left at y = 1.2, the robot at y = 0 heading along it.
        let world = [([-2.0, 1.2], [22.0, 1.2])];
        let log = drive(&world, [0.0, 0.0, 0.0], WallFollowConfig::default(), 300);
        let tail = &log[150..];
        assert!(tail.iter().all(|(_, s, _)| *s == FollowState::Following));
        for (pose, _, _) in tail {
            assert!((1.2 - pose[1] - 0.6).abs() < 0.05, "pose {pose:?}");
        }
    }

    #[test]
    fn follows_a_right_wall_round_an_inner_corner() {
        // Right wall along y = -0.6 up to x = 6, then a wall across at x = 6 going up (an inner
        // corner on the right: the robot must turn left and follow the new wall up).
        let world = [([-2.0, -0.6], [6.0, -0.6]), ([6.0, -0.6], [6.0, 10.0])];
        let cfg = WallFollowConfig {
            side: Side::Right,
            ..WallFollowConfig::default()
        };
        let log = drive(&world, [0.0, 0.0, 0.0], cfg, 300);
        assert!(log.iter().any(|(_, s, _)| *s == FollowState::InnerCorner));
        let (end, state, _) = log[log.len() - 1];
        assert_eq!(state, FollowState::Following);
        // Now going up along x = 6 with the wall on the right, 0.6 m away.
        assert!((end[0] - 5.4).abs() < 0.08 && end[1] > 2.0, "{end:?}");
        // Never closer than 0.35 m to either wall.
        for (p, _, _) in &log {
            assert!(p[1] > -0.6 + 0.35 && p[0] < 6.0 - 0.35, "{p:?}");
        }
    }

    #[test]
    fn goes_round_an_outer_corner() {
        // Left wall along y = 0.6 up to x = 5, then turning left (up) along x = 5.
        let world = [([-2.0, 0.6], [5.0, 0.6]), ([5.0, 0.6], [5.0, 10.0])];
        let log = drive(&world, [0.0, 0.0, 0.0], WallFollowConfig::default(), 400);
        assert!(log.iter().any(|(_, s, _)| *s == FollowState::OuterCorner));
        let (end, state, d) = log[log.len() - 1];
        assert_eq!(state, FollowState::Following);
        assert!((end[0] - 5.6).abs() < 0.1 && end[1] > 2.0, "{end:?}");
        assert!(d.is_some_and(|d| (d - 0.6).abs() < 0.1), "{d:?}");
    }

    #[test]
    fn stops_at_a_dead_end_and_without_a_wall() {
        // A 1.4 m wide dead-end corridor.
        let world = [
            ([-2.0, 0.7], [4.0, 0.7]),
            ([-2.0, -0.7], [4.0, -0.7]),
            ([4.0, -0.7], [4.0, 0.7]),
        ];
        let log = drive(&world, [0.0, 0.0, 0.0], WallFollowConfig::default(), 200);
        let (end, state, _) = log[log.len() - 1];
        assert_eq!(state, FollowState::DeadEnd);
        assert!(end[0] < 4.0 - 0.5, "{end:?}");
        // Open space: nothing to follow, no motion.
        let mut f = WallFollower::new(WallFollowConfig::default());
        let (cmd, state) = f.step(&[], f64::INFINITY, 0.1);
        assert_eq!((cmd, state), (Command::default(), FollowState::NoWall));
    }

    #[test]
    fn bad_parameters_are_refused_with_the_field() {
        let cfg = WallFollowConfig {
            distance: f64::NAN,
            ..WallFollowConfig::default()
        };
        assert!(cfg.validate().is_err_and(|e| e.contains("`distance`")));
        let cfg = WallFollowConfig {
            side: Side::Front,
            ..WallFollowConfig::default()
        };
        assert!(cfg.validate().is_err_and(|e| e.contains("`side`")));
        assert!(WallFollowConfig::default().validate().is_ok());
    }
}
