//! A planning costmap: lethal cells where the robot's footprint would touch an obstacle, and
//! an inflation cost that falls off with the distance to the nearest obstacle (Nav2's
//! inflation layer), so that least-cost paths keep to the middle of corridors where the
//! corridor leaves room, and pass narrow places only where they must.
//!
//! Built from an occupancy grid: a coarse grid (cells over [`CostmapConfig::max_cell_m`],
//! e.g. a MovingAI map at 1 m per cell) is first resampled into finer cells, each fine cell
//! taking its coarse cell's value, so the footprint and the cost fall-off are resolved where
//! a 1 m cell would make them all-or-nothing. Distances are from each cell centre to the
//! nearest obstacle cell's edge (the exact Euclidean distance transform to its centre, less
//! half a cell).

use hng_runtime::map::{FREE, OCCUPIED, OccupancyGrid, UNKNOWN};
use smart_default::SmartDefault;

use super::inflate::squared_distance_transform;

/// How the costmap is built.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct CostmapConfig {
    /// Cells whose centre is closer than this to an obstacle are lethal (the footprint radius
    /// plus its margin), m.
    #[default(crate::footprint::footprint_radius())]
    pub lethal_m: f64,
    /// Distance at which the inflation cost has fallen to 0, m.
    #[default(1.0)]
    pub inflation_m: f64,
    /// Cost just outside the lethal band: a move there costs `1 + weight` times its length.
    #[default(3.0)]
    pub weight: f64,
    /// Decay rate of the cost with distance, 1/m (`exp(-decay·(d − lethal))`).
    #[default(3.0)]
    pub decay: f64,
    /// Grids with coarser cells are resampled to cells no larger than this, m.
    #[default(0.1)]
    pub max_cell_m: f64,
    /// Cells with a value `>=` this are obstacles.
    #[default(50)]
    pub occupied_threshold: i8,
}

/// The costmap: `grid` has every lethal cell [`OCCUPIED`] (so the planner's plain
/// passability rules apply to it), `cost` the inflation cost of each cell (0 far from
/// obstacles, `weight` at the lethal band's edge), `clearance` each cell's distance to the
/// nearest obstacle, m.
#[derive(Debug, Clone)]
pub struct Costmap {
    grid: OccupancyGrid,
    cost: Vec<f32>,
    clearance: Vec<f32>,
}

/// The inflation cost at distance `d` from an obstacle (`d` >= lethal): `weight` at the
/// lethal band, decaying exponentially, shifted and scaled to reach exactly 0 at
/// `inflation_m` (no step in the cost there).
pub fn inflation_cost(d: f64, cfg: &CostmapConfig) -> f64 {
    if d >= cfg.inflation_m {
        return 0.0;
    }
    let span = (cfg.inflation_m - cfg.lethal_m).max(1e-9);
    let tail = (-cfg.decay * span).exp();
    let x = (d - cfg.lethal_m).clamp(0.0, span);
    cfg.weight * ((-cfg.decay * x).exp() - tail) / (1.0 - tail).max(1e-9)
}

impl Costmap {
    /// Builds the costmap of `grid`. Unknown cells are not obstacles (they keep their value).
    pub fn build(grid: &OccupancyGrid, cfg: &CostmapConfig) -> Costmap {
        let fine = resample(grid, cfg.max_cell_m);
        let w = fine.width() as usize;
        let h = fine.height() as usize;
        let res = fine.resolution();
        let thr = cfg.occupied_threshold;
        let data = fine.data();
        let d2 = squared_distance_transform(w, h, |i| data[i] >= thr);
        let mut cost = vec![0.0f32; w * h];
        let mut clearance = vec![f32::INFINITY; w * h];
        let mut out = fine.clone();
        for (i, &dd) in d2.iter().enumerate() {
            if data[i] >= thr {
                clearance[i] = 0.0;
                continue;
            }
            let d = if dd.is_finite() {
                (dd.sqrt() - 0.5) * res
            } else {
                f64::INFINITY
            };
            clearance[i] = d as f32;
            if d < cfg.lethal_m {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                out.set(x, y, OCCUPIED);
            } else {
                cost[i] = inflation_cost(d, cfg) as f32;
            }
        }
        Costmap {
            grid: out,
            cost,
            clearance,
        }
    }

    /// The grid with lethal cells occupied.
    pub fn grid(&self) -> &OccupancyGrid {
        &self.grid
    }

    /// Inflation cost per cell (row-major, as the grid).
    pub fn costs(&self) -> &[f32] {
        &self.cost
    }

    /// Distance of each cell's centre to the nearest obstacle, m (row-major, as the grid).
    pub fn clearances(&self) -> &[f32] {
        &self.clearance
    }

    /// Distance from the centre of cell `(x, y)` to the nearest obstacle, m (0 in an
    /// obstacle, infinite with none in the map, `None` outside the map).
    pub fn clearance(&self, x: i64, y: i64) -> Option<f64> {
        self.grid.index(x, y).map(|i| f64::from(self.clearance[i]))
    }

    /// Whether the map had no unknown cell.
    pub fn is_complete(&self) -> bool {
        !self.grid.data().contains(&UNKNOWN)
    }
}

