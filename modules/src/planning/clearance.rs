//! The clearance of a path: how close a polyline comes to an obstacle cell of a grid, for
//! judging a planned path apart from how the robot then drove it (`hng eval nav`).

use hng_runtime::map::OccupancyGrid;

/// Smallest distance from any point of the polyline `points` (map frame, m) to the edge of an
/// obstacle cell of `grid` (a cell whose value is `>= occupied_threshold`), m. Points are
/// sampled along each segment at most `min(resolution / 4, 0.02 m)` apart, each measured
/// exactly to the nearby cells' squares, so the result is within 1 cm of the true minimum.
/// `f64::INFINITY` when no obstacle is within `horizon_m` of the path (or the path is empty).
pub fn path_clearance(
    grid: &OccupancyGrid,
    points: &[[f64; 2]],
    occupied_threshold: i8,
    horizon_m: f64,
) -> f64 {
    let res = grid.resolution();
    let (w, h) = (i64::from(grid.width()), i64::from(grid.height()));
    let o = grid.origin();
    let (s, c) = grid.origin_yaw().sin_cos();
    // A map-frame point in the grid's own frame (metres from its origin, axes along its rows).
    let local = |p: [f64; 2]| {
        let (dx, dy) = (p[0] - o[0], p[1] - o[1]);
        (c * dx + s * dy, -s * dx + c * dy)
    };
    let data = grid.data();
    let mut best = f64::INFINITY;
    let mut at = |u: f64, v: f64| {
        let reach = best.min(horizon_m);
        let r = (reach / res).ceil() as i64 + 1;
        let (cx, cy) = ((u / res).floor() as i64, (v / res).floor() as i64);
        for y in (cy - r).max(0)..=(cy + r).min(h - 1) {
            // Distance along y from the point to the row's band [y·res, (y+1)·res].
            let y0 = y as f64 * res;
            let dy = (y0 - v).max(v - (y0 + res)).max(0.0);
            if dy >= best {
                continue;
            }
            for x in (cx - r).max(0)..=(cx + r).min(w - 1) {
                if data[(y * w + x) as usize] < occupied_threshold {
                    continue;
                }
                let x0 = x as f64 * res;
                let dx = (x0 - u).max(u - (x0 + res)).max(0.0);
                best = best.min(dx.hypot(dy));
            }
        }
    };
    let step = (res / 4.0).min(0.02);
    match points {
        [] => return f64::INFINITY,
        [p] => {
            let (u, v) = local(*p);
            at(u, v);
        }
        _ => {
            for seg in points.windows(2) {
                let (a, b) = (local(seg[0]), local(seg[1]));
                let len = (b.0 - a.0).hypot(b.1 - a.1);
                let n = (len / step).ceil().max(1.0) as usize;
                for i in 0..=n {
                    let t = i as f64 / n as f64;
                    at(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                }
            }
        }
    }
    if best <= horizon_m {
        best
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planning_module::{PlanningCore, PlanningParams};
    use hng_runtime::map::{FREE, OCCUPIED};
    use hng_runtime::msg::{Goal, Pose2D};

    #[test]
    fn clearance_of_segments_is_measured_to_the_cells_edges() {
        // One obstacle cell [1, 2] x [1, 2] at 1 m per cell.
        let mut g = OccupancyGrid::new(4, 4, 1.0, [0.0, 0.0], FREE).unwrap();
        g.set(1, 1, OCCUPIED);
        // Parallel to its top edge, 0.3 m above.
        let d = path_clearance(&g, &[[0.0, 2.3], [3.0, 2.3]], 50, 5.0);
        assert!((d - 0.3).abs() < 1e-9, "{d}");
        // Diagonal past its corner (2, 2): the corner is 0.5·√2 from the line x + y = 5.
        let d = path_clearance(&g, &[[1.5, 3.5], [3.5, 1.5]], 50, 5.0);
        assert!((d - 0.5 * 2f64.sqrt()).abs() < 0.01, "{d}");
        // Beyond the horizon: none.
        assert!(path_clearance(&g, &[[3.9, 3.9]], 50, 0.5).is_infinite());
        assert!(path_clearance(&g, &[], 50, 5.0).is_infinite());
    }

    /// A 3 m x 3 m block at 1 m per cell (`T` cells of a MovingAI map), x 3..6, y 3..6, in a
    /// 12 m x 12 m room with walls one cell thick.
    fn block_world() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(12, 12, 1.0, [0.0, 0.0], FREE).unwrap();
        for i in 0..12 {
            for (x, y) in [(i, 0), (i, 11), (0, i), (11, i)] {
                g.set(x, y, OCCUPIED);
            }
        }
        for x in 3..6 {
            for y in 3..6 {
                g.set(x, y, OCCUPIED);
            }
        }
        g
    }

    #[test]
    fn the_planned_path_keeps_its_distance_from_a_convex_corner_where_the_room_allows() {
        let g = block_world();
        let mut core = PlanningCore::new(PlanningParams::default());
        core.set_map(&g);
        for (id, start, goal) in [
            // Diagonally past the block's lower right corner (6, 3): the straight line runs
            // into the block, the shortest way turns round that corner by about 40°.
            (1, [2.5, 1.5], [9.5, 10.5]),
            // Round two corners, (3, 6) and (6, 6), turning 90° at each.
            (2, [2.0, 4.5], [7.0, 4.5]),
        ] {
            core.set_goal(Goal {
                id,
                pose: Pose2D::new(goal[0], goal[1], 0.0),
                tolerance_m: 0.1,
                ..Goal::default()
            });
            let step = core.update(&Pose2D::new(start[0], start[1], 0.0));
            assert!(step.replanned && core.has_path(), "{step:?}");
            let pts = core.path_points().to_vec();
            // The robot's gap is the centre's distance less its radius. The lethal band alone
            // allows 0.05 m; start and goal have 0.3 m or more, the room far more elsewhere.
            let gap = path_clearance(&g, &pts, 50, 5.0) - crate::footprint::ROBOT_RADIUS_M;
            assert!(
                gap >= 0.3 - 1e-9,
                "problem {id}: the path keeps the room the map leaves (0.3 m): {gap:.3} m, \
                 path {pts:?}"
            );
            let len = core.path_length();
            eprintln!(
                "problem {id}: gap {gap:.3} m, length {len:.2} m, {} points",
                pts.len()
            );
        }
    }

    /// Arena problem 101 (MovingAI `arena.map`, 1 m per cell): the shortest way passes the
    /// convex corner (3, 34) of a block diagonally, with 5 m free beyond it. Before the
    /// smoother kept to the planned cells' clearance, the plan's chord passed that corner at a
    /// 0.12-0.14 m gap (and the robot at 0.162 m).
    #[test]
    fn the_plan_of_arena_problem_101_keeps_its_distance_from_the_corner_it_passes() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/movingai");
        let m = crate::planning::movingai::read_map(&dir.join("arena.map")).expect("map");
        let scen = crate::planning::movingai::read_scen(&dir.join("arena.map.scen")).expect("scen");
        let g = m.to_occupancy_grid(1.0).expect("grid");
        let p = &scen[100];
        let at = |cell: (i64, i64)| {
            let (x, y) = m.to_grid_cell(cell.0, cell.1);
            g.cell_to_world(x, y)
        };
        let (start, goal) = (at(p.start), at(p.goal));
        assert_eq!(start, [1.5, 38.5], "problem 101's start");
        let mut core = PlanningCore::new(PlanningParams::default());
        core.set_map(&g);
        core.set_goal(Goal {
            id: 101,
            pose: Pose2D::new(goal[0], goal[1], 0.0),
            tolerance_m: 0.3,
            ..Goal::default()
        });
        core.update(&Pose2D::new(start[0], start[1], 0.0));
        let pts = core.path_points().to_vec();
        // The start is 0.5 m from the wall beside it (a 0.3 m gap): the map leaves 0.3 m.
        let gap = path_clearance(&g, &pts, 50, 5.0) - crate::footprint::ROBOT_RADIUS_M;
        assert!(gap >= 0.3 - 1e-9, "gap {gap:.3} m, path {pts:?}");
        let near_corner = path_clearance(&g, &pts[1..], 50, 5.0) - crate::footprint::ROBOT_RADIUS_M;
        assert!(
            near_corner >= 0.3,
            "past the corner: {near_corner:.3} m, path {pts:?}"
        );
        // Still about the octile optimum (any angle is shorter than 8-connected moves).
        let ratio = core.path_length() / p.optimal_length;
        assert!(
            ratio < 1.0,
            "path {:.2} m, optimum {:.2} m",
            core.path_length(),
            p.optimal_length
        );
        eprintln!("gap {gap:.3} m, past the corner {near_corner:.3} m, ratio {ratio:.3}");
    }
}
