//! 8-connected A* on an [`OccupancyGrid`] with reusable, generation-stamped buffers.

use smart_default::SmartDefault;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

use hng_runtime::map::{OccupancyGrid, UNKNOWN};

/// √2, the cost of a diagonal move in cells.
pub const SQRT_2: f64 = std::f64::consts::SQRT_2;

/// Which cells the planner may enter.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct PlannerConfig {
    /// Cells with a value `>=` this are blocked. Default 50.
    #[default(50)]
    pub occupied_threshold: i8,
    /// Whether unknown cells (`-1`) may be entered. Default false.
    pub unknown_is_free: bool,
}

impl PlannerConfig {
    /// Whether a cell with this value may be entered.
    #[inline]
    pub fn passable(&self, v: i8) -> bool {
        if v == UNKNOWN {
            self.unknown_is_free
        } else {
            v >= 0 && v < self.occupied_threshold
        }
    }
}

/// Why no path was returned. Cells are `(x, y)` grid indices.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// The start lies outside the grid.
    #[error("start cell {cell:?} is outside the {width}x{height} map")]
    StartOutsideMap {
        /// Requested start cell.
        cell: (i64, i64),
        /// Grid width.
        width: u32,
        /// Grid height.
        height: u32,
    },
    /// The goal lies outside the grid.
    #[error("goal cell {cell:?} is outside the {width}x{height} map")]
    GoalOutsideMap {
        /// Requested goal cell.
        cell: (i64, i64),
        /// Grid width.
        width: u32,
        /// Grid height.
        height: u32,
    },
    /// The start cell is occupied (or unknown and unknown is not allowed).
    #[error("start cell {cell:?} is not traversable (value {value})")]
    StartOccupied {
        /// Start cell.
        cell: (i64, i64),
        /// Its grid value.
        value: i8,
    },
    /// The goal cell is occupied (or unknown and unknown is not allowed).
    #[error("goal cell {cell:?} is not traversable (value {value})")]
    GoalOccupied {
        /// Goal cell.
        cell: (i64, i64),
        /// Its grid value.
        value: i8,
    },
    /// Start and goal are in different connected components.
    #[error(
        "no path from {start:?} to {goal:?}: goal unreachable after expanding {expanded} cells"
    )]
    NoPath {
        /// Start cell.
        start: (i64, i64),
        /// Goal cell.
        goal: (i64, i64),
        /// Cells expanded before giving up.
        expanded: usize,
    },
}

/// A path as grid cells, start and goal included.
#[derive(Debug, Clone, PartialEq)]
pub struct GridPath {
    /// Cells from start to goal, each 8-adjacent to the next.
    pub cells: Vec<(u32, u32)>,
    /// Length in cells (orthogonal step 1, diagonal step √2).
    pub length_cells: f64,
    /// Cells expanded by the search.
    pub expanded: usize,
}

/// A path in map-frame coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Path {
    /// The exact grid path.
    pub grid: GridPath,
    /// Map-frame centres of `grid.cells`.
    pub points: Vec<[f64; 2]>,
    /// Length in metres (`grid.length_cells * resolution`).
    pub length_m: f64,
}

#[derive(Debug, Clone, Copy)]
struct Open {
    f: f64,
    g: f64,
    idx: u32,
}

impl PartialEq for Open {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Open {}
impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Open {
    /// Max-heap order: smallest f first; on equal f the larger g (deeper node,
    /// closer to the goal) first; then the smaller index, for determinism.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .f
            .total_cmp(&self.f)
            .then_with(|| self.g.total_cmp(&other.g))
            .then_with(|| other.idx.cmp(&self.idx))
    }
}

/// Octile distance between two cells, in cells.
#[inline]
pub fn octile(dx: i64, dy: i64) -> f64 {
    let (dx, dy) = (dx.unsigned_abs() as f64, dy.unsigned_abs() as f64);
    let (lo, hi) = if dx < dy { (dx, dy) } else { (dy, dx) };
    hi + (SQRT_2 - 1.0) * lo
}