/// `grid` with cells of at most `max_cell_m` (each coarse cell split into `k x k` cells of
/// its value); the grid itself when it is fine enough.
pub fn resample(grid: &OccupancyGrid, max_cell_m: f64) -> OccupancyGrid {
    let res = grid.resolution();
    if max_cell_m.is_nan() || max_cell_m <= 0.0 || res <= max_cell_m * 1.0001 {
        return grid.clone();
    }
    let k = (res / max_cell_m - 1e-9).ceil().max(1.0) as usize;
    let (w, h) = (grid.width() as usize, grid.height() as usize);
    let (fw, fh) = (w * k, h * k);
    let Ok(mut fine) =
        OccupancyGrid::new(fw as u32, fh as u32, res / k as f64, grid.origin(), FREE)
    else {
        return grid.clone(); // too large: plan on the coarse grid
    };
    let data = grid.data();
    for fy in 0..fh {
        for fx in 0..fw {
            let v = data[(fy / k) * w + fx / k];
            if v != FREE {
                fine.set(fx as i64, fy as i64, v);
            }
        }
    }
    fine.with_origin_yaw(grid.origin_yaw())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A corridor 2 m wide (y 0..2) along x at 0.1 m, walls one cell thick outside it.
    fn corridor() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(60, 22, 0.1, [0.0, -0.1], FREE).unwrap();
        for x in 0..60 {
            g.set(x, 0, OCCUPIED);
            g.set(x, 21, OCCUPIED);
        }
        g
    }

    #[test]
    fn cost_falls_with_distance_and_lethal_band_matches_the_footprint() {
        let cfg = CostmapConfig::default();
        let c = Costmap::build(&corridor(), &cfg);
        // Cell row 1 is 0.05 m from the wall's edge: lethal; row 10 is in the middle.
        assert_eq!(c.grid().get(10, 1), Some(OCCUPIED));
        let lethal_rows = (1..11)
            .filter(|&y| c.grid().get(10, y) == Some(OCCUPIED))
            .count();
        // Rows 1, 2 (0.05, 0.15 m), row 3 at 0.25 m is not lethal (lethal < 0.25).
        assert_eq!(lethal_rows, 2);
        let costs: Vec<f32> = (3..11).map(|y| c.costs()[y * 60 + 10]).collect();
        assert!(costs.windows(2).all(|w| w[1] < w[0]), "{costs:?}");
        let mid = c.clearance(10, 10).unwrap();
        assert!((mid - 0.95).abs() < 1e-6, "{mid}");
        assert!(c.costs()[10 * 60 + 10] > 0.0 && c.costs()[10 * 60 + 10] < 0.1);
        assert!((inflation_cost(cfg.lethal_m, &cfg) - cfg.weight).abs() < 1e-9);
        assert_eq!(inflation_cost(cfg.inflation_m, &cfg), 0.0);
    }

    #[test]
    fn least_cost_paths_keep_to_the_middle_and_plain_costs_stay_shortest() {
        use crate::planning::{GridPlanner, PlannerConfig, simplify_with_cost};
        let g = corridor();
        let c = Costmap::build(&g, &CostmapConfig::default());
        let mut p = GridPlanner::new(PlannerConfig::default());
        // Both ends 0.4 m from the lower wall, 5 m apart.
        let (s, e) = ((5, 5), (55, 5));
        let plain = p.plan_cells(c.grid(), s, e).unwrap();
        assert!(
            (plain.length_cells - 50.0).abs() < 1e-9,
            "straight along the wall"
        );
        let costed = p.plan_cells_weighted(c.grid(), c.costs(), s, e).unwrap();
        let widest = costed
            .cells
            .iter()
            .map(|&(x, y)| c.clearance(x.into(), y.into()).unwrap())
            .fold(0.0, f64::max);
        assert!(widest > 0.75, "moves away from the wall: {widest}");
        let pts = simplify_with_cost(
            c.grid(),
            &PlannerConfig::default(),
            c.costs(),
            c.clearances(),
            1.0,
            &costed,
        );
        assert!(pts.len() >= 3, "keeps its bend: {pts:?}");
        // All-zero costs: the plain optimum exactly.
        let zero = vec![0.0f32; c.costs().len()];
        let same = p.plan_cells_weighted(c.grid(), &zero, s, e).unwrap();
        assert_eq!(same.length_cells, plain.length_cells);
    }

    #[test]
    fn coarse_grids_are_resampled() {
        let mut g = OccupancyGrid::new(3, 2, 1.0, [1.0, 2.0], FREE).unwrap();
        g.set(1, 1, OCCUPIED);
        let f = resample(&g, 0.1);
        assert_eq!((f.width(), f.height()), (30, 20));
        assert!((f.resolution() - 0.1).abs() < 1e-12);
        assert_eq!(f.origin(), [1.0, 2.0]);
        assert_eq!(f.get(15, 15), Some(OCCUPIED));
        assert_eq!(f.get(9, 15), Some(FREE));
        assert_eq!(f.get(15, 9), Some(FREE));
        // The same world point in the same kind of cell.
        let (x, y) = f.world_to_cell(2.5, 3.5);
        assert_eq!(f.get(x, y), Some(OCCUPIED));
        assert_eq!(
            resample(&corridor(), 0.1).width(),
            60,
            "fine grids untouched"
        );
    }
}
