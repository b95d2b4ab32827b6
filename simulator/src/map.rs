//! The simulator's side of occupancy maps: the ground-truth grid of a world, and the boxes
//! (colliders) of a map's occupied cells. The grid itself and the map_server file format live in
//! the runtime ([`hng_runtime::map`]), shared with the modules.

pub use hng_runtime::map::{FREE, OCCUPIED, OccupancyGrid, UNKNOWN};

use crate::error::{Result, SimError};
use crate::world::{BoxObstacle, World};

/// Rasterises the obstacles of `world` at `resolution` metres per cell: a cell is occupied
/// when any obstacle overlaps it, free otherwise. The grid covers the obstacles plus a
/// two-cell margin; its origin has yaw 0.
pub fn grid_from_world(world: &World, resolution: f64) -> Result<OccupancyGrid> {
    if !(resolution.is_finite() && resolution > 0.0) {
        return Err(SimError::invalid(
            "resolution",
            format!("must be finite and > 0, got {resolution}"),
        ));
    }
    let boxes = world.obstacle_boxes();
    let corners: Vec<[f64; 2]> = boxes.iter().flat_map(BoxObstacle::corners).collect();
    if corners.is_empty() {
        return Err(SimError::invalid(
            "walls",
            "the world has no obstacles to draw",
        ));
    }
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for c in &corners {
        x0 = x0.min(c[0]);
        y0 = y0.min(c[1]);
        x1 = x1.max(c[0]);
        y1 = y1.max(c[1]);
    }
    let margin = 2.0 * resolution;
    let (ox, oy) = (x0 - margin, y0 - margin);
    let width = ((x1 + margin - ox) / resolution).ceil() as usize;
    let height = ((y1 + margin - oy) / resolution).ceil() as usize;
    if width.saturating_mul(height) > 100_000_000 {
        return Err(SimError::invalid(
            "resolution",
            format!("a {width} x {height} grid is too large"),
        ));
    }
    let mut data = vec![FREE; width * height];
    for b in &boxes {
        let cs = b.corners();
        let bx0 = cs.iter().map(|c| c[0]).fold(f64::MAX, f64::min);
        let bx1 = cs.iter().map(|c| c[0]).fold(f64::MIN, f64::max);
        let by0 = cs.iter().map(|c| c[1]).fold(f64::MAX, f64::min);
        let by1 = cs.iter().map(|c| c[1]).fold(f64::MIN, f64::max);
        let c0 = (((bx0 - ox) / resolution).floor().max(0.0) as usize).min(width);
        let c1 = (((bx1 - ox) / resolution).ceil().max(0.0) as usize).min(width);
        let r0 = (((by0 - oy) / resolution).floor().max(0.0) as usize).min(height);
        let r1 = (((by1 - oy) / resolution).ceil().max(0.0) as usize).min(height);
        for row in r0..r1 {
            for col in c0..c1 {
                let cx = ox + (col as f64) * resolution;
                let cy = oy + (row as f64) * resolution;
                if box_overlaps_cell(b, &cs, [cx, cy], resolution) {
                    data[row * width + col] = OCCUPIED;
                }
            }
        }
    }
    let too_large = |e: hng_runtime::map::GridError| SimError::invalid("resolution", e.to_string());
    let w = u32::try_from(width).map_err(|_| SimError::invalid("resolution", "grid too wide"))?;
    let h = u32::try_from(height).map_err(|_| SimError::invalid("resolution", "grid too high"))?;
    OccupancyGrid::from_data(w, h, resolution, [ox, oy], data).map_err(too_large)
}

