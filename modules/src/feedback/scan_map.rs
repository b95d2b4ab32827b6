//! [`ScanMapAgreement`]: Planning rates its "Mapping" provider by agreement with the scans
//! (client feedback, the E term of eq. 3; docs/autonomy.md).
//!
//! Once per `window_s`, the endpoints of one scan (beams with a return, at most `max_points`
//! of them, evenly spread) are placed in the map at the robot's pose. An endpoint *agrees*
//! when an occupied cell of the map lies within `hit_m` of it (a distance transform of the
//! map, computed once per map); endpoints in unknown cells count neither way, nor do those
//! outside a map that has unknown cells (a SLAM map still growing), while outside a complete
//! map (a survey, no unknown cell: it claims to cover the place) they disagree; with fewer
//! than `min_points` endpoints to judge by nothing is judged. The agreement is the best fraction over small shifts of the pose (± `search_m`
//! in x and y, ± `search_rad` in heading): an error of the pose is the Localization
//! provider's (the Servo rates that one), so the map is blamed only for what no placement
//! near the pose explains. `E = 0` at an agreement of `agree` or more, falling linearly to
//! `E = −1` at `disagree`. As for the Servo's rating, only the penalty side is used (a
//! positive E sent at every refresh would pile up and entrench the provider in use).
//!
//! A pose wrong by more than `search_m` would blame the map too: Planning passes no pose
//! while its [`super::PoseCheck`] has the Localization provider's poses in doubt (they
//! disagree with the odometry, or jumped to an operator's estimate), so nothing is judged then.

use hng_runtime::channel::InputId;
use hng_runtime::map::{OCCUPIED, OccupancyGrid, UNKNOWN};
use hng_runtime::msg::{LaserScan, Pose2D};
use hng_runtime::{Context, ModuleResult, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{ConfigError, field_error};
use crate::planning::squared_distance_transform;

/// Parameters of the map rating (`map_feedback` in Planning's configuration).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapFeedbackParams {
    /// One rating per this long, s (default 1.0).
    pub window_s: f64,
    /// An endpoint this close to an occupied cell agrees with the map, m (default 0.15).
    pub hit_m: f64,
    /// Pose shifts searched in x and y, ± m (default 1.0).
    pub search_m: f64,
    /// Heading shifts searched, ± rad (default 0.15).
    pub search_rad: f64,
    /// Agreement at or above which E = 0 (default 0.6).
    pub agree: f64,
    /// Agreement at or below which E = −1 (default 0.3).
    pub disagree: f64,
    /// Fewest known endpoints to judge by (default 20).
    pub min_points: usize,
    /// Most endpoints used per rating (default 90).
    pub max_points: usize,
}

impl Default for MapFeedbackParams {
    fn default() -> Self {
        MapFeedbackParams {
            window_s: 1.0,
            hit_m: 0.15,
            search_m: 1.0,
            search_rad: 0.15,
            agree: 0.6,
            disagree: 0.3,
            min_points: 20,
            max_points: 90,
        }
    }
}

impl MapFeedbackParams {
    /// Checks the values; the error names the field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (f, v) in [
            ("map_feedback.window_s", self.window_s),
            ("map_feedback.hit_m", self.hit_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(field_error(f, "must be > 0"));
            }
        }
        for (f, v) in [
            ("map_feedback.search_m", self.search_m),
            ("map_feedback.search_rad", self.search_rad),
        ] {
            crate::common::non_negative(f, v)?;
        }
        if !((0.0..self.agree).contains(&self.disagree) && self.agree <= 1.0) {
            return Err(field_error(
                "map_feedback.agree",
                "needs 0 <= disagree < agree <= 1",
            ));
        }
        if self.min_points == 0 || self.max_points < self.min_points {
            return Err(field_error(
                "map_feedback.max_points",
                "needs 1 <= min_points <= max_points",
            ));
        }
        Ok(())
    }
}

/// Agreement of a map with the scans.
#[derive(Debug, Clone, Default)]
pub struct ScanMapAgreement {
    /// The parameters.
    pub params: MapFeedbackParams,
    map: Option<OccupancyGrid>,
    /// The map has no unknown cell.
    complete: bool,
    /// Distance of each cell to the nearest occupied one, m (empty until needed).
    dist: Vec<f32>,
    last_t: Option<f64>,
    /// The last evaluation and the agreement behind it.
    pub last: Option<(f64, f64)>,
}

impl ScanMapAgreement {
    /// A rater with `params`.
    pub fn new(params: MapFeedbackParams) -> ScanMapAgreement {
        ScanMapAgreement {
            params,
            ..ScanMapAgreement::default()
        }
    }

    /// The map to judge (the Mapping provider's latest).
    pub fn set_map(&mut self, map: &OccupancyGrid) {
        self.map = Some(map.clone());
        self.complete = !map.data().contains(&UNKNOWN);
        self.dist.clear();
    }