/// A* planner that keeps its buffers between queries.
///
/// The open/closed state is generation-stamped: starting a query bumps a
/// counter instead of clearing `width * height` entries, so repeated queries
/// cost only the cells they touch.
#[derive(Debug, Default)]
pub struct GridPlanner {
    cfg: PlannerConfig,
    g: Vec<f64>,
    parent: Vec<u32>,
    /// Generation in which `g`/`parent` of the cell were written.
    seen: Vec<u32>,
    /// Generation in which the cell was closed.
    closed: Vec<u32>,
    generation: u32,
    heap: BinaryHeap<Open>,
}

/// The eight neighbours of a cell (dx, dy), the four sides first.
pub const NEIGHBOURS: [(i64, i64); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (1, -1),
    (-1, 1),
    (-1, -1),
];

impl GridPlanner {
    /// A planner with the given traversability rules.
    pub fn new(cfg: PlannerConfig) -> Self {
        Self {
            cfg,
            ..Default::default()
        }
    }

    /// The traversability rules.
    pub fn config(&self) -> &PlannerConfig {
        &self.cfg
    }

    fn begin(&mut self, n: usize) {
        if self.seen.len() != n {
            self.g = vec![0.0; n];
            self.parent = vec![0; n];
            self.seen = vec![0; n];
            self.closed = vec![0; n];
            self.generation = 0;
        }
        if self.generation == u32::MAX {
            self.seen.fill(0);
            self.closed.fill(0);
            self.generation = 0;
        }
        self.generation += 1;
        self.heap.clear();
    }

    /// Shortest 8-connected path between two cells, no corner cutting: a
    /// diagonal move is allowed only if both orthogonally adjacent cells are
    /// passable.
    pub fn plan_cells(
        &mut self,
        grid: &OccupancyGrid,
        start: (i64, i64),
        goal: (i64, i64),
    ) -> Result<GridPath, PlanError> {
        self.search(grid, None, start, goal)
    }

    /// Like [`Self::plan_cells`], but a move into cell `i` costs its length times
    /// `1 + extra[i]` (`extra` has one entry per cell, each `>= 0`: a costmap's inflation
    /// cost). The octile heuristic stays admissible, so the path has the least total cost;
    /// with every `extra` 0 it is the plain shortest path. `extra` of the wrong length is
    /// ignored (plain costs).
    pub fn plan_cells_weighted(
        &mut self,
        grid: &OccupancyGrid,
        extra: &[f32],
        start: (i64, i64),
        goal: (i64, i64),
    ) -> Result<GridPath, PlanError> {
        let extra = (extra.len() == grid.data().len()).then_some(extra);
        self.search(grid, extra, start, goal)
    }

