//! Wall detection: straight walls extracted from one laser scan by split-and-merge.
//!
//! The scan's valid returns become points in the sensor frame, in beam order. They are cut into
//! runs wherever two neighbours are further apart than a range-dependent gap (an open door, the
//! edge of a box). Each run is split recursively at the point furthest from the chord between its
//! ends while that point is further than the split tolerance (Douglas-Peucker, the "split" of
//! split-and-merge, Pavlidis and Horowitz 1974); neighbouring pieces that are collinear again are
//! merged. Each piece is then fitted by total least squares (the line through the centroid along
//! the points' main axis), which makes the fit independent of the beam order, and kept if it has
//! enough points and length. Nguyen et al. (2005, "A comparison of line extraction algorithms
//! using 2D laser rangefinder") found split-and-merge the fastest and among the most accurate of
//! the classic extractors, which is why it was chosen here.
//!
//! Conventions (REP-103): the sensor frame's x points forward, y to the left; angles in radians,
//! counter-clockwise.

use hng_runtime::msg::LaserScan;
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

/// Which side of the robot a wall is on, by the bearing of the wall's closest point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// Bearing of the closest point in [30, 150] degrees.
    Left,
    /// Bearing of the closest point in [-150, -30] degrees.
    Right,
    /// Ahead (bearing within 30 degrees of straight ahead).
    Front,
    /// Behind.
    Back,
}

impl Side {
    fn of_bearing(b: f64) -> Side {
        let deg = b.to_degrees();
        if (30.0..=150.0).contains(&deg) {
            Side::Left
        } else if (-150.0..=-30.0).contains(&deg) {
            Side::Right
        } else if deg.abs() < 30.0 {
            Side::Front
        } else {
            Side::Back
        }
    }
}

/// One straight wall seen in a scan, in the sensor frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Wall {
    /// Perpendicular distance from the sensor to the wall's line, m.
    pub distance: f64,
    /// Bearing of the foot of that perpendicular (the closest point of the line), rad.
    pub normal_bearing: f64,
    /// Direction of the wall relative to the sensor's x axis, in (-pi/2, pi/2], rad: 0 for a
    /// wall parallel to the robot's heading.
    pub angle: f64,
    /// Length between the extreme points, m.
    pub length: f64,
    /// The side the wall is on, by the bearing of its closest point (the foot of the
    /// perpendicular when the wall is `beside` the sensor, else its nearer end).
    pub side: Side,
    /// The foot of the perpendicular lies on the wall: the sensor is level with some part of
    /// it (a follower follows only such a wall; one that ended behind is an outer corner).
    pub beside: bool,
    /// First and last point (in beam order) projected on the line, m.
    pub start: [f64; 2],
    /// See `start`.
    pub end: [f64; 2],
    /// Number of scan points on the wall.
    pub points: usize,
    /// Root mean square distance of those points from the line, m.
    pub rmse: f64,
}

/// Parameters of the extractor. Distances in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct WallDetectorConfig {
    /// A point further than this from the chord splits a piece (plus `split_per_metre` times
    /// its range, for the noise that grows with range).
    #[default(0.04)]
    pub split_tolerance: f64,
    /// Range-proportional part of the split tolerance, m per m of range.
    #[default(0.01)]
    pub split_per_metre: f64,
    /// Breakpoints (Borges and Aldon 2004, adaptive breakpoint detector): two neighbouring
    /// points start a new run when they are further apart than a wall seen at this incidence
    /// angle (rad) would put them, `r sin(dθ) / sin(λ - dθ)`, plus three `range_sigma`. Walls
    /// seen more obliquely than this fall apart into their near part (which is the part a
    /// follower needs).
    #[default(10f64.to_radians())]
    pub breakpoint_incidence: f64,
    /// Standard deviation of a range reading, m.
    #[default(0.01)]
    pub range_sigma: f64,
    /// Fewest points a wall is made of.
    #[default(6)]
    pub min_points: usize,
    /// Shortest wall reported, m.
    #[default(0.4)]
    pub min_length: f64,
    /// Two neighbouring pieces merge when their directions differ by less than this (rad) and
    /// their lines are within `split_tolerance` of each other's ends.
    #[default(0.08)]
    pub merge_angle: f64,
    /// Returns further than this are ignored, m (walls far away are not followed).
    #[default(8.0)]
    pub max_range: f64,
}

/// The wall extractor; keeps its buffers between scans so a scan allocates nothing once warm.
#[derive(Debug, Default)]
pub struct WallDetector {
    cfg: WallDetectorConfig,
    pts: Vec<[f64; 2]>,
    ranges: Vec<f64>,
    pieces: Vec<(usize, usize)>,
    stack: Vec<(usize, usize)>,
}

