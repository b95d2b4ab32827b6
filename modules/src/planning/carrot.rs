//! How far ahead on the path the pure-pursuit carrot goes: `lookahead_m` in the open, shorter
//! where the path passes near obstacles.
//!
//! Pure pursuit steers on the arc through the carrot, so it cuts the inside of every bend by a
//! distance that grows with the carrot's distance: with a 0.6 m carrot the robot passed a
//! door's jamb 0.1 m closer than the planned path (generated problem 8: plan 0.154 m,
//! robot 0.048 m). The carrot is therefore taken at the largest distance (from `lookahead_m` down to
//! `min_lookahead_m`, in 5 cm steps) for which the straight line from the robot to it keeps
//! at least the clearance the path itself keeps over that stretch (less 2 cm), or `comfort_m`
//! from obstacles where the path keeps more (in the open the carrot stays at `lookahead_m`).
//! The chord is the worst case for the inside of a bend: the arc the robot drives leaves along
//! its heading, on the path's side of the chord.

use crate::planning::OccupancyGrid;
use crate::planning::path::PathState;

/// Sampling step along the path and the chord, m.
const STEP_M: f64 = 0.05;
/// Shortening step of the carrot's distance, m.
const SHORTEN_M: f64 = 0.05;
/// What the chord may lose against the path: the clearance field is sampled on a grid.
const SLACK_M: f64 = 0.02;

/// The distance to the nearest obstacle at any point: bilinear between the centres of a
/// grid's cells.
pub(crate) struct ClearanceField<'a> {
    /// The costmap's grid.
    pub(crate) grid: &'a OccupancyGrid,
    /// Each cell centre's distance to the nearest obstacle, m (row-major, as the grid).
    pub(crate) clearances: &'a [f32],
}

impl ClearanceField<'_> {
    fn cell(&self, x: i64, y: i64) -> f64 {
        self.grid
            .index(x, y)
            .and_then(|i| self.clearances.get(i))
            .map_or(0.0, |&c| f64::from(c).min(1e3))
    }

    /// The distance to the nearest obstacle at `p` (map frame), m; 0 outside the map.
    pub(crate) fn at(&self, p: [f64; 2]) -> f64 {
        let res = self.grid.resolution();
        let o = self.grid.origin();
        let fx = (p[0] - o[0]) / res - 0.5;
        let fy = (p[1] - o[1]) / res - 0.5;
        if !(fx.is_finite() && fy.is_finite()) {
            return 0.0;
        }
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let v00 = self.cell(x0, y0);
        let v10 = self.cell(x0 + 1, y0);
        let v01 = self.cell(x0, y0 + 1);
        let v11 = self.cell(x0 + 1, y0 + 1);
        (v00 * (1.0 - tx) + v10 * tx) * (1.0 - ty) + (v01 * (1.0 - tx) + v11 * tx) * ty
    }

    /// The least distance to obstacles along the segment `a`-`b`.
    fn along_segment(&self, a: [f64; 2], b: [f64; 2]) -> f64 {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = (len / STEP_M).ceil().max(1.0) as usize;
        (0..=n)
            .map(|i| {
                let t = i as f64 / n as f64;
                self.at([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])])
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// The least distance to obstacles along the path between arc lengths `s0` and `s1`.
    fn along_path(&self, path: &PathState, s0: f64, s1: f64) -> f64 {
        let n = ((s1 - s0) / STEP_M).ceil().max(1.0) as usize;
        (0..=n)
            .map(|i| self.at(path.at(s0 + (s1 - s0) * i as f64 / n as f64).0))
            .fold(f64::INFINITY, f64::min)
    }
}

/// The carrot's distance ahead of arc length `s` (the robot's projection on `path`) for a
/// robot at `robot`: see the module's documentation.
#[allow(clippy::too_many_arguments)]
pub(crate) fn carrot_distance(
    field: &ClearanceField<'_>,
    path: &PathState,
    s: f64,
    robot: [f64; 2],
    lookahead_m: f64,
    min_lookahead_m: f64,
    comfort_m: f64,
    lethal_m: f64,
) -> f64 {
    let min_l = min_lookahead_m.min(lookahead_m);
    // In a tight stretch the carrot starts shorter: in proportion to the room the path has
    // beyond the lethal band (squared), from `min_l` at the band to `lookahead_m` at
    // `comfort_m`.
    let tight = field.along_path(path, s, s + lookahead_m);
    let room = ((tight - lethal_m) / (comfort_m - lethal_m).max(1e-3)).clamp(0.0, 1.0);
    let start = min_l + (lookahead_m - min_l) * room * room;
    let mut l = (start / SHORTEN_M).floor() * SHORTEN_M;
    if room >= 1.0 {
        l = lookahead_m;
    }
    while l > min_l + 1e-9 {
        let want = field.along_path(path, s, s + l).min(comfort_m) - SLACK_M;
        let (carrot, _) = path.at(s + l);
        if field.along_segment(robot, carrot) >= want {
            return l;
        }
        l -= SHORTEN_M;
    }
    min_l
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planning::{FREE, OCCUPIED};

    /// 6 x 4 m at 0.1 m with a wall block x 3-3.4, y 0-2 (its corner at (3, 2)).
    fn corner() -> (OccupancyGrid, Vec<f32>) {
        let mut g = OccupancyGrid::new(60, 40, 0.1, [0.0, 0.0], FREE).expect("grid");
        for x in 30..34 {
            for y in 0..20 {
                g.set(x, y, OCCUPIED);
            }
        }
        let c = crate::planning::Costmap::build(&g, &crate::planning::CostmapConfig::default());
        (g, c.clearances().to_vec())
    }

    #[test]
    fn the_carrot_is_short_round_a_close_corner_and_long_in_the_open() {
        let (g, c) = corner();
        let field = ClearanceField {
            grid: &g,
            clearances: &c,
        };
        // Interpolation between cell centres.
        assert!(
            (field.at([1.0, 2.0]) - 2.0).abs() < 0.06,
            "{}",
            field.at([1.0, 2.0])
        );
        // A path up along the block's side at 0.35 m from it, round its corner, and down.
        let path = PathState::new(vec![[2.65, 0.5], [2.65, 2.35], [3.75, 2.35], [3.75, 0.5]]);
        // Along the block's side, 0.1 m beyond the lethal band: a short carrot.
        let s = 0.2;
        let at = path.at(s).0;
        let l = carrot_distance(&field, &path, s, at, 0.6, 0.25, 0.7, 0.25);
        assert!((0.25..0.35).contains(&l), "{l}");
        // A path 0.5 m from the block's side: between.
        let wider = PathState::new(vec![[2.5, 0.5], [2.5, 1.5]]);
        let l = carrot_distance(&field, &wider, 0.2, wider.at(0.2).0, 0.6, 0.25, 0.7, 0.25);
        assert!(l > 0.3 && l < 0.6, "{l}");
        // In the open (a path far from everything) the carrot stays long even through a bend.
        let open = PathState::new(vec![[0.5, 3.5], [1.5, 3.5], [1.5, 2.5]]);
        let at = open.at(0.8).0;
        assert_eq!(
            carrot_distance(&field, &open, 0.8, at, 0.6, 0.25, 0.7, 0.25),
            0.6
        );
    }
}