    fn search(
        &mut self,
        grid: &OccupancyGrid,
        extra: Option<&[f32]>,
        start: (i64, i64),
        goal: (i64, i64),
    ) -> Result<GridPath, PlanError> {
        let (w, h) = (grid.width(), grid.height());
        let Some(si) = grid.index(start.0, start.1) else {
            return Err(PlanError::StartOutsideMap {
                cell: start,
                width: w,
                height: h,
            });
        };
        let Some(gi) = grid.index(goal.0, goal.1) else {
            return Err(PlanError::GoalOutsideMap {
                cell: goal,
                width: w,
                height: h,
            });
        };
        let data = grid.data();
        let cfg = self.cfg;
        if !cfg.passable(data[si]) {
            return Err(PlanError::StartOccupied {
                cell: start,
                value: data[si],
            });
        }
        if !cfg.passable(data[gi]) {
            return Err(PlanError::GoalOccupied {
                cell: goal,
                value: data[gi],
            });
        }
        self.begin(data.len());
        let gen_ = self.generation;
        let wi = w as i64;
        let hi = h as i64;
        let pass = |x: i64, y: i64| -> bool {
            x >= 0 && y >= 0 && x < wi && y < hi && cfg.passable(data[(y * wi + x) as usize])
        };
        self.g[si] = 0.0;
        self.parent[si] = si as u32;
        self.seen[si] = gen_;
        self.heap.push(Open {
            f: octile(goal.0 - start.0, goal.1 - start.1),
            g: 0.0,
            idx: si as u32,
        });
        let mut expanded = 0usize;
        while let Some(Open { g, idx, .. }) = self.heap.pop() {
            let i = idx as usize;
            if self.closed[i] == gen_ || g > self.g[i] {
                continue; // stale heap entry
            }
            self.closed[i] = gen_;
            expanded += 1;
            if i == gi {
                return Ok(self.reconstruct(si, gi, w, expanded));
            }
            let x = (i % w as usize) as i64;
            let y = (i / w as usize) as i64;
            for &(dx, dy) in &NEIGHBOURS {
                let (nx, ny) = (x + dx, y + dy);
                if !pass(nx, ny) {
                    continue;
                }
                let step = if dx != 0 && dy != 0 {
                    if !pass(x + dx, y) || !pass(x, y + dy) {
                        continue; // no corner cutting
                    }
                    SQRT_2
                } else {
                    1.0
                };
                let ni = (ny * wi + nx) as usize;
                if self.closed[ni] == gen_ {
                    continue;
                }
                let ng = match extra {
                    None => g + step,
                    Some(e) => g + step * (1.0 + f64::from(e[ni].max(0.0))),
                };
                if self.seen[ni] != gen_ || ng < self.g[ni] {
                    self.seen[ni] = gen_;
                    self.g[ni] = ng;
                    self.parent[ni] = idx;
                    self.heap.push(Open {
                        f: ng + octile(goal.0 - nx, goal.1 - ny),
                        g: ng,
                        idx: ni as u32,
                    });
                }
            }
        }
        Err(PlanError::NoPath {
            start,
            goal,
            expanded,
        })
    }

    fn reconstruct(&self, si: usize, gi: usize, w: u32, expanded: usize) -> GridPath {
        let w = w as usize;
        let mut cells = Vec::new();
        let mut i = gi;
        loop {
            cells.push(((i % w) as u32, (i / w) as u32));
            if i == si {
                break;
            }
            i = self.parent[i] as usize;
        }
        cells.reverse();
        let length_cells = path_length_cells(&cells);
        GridPath {
            cells,
            length_cells,
            expanded,
        }
    }

    /// Shortest path between two map-frame points (see [`Self::plan_cells`]).
    pub fn plan(
        &mut self,
        grid: &OccupancyGrid,
        start: [f64; 2],
        goal: [f64; 2],
    ) -> Result<Path, PlanError> {
        let s = grid.world_to_cell(start[0], start[1]);
        let g = grid.world_to_cell(goal[0], goal[1]);
        let gp = self.plan_cells(grid, s, g)?;
        let points = gp
            .cells
            .iter()
            .map(|&(x, y)| grid.cell_to_world(x as i64, y as i64))
            .collect();
        let length_m = gp.length_cells * grid.resolution();
        Ok(Path {
            grid: gp,
            points,
            length_m,
        })
    }
}