impl WallDetector {
    /// A detector with `cfg`.
    #[must_use]
    pub fn new(cfg: WallDetectorConfig) -> Self {
        WallDetector {
            cfg,
            ..WallDetector::default()
        }
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &WallDetectorConfig {
        &self.cfg
    }

    /// The walls of a scan message (its own geometry), closest first, appended to `out`
    /// after clearing it.
    pub fn detect_scan(&mut self, scan: &LaserScan, out: &mut Vec<Wall>) {
        self.detect(
            f64::from(scan.angle_min),
            f64::from(scan.angle_increment),
            f64::from(scan.range_min),
            scan.ranges(),
            out,
        );
    }

    /// The walls of the beams `ranges`, beam `i` at `angle_min + i * angle_increment`; returns
    /// outside `[range_min, max_range]` and non-finite ones are skipped.
    pub fn detect(
        &mut self,
        angle_min: f64,
        angle_increment: f64,
        range_min: f64,
        ranges: &[f32],
        out: &mut Vec<Wall>,
    ) {
        out.clear();
        self.pts.clear();
        self.ranges.clear();
        if !(angle_increment.is_finite() && angle_increment > 0.0 && angle_min.is_finite()) {
            return;
        }
        for (i, &r) in ranges.iter().enumerate() {
            let r = f64::from(r);
            if r.is_finite() && r >= range_min.max(0.0) && r <= self.cfg.max_range {
                let a = angle_min + angle_increment * i as f64;
                self.pts.push([r * a.cos(), r * a.sin()]);
                self.ranges.push(r);
            }
        }
        // Runs of neighbouring points.
        self.pieces.clear();
        let mut start = 0;
        let lambda = self.cfg.breakpoint_incidence;
        let spread = angle_increment.sin() / (lambda - angle_increment).sin().max(1e-6);
        for i in 1..=self.pts.len() {
            let cut = i == self.pts.len() || {
                let r = self.ranges[i].min(self.ranges[i - 1]);
                let allowed = r * spread + 3.0 * self.cfg.range_sigma;
                dist(self.pts[i], self.pts[i - 1]) > allowed
            };
            if cut {
                if i - start >= self.cfg.min_points {
                    self.split(start, i);
                }
                start = i;
            }
        }
        self.merge();
        for &(a, b) in &self.pieces {
            if let Some(w) = fit(&self.pts[a..b])
                && w.points >= self.cfg.min_points
                && w.length >= self.cfg.min_length
            {
                out.push(w);
            }
        }
        out.sort_by(|a, b| a.distance.total_cmp(&b.distance));
    }

    /// Splits the points `[a, b)` into straight pieces, appended to `self.pieces` in order.
    fn split(&mut self, a: usize, b: usize) {
        self.stack.clear();
        self.stack.push((a, b));
        let first = self.pieces.len();
        while let Some((a, b)) = self.stack.pop() {
            let (p, q) = (self.pts[a], self.pts[b - 1]);
            let mut worst = (0.0, a);
            for i in a + 1..b - 1 {
                let d = line_distance(p, q, self.pts[i]);
                let tol = self.cfg.split_tolerance + self.cfg.split_per_metre * self.ranges[i];
                let excess = d - tol;
                if excess > worst.0 {
                    worst = (excess, i);
                }
            }
            if worst.0 > 0.0 {
                // Keep the split point in both halves: it is the corner.
                self.stack.push((worst.1, b));
                self.stack.push((a, worst.1 + 1));
            } else {
                self.pieces.push((a, b));
            }
        }
        // The stack pops the first half first, so pieces come out in beam order.
        debug_assert!(self.pieces[first..].windows(2).all(|w| w[0].0 <= w[1].0));
    }

    /// Merges neighbouring pieces that share a point and lie on one line.
    fn merge(&mut self) {
        let mut merged: Vec<(usize, usize)> = Vec::with_capacity(self.pieces.len());
        for &(a, b) in &self.pieces {
            if let Some(last) = merged.last_mut()
                && last.1 > a
                && self.collinear(*last, (a, b))
            {
                last.1 = b;
                continue;
            }
            merged.push((a, b));
        }
        self.pieces = merged;
    }

    fn collinear(&self, x: (usize, usize), y: (usize, usize)) -> bool {
        let dir = |(a, b): (usize, usize)| {
            let (p, q) = (self.pts[a], self.pts[b - 1]);
            (q[1] - p[1]).atan2(q[0] - p[0])
        };
        let mut d = (dir(x) - dir(y)).rem_euclid(std::f64::consts::PI);
        if d > std::f64::consts::FRAC_PI_2 {
            d = std::f64::consts::PI - d;
        }
        let (p, q) = (self.pts[x.0], self.pts[y.1 - 1]);
        let tol = self.cfg.split_tolerance;
        d < self.cfg.merge_angle
            && line_distance(p, q, self.pts[x.1 - 1]) < tol
            && line_distance(p, q, self.pts[y.0]) < tol
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Distance of `x` from the line through `p` and `q` (from `p` if they coincide).
fn line_distance(p: [f64; 2], q: [f64; 2], x: [f64; 2]) -> f64 {
    let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
    let len = dx.hypot(dy);
    if len < 1e-12 {
        return dist(p, x);
    }
    ((x[0] - p[0]) * dy - (x[1] - p[1]) * dx).abs() / len
}

/// Total-least-squares line through `pts`.
fn fit(pts: &[[f64; 2]]) -> Option<Wall> {
    let n = pts.len();
    if n < 2 {
        return None;
    }
    let nf = n as f64;
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0] / nf, y + p[1] / nf));
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy) = (p[0] - mx, p[1] - my);
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    // Direction of the main axis of the scatter.
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (u, v) = (theta.cos(), theta.sin());
    let project = |p: &[f64; 2]| {
        let t = (p[0] - mx) * u + (p[1] - my) * v;
        [mx + t * u, my + t * v]
    };
    let start = project(&pts[0]);
    let end = project(&pts[n - 1]);
    let sq: f64 = pts
        .iter()
        .map(|p| {
            let d = -(p[0] - mx) * v + (p[1] - my) * u;
            d * d
        })
        .sum();
    // Foot of the perpendicular from the sensor (the origin) onto the line.
    let t0 = -(mx * u + my * v);
    let foot = [mx + t0 * u, my + t0 * v];
    let distance = foot[0].hypot(foot[1]);
    let normal_bearing = foot[1].atan2(foot[0]);
    let along = |p: [f64; 2]| (p[0] - mx) * u + (p[1] - my) * v;
    let (ta, tb) = (along(start), along(end));
    let beside = t0 >= ta.min(tb) && t0 <= ta.max(tb);
    let closest = if beside {
        foot
    } else if (t0 - ta).abs() < (t0 - tb).abs() {
        start
    } else {
        end
    };
    // Wall direction folded into (-pi/2, pi/2].
    let mut angle = theta;
    if angle <= -std::f64::consts::FRAC_PI_2 {
        angle += std::f64::consts::PI;
    } else if angle > std::f64::consts::FRAC_PI_2 {
        angle -= std::f64::consts::PI;
    }
    Some(Wall {
        distance,
        normal_bearing,
        angle,
        length: dist(start, end),
        side: Side::of_bearing(closest[1].atan2(closest[0])),
        beside,
        start,
        end,
        points: n,
        rmse: (sq / nf).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Ranges of a 360-beam, 360-degree lidar at the origin of a room given as segments.
    fn cast(segments: &[([f64; 2], [f64; 2])], beams: usize) -> (f64, f64, Vec<f32>) {
        let inc = 2.0 * PI / beams as f64;
        let a0 = -PI;
        let ranges = (0..beams)
            .map(|i| {
                let a = a0 + inc * i as f64;
                let (dx, dy) = (a.cos(), a.sin());
                let mut best = f64::INFINITY;
                for &(p, q) in segments {
                    let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
                    let den = dx * ey - dy * ex;
                    if den.abs() < 1e-12 {
                        continue;
                    }
                    let t = (p[0] * ey - p[1] * ex) / den;
                    let s = (p[0] * dy - p[1] * dx) / den;
                    if t > 0.0 && (0.0..=1.0).contains(&s) {
                        best = best.min(t);
                    }
                }
                best as f32
            })
            .collect();
        (a0, inc, ranges)
    }

    fn detect(segments: &[([f64; 2], [f64; 2])]) -> Vec<Wall> {
        let (a0, inc, ranges) = cast(segments, 360);
        let mut d = WallDetector::new(WallDetectorConfig::default());
        let mut out = Vec::new();
        d.detect(a0, inc, 0.05, &ranges, &mut out);
        out
    }

    #[test]
    fn a_corridor_gives_two_parallel_walls_at_their_distances() {
        // Left wall 0.6 m away, right wall 1.4 m away, both parallel to x, 10 m long.
        let walls = detect(&[([-5.0, 0.6], [5.0, 0.6]), ([-5.0, -1.4], [5.0, -1.4])]);
        assert_eq!(walls.len(), 2, "{walls:#?}");
        let (l, r) = (&walls[0], &walls[1]);
        assert_eq!((l.side, r.side), (Side::Left, Side::Right));
        assert!((l.distance - 0.6).abs() < 0.01, "{l:?}");
        assert!((r.distance - 1.4).abs() < 0.01, "{r:?}");
        assert!(l.angle.abs() < 0.01 && r.angle.abs() < 0.01);
        // Seen at 10 degrees of incidence or more: 0.6 / tan(10 deg) = 3.4 m either way.
        assert!(l.length > 6.0, "{l:?}");
        assert!(l.rmse < 1e-6);
    }

    #[test]
    fn a_corner_is_split_into_two_walls() {
        // A wall on the left along x, turning into a wall across the path at x = 2.
        let walls = detect(&[([-3.0, 0.6], [2.0, 0.6]), ([2.0, 0.6], [2.0, -3.0])]);
        assert_eq!(walls.len(), 2, "{walls:#?}");
        let front = walls.iter().find(|w| w.side == Side::Front);
        let left = walls.iter().find(|w| w.side == Side::Left);
        let (Some(front), Some(left)) = (front, left) else {
            panic!("expected a front and a left wall: {walls:#?}");
        };
        assert!((front.distance - 2.0).abs() < 0.02, "{front:?}");
        assert!((front.angle.abs() - PI / 2.0).abs() < 0.02, "{front:?}");
        assert!((left.distance - 0.6).abs() < 0.02, "{left:?}");
    }

    #[test]
    fn a_turned_wall_reports_its_angle() {
        // A wall on the right, turned 20 degrees: y = -1 + tan(20 deg) x.
        let t = 20f64.to_radians().tan();
        let walls = detect(&[([-4.0, -1.0 - 4.0 * t], [4.0, -1.0 + 4.0 * t])]);
        assert_eq!(walls.len(), 1, "{walls:#?}");
        let w = walls[0];
        assert_eq!(w.side, Side::Right);
        assert!((w.angle - 20f64.to_radians()).abs() < 0.01, "{w:?}");
        assert!(
            (w.distance - 20f64.to_radians().cos()).abs() < 0.01,
            "{w:?}"
        );
    }

    #[test]
    fn a_door_gap_splits_a_wall_and_clutter_is_ignored() {
        // A left wall with a 1 m door at x in [0.5, 1.5], and a small box (0.2 m) on the right.
        let walls = detect(&[
            ([-5.0, 1.0], [0.5, 1.0]),
            ([1.5, 1.0], [5.0, 1.0]),
            ([1.0, -1.0], [1.2, -1.0]),
            ([1.2, -1.0], [1.2, -1.2]),
        ]);
        let left: Vec<_> = walls.iter().filter(|w| w.side == Side::Left).collect();
        assert_eq!(left.len(), 2, "{walls:#?}");
        assert!(walls.iter().all(|w| w.length >= 0.4), "{walls:#?}");
    }

    #[test]
    fn nothing_in_range_and_bad_scans_give_no_walls() {
        let mut d = WallDetector::new(WallDetectorConfig::default());
        let mut out = vec![];
        d.detect(-PI, 0.01, 0.05, &[f32::INFINITY; 300], &mut out);
        assert!(out.is_empty());
        d.detect(-PI, f64::NAN, 0.05, &[1.0; 300], &mut out);
        assert!(out.is_empty());
        d.detect(-PI, 0.0, 0.05, &[1.0; 300], &mut out);
        assert!(out.is_empty());
        let mut noisy = [f32::NAN; 360];
        noisy[10] = -1.0;
        d.detect(-PI, 2.0 * PI / 360.0, 0.05, &noisy, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn noisy_ranges_still_give_one_wall_per_side() {
        let (a0, inc, mut ranges) = cast(&[([-5.0, 0.8], [5.0, 0.8])], 360);
        // Deterministic +-1 cm noise.
        let mut s: u32 = 12345;
        for r in ranges.iter_mut().filter(|r| r.is_finite()) {
            s = s.wrapping_mul(1_103_515_245).wrapping_add(12345);
            *r += ((s >> 16) as f32 / 65535.0 - 0.5) * 0.02;
        }
        let mut d = WallDetector::new(WallDetectorConfig::default());
        let mut out = vec![];
        d.detect(a0, inc, 0.05, &ranges, &mut out);
        assert_eq!(out.len(), 1, "{out:#?}");
        assert!((out[0].distance - 0.8).abs() < 0.01, "{:?}", out[0]);
        assert!(out[0].angle.abs() < 0.02, "{:?}", out[0]);
    }
}
