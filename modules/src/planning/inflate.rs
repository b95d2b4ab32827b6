//! Obstacle inflation by a robot radius with an exact Euclidean distance transform.

use hng_runtime::map::{OCCUPIED, OccupancyGrid, UNKNOWN};
use smart_default::SmartDefault;

/// Which cells count as obstacles when inflating.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct InflationConfig {
    /// Robot radius in metres; cells whose centre is within this distance of an
    /// obstacle cell centre become [`OCCUPIED`]. Default 0.3 m.
    #[default(0.3)]
    pub radius_m: f64,
    /// Cells with a value `>=` this are obstacles. Default 50.
    #[default(50)]
    pub occupied_threshold: i8,
    /// Whether unknown cells (`-1`) are inflated like obstacles. Default false.
    pub inflate_unknown: bool,
}

/// Squared Euclidean distance (in cells²) from every cell centre to the nearest
/// cell for which `is_obstacle` holds (Felzenszwalb & Huttenlocher, exact, O(cells)).
/// Cells with no obstacle in the grid get `f64::INFINITY`.
pub fn squared_distance_transform(
    width: usize,
    height: usize,
    is_obstacle: impl Fn(usize) -> bool,
) -> Vec<f64> {
    let n = width * height;
    let mut d: Vec<f64> = (0..n)
        .map(|i| if is_obstacle(i) { 0.0 } else { f64::INFINITY })
        .collect();
    let len = width.max(height);
    let mut f = vec![0.0; len];
    let mut out = vec![0.0; len];
    let mut v = vec![0usize; len];
    let mut z = vec![0.0; len + 1];
    // Columns, then rows.
    for x in 0..width {
        for y in 0..height {
            f[y] = d[y * width + x];
        }
        edt_1d(&f[..height], &mut out[..height], &mut v, &mut z);
        for y in 0..height {
            d[y * width + x] = out[y];
        }
    }
    for y in 0..height {
        let row = &mut d[y * width..(y + 1) * width];
        f[..width].copy_from_slice(row);
        edt_1d(&f[..width], &mut out[..width], &mut v, &mut z);
        row.copy_from_slice(&out[..width]);
    }
    d
}

/// 1D squared distance transform of sampled function `f` (lower envelope of parabolas).
fn edt_1d(f: &[f64], out: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    // Find the first finite sample; if none, everything stays infinite.
    let Some(first) = f.iter().position(|x| x.is_finite()) else {
        out.fill(f64::INFINITY);
        return;
    };
    let mut k = 0usize;
    v[0] = first;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in first + 1..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            let p = v[k];
            let s =
                ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                // k == 0 and the new parabola dominates everywhere.
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f64::INFINITY;
            }
            break;
        }
    }
    let mut k = 0usize;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        let dq = q as f64 - p as f64;
        *o = dq * dq + f[p];
    }
}

/// Returns a copy of `grid` in which every cell within `cfg.radius_m` of an
/// obstacle is [`OCCUPIED`]; other cells keep their value.
pub fn inflate(grid: &OccupancyGrid, cfg: &InflationConfig) -> OccupancyGrid {
    let w = grid.width() as usize;
    let h = grid.height() as usize;
    let data = grid.data();
    let thr = cfg.occupied_threshold;
    let d2 = squared_distance_transform(w, h, |i| {
        let v = data[i];
        v >= thr || (cfg.inflate_unknown && v == UNKNOWN)
    });
    let r_cells = (cfg.radius_m / grid.resolution()).max(0.0);
    // Small epsilon so a radius of exactly k cells includes cells at distance k.
    let r2 = r_cells * r_cells + 1e-9;
    let mut out = grid.clone();
    for (y, row) in d2.chunks(w).enumerate() {
        for (x, &dd) in row.iter().enumerate() {
            if dd <= r2 {
                out.set(x as i64, y as i64, OCCUPIED);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::map::FREE;

    #[test]
    fn distance_transform_matches_brute_force() {
        let (w, h) = (23usize, 17usize);
        let obst: Vec<bool> = (0..w * h).map(|i| (i * 7919) % 37 == 0).collect();
        let d = squared_distance_transform(w, h, |i| obst[i]);
        for y in 0..h {
            for x in 0..w {
                let mut best = f64::INFINITY;
                for yy in 0..h {
                    for xx in 0..w {
                        if obst[yy * w + xx] {
                            let dx = x as f64 - xx as f64;
                            let dy = y as f64 - yy as f64;
                            best = best.min(dx * dx + dy * dy);
                        }
                    }
                }
                assert_eq!(d[y * w + x], best, "cell {x},{y}");
            }
        }
    }

    #[test]
    fn empty_grid_has_infinite_distance() {
        let d = squared_distance_transform(4, 3, |_| false);
        assert!(d.iter().all(|v| v.is_infinite()));
    }

    #[test]
    fn inflation_makes_a_disk() {
        let mut g = OccupancyGrid::new(21, 21, 0.1, [0.0, 0.0], FREE).expect("grid");
        g.set(10, 10, OCCUPIED);
        let cfg = InflationConfig {
            radius_m: 0.3,
            ..Default::default()
        };
        let out = inflate(&g, &cfg);
        for y in 0..21i64 {
            for x in 0..21i64 {
                let d2 = (x - 10).pow(2) + (y - 10).pow(2);
                let occ = out.get(x, y) == Some(OCCUPIED);
                assert_eq!(occ, d2 <= 9, "cell {x},{y}");
            }
        }
    }
}