/// The occupied cells as boxes: runs of occupied cells in a row become one box, and runs
/// with the same columns in consecutive rows are merged, to keep the collider count low.
#[must_use]
pub fn grid_boxes(grid: &OccupancyGrid) -> Vec<BoxObstacle> {
    let (width, height) = (grid.width() as usize, grid.height() as usize);
    let data = grid.data();
    // (start col, end col exclusive) -> first row of the open rectangle
    let mut open: Vec<(usize, usize, usize)> = Vec::new();
    let mut rects: Vec<(usize, usize, usize, usize)> = Vec::new(); // c0, c1, r0, r1 (excl.)
    for row in 0..=height {
        let mut runs = Vec::new();
        if row < height {
            let cells = &data[row * width..(row + 1) * width];
            let mut col = 0;
            while col < width {
                if cells[col] == OCCUPIED {
                    let start = col;
                    while col < width && cells[col] == OCCUPIED {
                        col += 1;
                    }
                    runs.push((start, col));
                } else {
                    col += 1;
                }
            }
        }
        let mut next_open = Vec::with_capacity(runs.len());
        for &(c0, c1) in &runs {
            if let Some(pos) = open.iter().position(|&(a, b, _)| a == c0 && b == c1) {
                let (_, _, r0) = open.swap_remove(pos);
                next_open.push((c0, c1, r0));
            } else {
                next_open.push((c0, c1, row));
            }
        }
        rects.extend(open.drain(..).map(|(c0, c1, r0)| (c0, c1, r0, row)));
        open = next_open;
    }
    let res = grid.resolution();
    let origin = grid.origin();
    let yaw = grid.origin_yaw();
    let (s, c) = yaw.sin_cos();
    let mut boxes: Vec<BoxObstacle> = rects
        .into_iter()
        .map(|(c0, c1, r0, r1)| {
            let u = (c0 + c1) as f64 * res / 2.0;
            let v = (r0 + r1) as f64 * res / 2.0;
            BoxObstacle {
                center: [origin[0] + c * u - s * v, origin[1] + s * u + c * v],
                size: [(c1 - c0) as f64 * res, (r1 - r0) as f64 * res],
                angle: yaw,
                color: None,
            }
        })
        .collect();
    // Deterministic order regardless of the merge bookkeeping.
    boxes.sort_by(|a, b| {
        a.center[1]
            .total_cmp(&b.center[1])
            .then(a.center[0].total_cmp(&b.center[0]))
    });
    boxes
}

/// Separating-axis test of an oriented box against the axis-aligned square cell at `min`.
fn box_overlaps_cell(b: &BoxObstacle, corners: &[[f64; 2]; 4], min: [f64; 2], size: f64) -> bool {
    let cell = [
        min,
        [min[0] + size, min[1]],
        [min[0] + size, min[1] + size],
        [min[0], min[1] + size],
    ];
    let (s, c) = b.angle.sin_cos();
    let axes = [[1.0, 0.0], [0.0, 1.0], [c, s], [-s, c]];
    axes.iter().all(|a| {
        let proj = |p: &[f64; 2]| p[0] * a[0] + p[1] * a[1];
        let (mut amin, mut amax, mut bmin, mut bmax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in corners {
            amin = amin.min(proj(p));
            amax = amax.max(proj(p));
        }
        for p in &cell {
            bmin = bmin.min(proj(p));
            bmax = bmax.max(proj(p));
        }
        // Strict: touching edges do not count as overlap.
        amin < bmax - 1e-9 && bmin < amax - 1e-9
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_merge_into_rectangles() -> Result<(), hng_runtime::map::GridError> {
        // A 3 x 2 occupied block and one lone cell: two boxes.
        let mut g = OccupancyGrid::new(5, 3, 1.0, [0.0, 0.0], FREE)?;
        for row in 0..2 {
            for col in 0..3 {
                g.set(col, row, OCCUPIED);
            }
        }
        g.set(4, 2, OCCUPIED);
        let boxes = grid_boxes(&g);
        assert_eq!(boxes.len(), 2);
        assert_eq!(boxes[0].center, [1.5, 1.0]);
        assert_eq!(boxes[0].size, [3.0, 2.0]);
        assert_eq!(boxes[1].center, [4.5, 2.5]);
        Ok(())
    }
}