    /// Forgets the map and the window (a new provider: its map comes next).
    pub fn reset(&mut self) {
        self.map = None;
        self.dist.clear();
        self.last_t = None;
        self.last = None;
    }

    /// A scan taken at `pose` (map frame) at `t` s; returns an evaluation in [-1, 0] when a
    /// window closes and the map knows enough of what the scan sees.
    pub fn on_scan(&mut self, scan: &LaserScan, pose: &Pose2D, t: f64) -> Option<f64> {
        let p = self.params;
        if self.last_t.is_some_and(|t0| t >= t0 && t - t0 < p.window_s) {
            return None;
        }
        let map = self.map.as_ref()?;
        if !(pose.x.is_finite() && pose.y.is_finite() && pose.theta.is_finite()) {
            return None;
        }
        self.last_t = Some(t);
        let ranges = scan.ranges();
        let step = ranges.len().div_ceil(p.max_points).max(1);
        let (sin, cos) = pose.theta.sin_cos();
        let mut pts = Vec::with_capacity(p.max_points);
        for i in (0..ranges.len()).step_by(step) {
            let r = f64::from(ranges[i]);
            if !(r.is_finite() && r > f64::from(scan.range_min) && r < f64::from(scan.range_max)) {
                continue;
            }
            let a = f64::from(scan.angle(i));
            let (lx, ly) = (r * a.cos(), r * a.sin());
            let (wx, wy) = (pose.x + cos * lx - sin * ly, pose.y + sin * lx + cos * ly);
            let (cx, cy) = map.world_to_cell(wx, wy);
            let judged = match map.get(cx, cy) {
                Some(v) => v != UNKNOWN,
                None => self.complete,
            };
            if judged {
                pts.push((lx, ly));
            }
        }
        if pts.len() < p.min_points {
            return None;
        }
        if self.dist.is_empty() {
            let data = map.data();
            let res = map.resolution();
            self.dist =
                squared_distance_transform(map.width() as usize, map.height() as usize, |i| {
                    data[i] >= OCCUPIED / 2
                })
                .into_iter()
                .map(|d2| (d2.sqrt() * res) as f32)
                .collect();
        }
        let best = self.best_hits(map, &pts, pose);
        let agreement = best as f64 / pts.len() as f64;
        let e = if agreement >= p.agree {
            0.0
        } else {
            ((agreement - p.disagree) / (p.agree - p.disagree) - 1.0).clamp(-1.0, 0.0)
        };
        self.last = Some((e, agreement));
        Some(e)
    }

    /// The most endpoints that agree with the map over the searched shifts of `pose`.
    fn best_hits(&self, map: &OccupancyGrid, pts: &[(f64, f64)], pose: &Pose2D) -> usize {
        let p = self.params;
        let xy_step = map.resolution().max(0.1);
        let nxy = (p.search_m / xy_step).round() as i64;
        let nth = (p.search_rad / 0.05).round() as i64;
        let hit = p.hit_m as f32;
        let mut best = 0;
        let mut world = Vec::with_capacity(pts.len());
        for k in -nth..=nth {
            let (sin, cos) = (pose.theta + k as f64 * 0.05).sin_cos();
            world.clear();
            world.extend(
                pts.iter()
                    .map(|&(x, y)| (pose.x + cos * x - sin * y, pose.y + sin * x + cos * y)),
            );
            for i in -nxy..=nxy {
                for j in -nxy..=nxy {
                    let (dx, dy) = (i as f64 * xy_step, j as f64 * xy_step);
                    let hits = world
                        .iter()
                        .filter(|&&(x, y)| {
                            let (cx, cy) = map.world_to_cell(x + dx, y + dy);
                            map.index(cx, cy).is_some_and(|n| self.dist[n] <= hit)
                        })
                        .count();
                    if hits > best {
                        best = hits;
                        if best == pts.len() {
                            return best;
                        }
                    }
                }
            }
        }
        best
    }
}

/// A client's side of the rating: its scan input and the rater (Planning's "Mapping").
#[derive(Debug)]
pub struct MapRating {
    scan: Option<Subscriber<LaserScan>>,
    /// The rater.
    pub rater: ScanMapAgreement,
}

impl MapRating {
    /// Reads scans on `channel` (empty: no rating).
    pub fn new(ctx: &mut Context, channel: &str, params: MapFeedbackParams) -> ModuleResult<Self> {
        params.validate()?;
        Ok(MapRating {
            scan: if channel.is_empty() {
                None
            } else {
                Some(ctx.subscribe(channel, None)?)
            },
            rater: ScanMapAgreement::new(params),
        })
    }

    /// True if `input` is the scan input.
    pub fn is(&self, input: InputId) -> bool {
        self.scan.as_ref().is_some_and(|s| s.id() == input)
    }

