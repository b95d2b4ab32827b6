//! Path simplification: greedy line-of-sight shortcutting of a grid path.

use super::astar::{GridPath, PlannerConfig, SQRT_2};
use hng_runtime::map::OccupancyGrid;

/// Whether the straight segment between the centres of cells `a` and `b`
/// crosses only passable cells. Conservative: every cell the segment touches
/// is checked, and where the segment passes exactly through a cell corner both
/// cells beside the corner must be passable (the same no-corner-cutting rule as
/// the planner).
pub fn line_of_sight(
    grid: &OccupancyGrid,
    cfg: &PlannerConfig,
    a: (i64, i64),
    b: (i64, i64),
) -> bool {
    line_of_sight_by(a, b, |x, y| grid.get(x, y).is_some_and(|v| cfg.passable(v)))
}

/// [`line_of_sight`] with any passability test `pass(x, y)`.
pub fn line_of_sight_by(a: (i64, i64), b: (i64, i64), pass: impl Fn(i64, i64) -> bool) -> bool {
    let (mut x, mut y) = a;
    if !pass(x, y) {
        return false;
    }
    let dx = b.0 - a.0;
    let dy = b.1 - a.1;
    let (nx, ny) = (dx.abs(), dy.abs());
    let sx = dx.signum();
    let sy = dy.signum();
    // Integer supercover traversal from centre to centre: compare the
    // crossing parameters (2*ix+1)/(2*nx) and (2*iy+1)/(2*ny) exactly.
    let (mut ix, mut iy) = (0i64, 0i64);
    while ix < nx || iy < ny {
        let cmp = (2 * ix + 1) * ny - (2 * iy + 1) * nx;
        if cmp == 0 {
            // Passes exactly through a corner: both side cells must be free.
            if !pass(x + sx, y) || !pass(x, y + sy) {
                return false;
            }
            x += sx;
            y += sy;
            ix += 1;
            iy += 1;
        } else if cmp < 0 {
            x += sx;
            ix += 1;
        } else {
            y += sy;
            iy += 1;
        }
        if !pass(x, y) {
            return false;
        }
    }
    true
}

/// Reduces a grid path to waypoints (map-frame cell centres) such that each
/// consecutive pair has [`line_of_sight`]. The first and last points are the
/// path's start and goal. The raw path in `path` is left untouched.
pub fn simplify(grid: &OccupancyGrid, cfg: &PlannerConfig, path: &GridPath) -> Vec<[f64; 2]> {
    let cells = &path.cells;
    let mut out = Vec::new();
    let Some(&first) = cells.first() else {
        return out;
    };
    let c = |p: (u32, u32)| (p.0 as i64, p.1 as i64);
    out.push(grid.cell_to_world(first.0 as i64, first.1 as i64));
    let mut anchor = 0usize;
    while anchor + 1 < cells.len() {
        // Walk forward while the anchor still sees the path cell; a path
        // neighbour always qualifies. Linear in the path length times the
        // segment length (scanning back from the goal would be quadratic).
        let mut next = anchor + 1;
        for j in anchor + 2..cells.len() {
            if !line_of_sight(grid, cfg, c(cells[anchor]), c(cells[j])) {
                break;
            }
            next = j;
        }
        let p = cells[next];
        out.push(grid.cell_to_world(p.0 as i64, p.1 as i64));
        anchor = next;
    }
    out
}