/// Length of a cell path in cells, counting each step as 1 or √2.
/// Both counts are summed separately so the result is exact to rounding of one multiply.
pub fn path_length_cells(cells: &[(u32, u32)]) -> f64 {
    let mut straight = 0u64;
    let mut diagonal = 0u64;
    for w in cells.windows(2) {
        let dx = w[0].0 != w[1].0;
        let dy = w[0].1 != w[1].1;
        if dx && dy {
            diagonal += 1;
        } else if dx || dy {
            straight += 1;
        }
    }
    straight as f64 + diagonal as f64 * SQRT_2
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::map::{FREE, OCCUPIED};

    fn grid_from(rows: &[&str]) -> OccupancyGrid {
        // rows[0] is the top row (largest y).
        let h = rows.len();
        let w = rows[0].len();
        let mut g = OccupancyGrid::new(w as u32, h as u32, 1.0, [0.0, 0.0], FREE).expect("grid");
        for (r, row) in rows.iter().enumerate() {
            for (x, c) in row.chars().enumerate() {
                if c == '#' {
                    g.set(x as i64, (h - 1 - r) as i64, OCCUPIED);
                }
            }
        }
        g
    }

    #[test]
    fn straight_and_diagonal_lengths() {
        let g = grid_from(&["....", "....", "....", "...."]);
        let mut p = GridPlanner::new(PlannerConfig::default());
        let path = p.plan_cells(&g, (0, 0), (3, 3)).expect("path");
        assert!((path.length_cells - 3.0 * SQRT_2).abs() < 1e-12);
        let path = p.plan_cells(&g, (0, 0), (3, 1)).expect("path");
        assert!((path.length_cells - (2.0 + SQRT_2)).abs() < 1e-12);
        assert_eq!(path.cells.first(), Some(&(0, 0)));
        assert_eq!(path.cells.last(), Some(&(3, 1)));
    }

    #[test]
    fn no_corner_cutting() {
        // Diagonal (0,0)->(1,1) is blocked because (1,0) is occupied.
        let g = grid_from(&["...", "...", ".#."]);
        let mut p = GridPlanner::new(PlannerConfig::default());
        let path = p.plan_cells(&g, (0, 0), (2, 0)).expect("path");
        // Every diagonal touching (1,0) is forbidden, so the shortest legal path
        // is (0,0)->(0,1)->(1,1)->(2,1)->(2,0), length 4 (2+√2 with cutting).
        assert!((path.length_cells - 4.0).abs() < 1e-12, "{path:?}");
        for w in path.cells.windows(2) {
            let (a, b) = (w[0], w[1]);
            if a.0 != b.0 && a.1 != b.1 {
                assert!(g.get(b.0 as i64, a.1 as i64) != Some(OCCUPIED));
                assert!(g.get(a.0 as i64, b.1 as i64) != Some(OCCUPIED));
            }
        }
    }

    #[test]
    fn typed_errors() {
        let g = grid_from(&["..#", ".##", "#.."]);
        let mut p = GridPlanner::new(PlannerConfig::default());
        assert!(matches!(
            p.plan_cells(&g, (0, 0), (1, 0)),
            Err(PlanError::StartOccupied { .. })
        ));
        assert!(matches!(
            p.plan_cells(&g, (1, 0), (2, 2)),
            Err(PlanError::GoalOccupied { .. })
        ));
        assert!(matches!(
            p.plan_cells(&g, (1, 0), (3, 0)),
            Err(PlanError::GoalOutsideMap { .. })
        ));
        assert!(matches!(
            p.plan_cells(&g, (-1, 0), (1, 0)),
            Err(PlanError::StartOutsideMap { .. })
        ));
        // (1,0) -> (0,2): blocked by the wall, diagonal (0,1)->(1,0) cut by corners.
        assert!(matches!(
            p.plan_cells(&g, (1, 0), (0, 2)),
            Err(PlanError::NoPath { .. })
        ));
        // Unknown cells blocked by default, allowed on request.
        let mut u = OccupancyGrid::new(3, 1, 1.0, [0.0, 0.0], FREE).expect("grid");
        u.set(1, 0, UNKNOWN);
        assert!(matches!(
            p.plan_cells(&u, (0, 0), (2, 0)),
            Err(PlanError::NoPath { .. })
        ));
        let mut q = GridPlanner::new(PlannerConfig {
            unknown_is_free: true,
            ..Default::default()
        });
        assert!(q.plan_cells(&u, (0, 0), (2, 0)).is_ok());
    }

    #[test]
    fn world_coordinates_and_buffer_reuse() {
        let g = OccupancyGrid::new(10, 10, 0.5, [-2.5, -2.5], FREE).expect("grid");
        let mut p = GridPlanner::new(PlannerConfig::default());
        for _ in 0..3 {
            let path = p.plan(&g, [-2.25, -2.25], [2.25, -2.25]).expect("path");
            assert!((path.length_m - 4.5).abs() < 1e-12);
            assert_eq!(path.points[0], [-2.25, -2.25]);
            assert_eq!(path.points.last(), Some(&[2.25, -2.25]));
        }
        // A different grid size reallocates.
        let g2 = OccupancyGrid::new(3, 3, 1.0, [0.0, 0.0], FREE).expect("grid");
        assert!(p.plan_cells(&g2, (0, 0), (2, 2)).is_ok());
    }
}