    /// Reads the scans; the latest, at `pose`, rates the provider of need `need` when a
    /// window closes (`Context::evaluate_provider`, the path every client's feedback takes).
    pub fn on_input(&mut self, ctx: &mut Context, pose: Option<Pose2D>, need: u16) -> ModuleResult {
        let Some(sub) = &self.scan else {
            return Ok(());
        };
        let mut latest = None;
        while let Some(s) = sub.receive()? {
            latest = Some(*s);
        }
        if let (Some(scan), Some(pose)) = (latest, pose)
            && let Some(e) = self.rater.on_scan(&scan, &pose, ctx.now().as_secs_f64())
        {
            ctx.evaluate_provider(need, e);
            tracing::debug!(
                module = ctx.name(),
                e,
                agreement = self.rater.last.map_or(0.0, |l| l.1),
                "Mapping provider rated"
            );
            if e < 0.0 {
                let agreement = self.rater.last.map_or(0.0, |l| l.1);
                tracing::info!(
                    module = ctx.name(),
                    e,
                    agreement,
                    "the Mapping provider's map disagrees with the scan"
                );
            }
        }
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use hng_runtime::map::FREE;

    /// A 10 x 8 m room at 0.05 m with an inner wall, walls in `shift` (x, y) cells.
    fn room(shift: (i64, i64)) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(200, 160, 0.05, [0.0, 0.0], FREE).unwrap();
        let mut wall = |x: i64, y: i64| {
            g.set(x + shift.0, y + shift.1, OCCUPIED);
        };
        for x in 0..200 {
            wall(x, 0);
            wall(x, 159);
        }
        for y in 0..160 {
            wall(0, y);
            wall(199, y);
        }
        for y in 0..100 {
            wall(120, y);
        }
        for x in 40..90 {
            wall(x, 110);
        }
        g
    }

    /// A 360-beam scan of `truth` from `pose` (ray marching, 12 m range).
    fn scan(truth: &OccupancyGrid, pose: &Pose2D) -> LaserScan {
        let mut s = LaserScan::full_circle(&[f32::INFINITY; 360], 0.1, 12.0);
        for i in 0..360 {
            let a = pose.theta + f64::from(s.angle(i));
            let mut r = 0.1;
            s.ranges[i] = f32::INFINITY;
            while r < 12.0 {
                let c = truth.world_to_cell(pose.x + r * a.cos(), pose.y + r * a.sin());
                if truth.get(c.0, c.1).is_none_or(|v| v == OCCUPIED) {
                    s.ranges[i] = r as f32;
                    break;
                }
                r += 0.02;
            }
        }
        s
    }

    fn rate(map: &OccupancyGrid, truth: &OccupancyGrid, believed: Pose2D, real: Pose2D) -> f64 {
        let mut a = ScanMapAgreement::new(MapFeedbackParams::default());
        a.set_map(map);
        let e = a.on_scan(&scan(truth, &real), &believed, 0.0).unwrap();
        assert!(
            a.on_scan(&scan(truth, &real), &believed, 0.5).is_none(),
            "once per window"
        );
        e
    }

    #[test]
    fn the_true_map_agrees_and_a_wrong_one_is_blamed() {
        let truth = room((0, 0));
        let at = Pose2D::new(3.0, 3.0, 0.4);
        assert_eq!(rate(&truth, &truth, at, at), 0.0);
        // The surveyed map of another place: walls 1.5 m away from where the scans see them.
        assert_eq!(rate(&room((30, 30)), &truth, at, at), -1.0);
        // A pose 0.6 m and 0.1 rad off: the map is not blamed for the Localization's error.
        let off = Pose2D::new(3.5, 2.7, 0.5);
        assert_eq!(rate(&truth, &truth, off, at), 0.0);
    }

    #[test]
    fn unknown_cells_count_neither_way() {
        let truth = room((0, 0));
        let at = Pose2D::new(3.0, 3.0, 0.0);
        // A SLAM map seen only on the left: judged by what it knows.
        let mut partial = truth.clone();
        for x in 60..200 {
            for y in 0..160 {
                partial.set(x, y, UNKNOWN);
            }
        }
        assert_eq!(rate(&partial, &truth, at, at), 0.0);
        // Nothing known: no judgement.
        let blank = OccupancyGrid::new(200, 160, 0.05, [0.0, 0.0], UNKNOWN).unwrap();
        let mut a = ScanMapAgreement::new(MapFeedbackParams::default());
        a.set_map(&blank);
        assert_eq!(a.on_scan(&scan(&truth, &at), &at, 0.0), None);
        // No map: none either.
        let mut a = ScanMapAgreement::new(MapFeedbackParams::default());
        assert_eq!(a.on_scan(&scan(&truth, &at), &at, 0.0), None);
    }

    #[test]
    fn bad_parameters_are_refused_with_their_field() {
        let mut p = MapFeedbackParams::default();
        assert!(p.validate().is_ok());
        p.agree = 0.2;
        assert!(p.validate().unwrap_err().to_string().contains("agree"));
        p = MapFeedbackParams {
            window_s: f64::NAN,
            ..MapFeedbackParams::default()
        };
        assert!(p.validate().unwrap_err().to_string().contains("window_s"));
    }
}