/// [`simplify`] on a costmap: a shortcut from one kept point to a later path cell is taken
/// only if
/// - it costs no more than the stretch of path it replaces (a segment's cost: its length
///   times one plus the mean inflation cost `cost` of the cells it crosses; the path's: each
///   step's length times one plus its cell's cost, as the planner counts it), and
/// - it comes no nearer an obstacle than that stretch's cells do, unless it stays `open_m`
///   from every obstacle: the segment's clearance is bounded below by each crossed cell's
///   `clearance` (m, its centre's distance to the nearest obstacle) less the segment's distance
///   from that centre.
///
/// A shortcut along a wall is dearer than the planned path through the middle and is not
/// taken; a chord across a bend round a convex corner, which would pass nearer the corner than
/// the bend (a long chord's mean cost dilutes the corner's), is not taken either; any-angle
/// shortcuts through open space are. Without a cost and a clearance per cell: [`simplify`].
pub fn simplify_with_cost(
    grid: &OccupancyGrid,
    cfg: &PlannerConfig,
    cost: &[f32],
    clearance: &[f32],
    open_m: f64,
    path: &GridPath,
) -> Vec<[f64; 2]> {
    let n = grid.data().len();
    if cost.len() != n || clearance.len() != n {
        return simplify(grid, cfg, path);
    }
    let cells = &path.cells;
    let mut out = Vec::new();
    let Some(&first) = cells.first() else {
        return out;
    };
    let w = grid.width() as i64;
    let res = grid.resolution();
    let cost_at = |x: i64, y: i64| f64::from(cost[(y * w + x) as usize].max(0.0));
    let clear_at = |x: i64, y: i64| f64::from(clearance[(y * w + x) as usize]);
    let c = |p: (u32, u32)| (p.0 as i64, p.1 as i64);
    // prefix[i]: the path's cost from its start to cell i.
    let mut prefix = vec![0.0f64; cells.len()];
    for i in 1..cells.len() {
        let (a, b) = (c(cells[i - 1]), c(cells[i]));
        let step = if a.0 != b.0 && a.1 != b.1 {
            SQRT_2
        } else {
            1.0
        };
        prefix[i] = prefix[i - 1] + step * (1.0 + cost_at(b.0, b.1));
    }
    out.push(grid.cell_to_world(first.0 as i64, first.1 as i64));
    let mut anchor = 0usize;
    while anchor + 1 < cells.len() {
        let a = c(cells[anchor]);
        let mut next = anchor + 1;
        // The nearest approach of the path's cells from the anchor to cell j.
        let mut stretch_min = clear_at(a.0, a.1);
        for j in anchor + 1..cells.len() {
            let b = c(cells[j]);
            stretch_min = stretch_min.min(clear_at(b.0, b.1));
            if j == anchor + 1 {
                continue;
            }
            let (dx, dy) = ((b.0 - a.0) as f64, (b.1 - a.1) as f64);
            let len = dx.hypot(dy);
            let sum = std::cell::Cell::new(0.0f64);
            let count = std::cell::Cell::new(0usize);
            let nearest = std::cell::Cell::new(f64::INFINITY);
            let visible = line_of_sight_by(a, b, |x, y| {
                let ok = grid.get(x, y).is_some_and(|v| cfg.passable(v));
                if ok && (x, y) != a {
                    sum.set(sum.get() + cost_at(x, y));
                    count.set(count.get() + 1);
                    // The cell centre's distance from the segment's line, m.
                    let off = (dx * (y - a.1) as f64 - dy * (x - a.0) as f64).abs() / len * res;
                    nearest.set(nearest.get().min(clear_at(x, y) - off));
                }
                ok
            });
            if !visible {
                break;
            }
            let mean = sum.get() / count.get().max(1) as f64;
            let cheaper = len * (1.0 + mean) <= (prefix[j] - prefix[anchor]) * (1.0 + 1e-9) + 1e-9;
            let no_nearer = nearest.get() >= stretch_min.min(open_m) - 1e-6;
            if cheaper && no_nearer {
                next = j;
            }
        }
        let p = cells[next];
        out.push(grid.cell_to_world(p.0 as i64, p.1 as i64));
        anchor = next;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planning::astar::GridPlanner;
    use hng_runtime::map::{FREE, OCCUPIED};

    #[test]
    fn open_field_collapses_to_two_points() {
        let g = OccupancyGrid::new(20, 20, 1.0, [0.0, 0.0], FREE).expect("grid");
        let cfg = PlannerConfig::default();
        let mut p = GridPlanner::new(cfg);
        let path = p.plan_cells(&g, (0, 0), (19, 7)).expect("path");
        let wp = simplify(&g, &cfg, &path);
        assert_eq!(wp, vec![[0.5, 0.5], [19.5, 7.5]]);
    }

    #[test]
    fn waypoints_keep_clear_of_walls() {
        let mut g = OccupancyGrid::new(20, 20, 1.0, [0.0, 0.0], FREE).expect("grid");
        for y in 0..15 {
            g.set(10, y, OCCUPIED);
        }
        let cfg = PlannerConfig::default();
        let mut p = GridPlanner::new(cfg);
        let path = p.plan_cells(&g, (2, 2), (18, 2)).expect("path");
        let wp = simplify(&g, &cfg, &path);
        assert!(wp.len() >= 3, "{wp:?}");
        for w in wp.windows(2) {
            let a = g.world_to_cell(w[0][0], w[0][1]);
            let b = g.world_to_cell(w[1][0], w[1][1]);
            assert!(line_of_sight(&g, &cfg, a, b));
        }
    }

    #[test]
    fn corner_touching_segment_is_rejected() {
        let mut g = OccupancyGrid::new(3, 3, 1.0, [0.0, 0.0], FREE).expect("grid");
        g.set(1, 0, OCCUPIED);
        let cfg = PlannerConfig::default();
        assert!(!line_of_sight(&g, &cfg, (0, 0), (1, 1)));
        assert!(line_of_sight(&g, &cfg, (0, 1), (2, 2)));
        assert!(!line_of_sight(&g, &cfg, (0, 0), (2, 0)));
    }
}
