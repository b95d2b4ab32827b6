//! Occupancy-grid mapping with log-odds and ray traversal, and export in the
//! ROS `map_server` format (PGM + YAML).

use smart_default::SmartDefault;
use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry2, Point2, Vector2};

use crate::planning::{OccupancyGrid, UNKNOWN};

/// Log-odds update parameters.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct MapperConfig {
    /// Cell size (m). Default 0.05.
    #[default(0.05)]
    pub resolution: f64,
    /// Log-odds added to a cell containing a beam end point. Default 0.85 (p ≈ 0.7).
    #[default(0.85)]
    pub hit: f32,
    /// Log-odds added to a cell a beam passes through. Default −0.4 (p ≈ 0.4).
    #[default(-0.4)]
    pub miss: f32,
    /// Log-odds are clamped to `[−clamp, clamp]`. Default 3.5.
    #[default(3.5)]
    pub clamp: f32,
    /// Beams longer than this are ignored (m). Default 30.
    #[default(30.0)]
    pub max_range: f64,
}

/// A growable log-odds occupancy map. Cells never observed stay exactly 0
/// and count as unknown.
#[derive(Debug, Clone)]
pub struct LogOddsMap {
    cfg: MapperConfig,
    origin: Vector2<f64>,
    width: usize,
    height: usize,
    cells: Vec<f32>,
    observed: Vec<bool>,
}

impl LogOddsMap {
    /// An empty map.
    pub fn new(cfg: MapperConfig) -> Self {
        Self {
            cfg,
            origin: Vector2::zeros(),
            width: 0,
            height: 0,
            cells: Vec::new(),
            observed: Vec::new(),
        }
    }

    /// The parameters.
    pub fn config(&self) -> &MapperConfig {
        &self.cfg
    }

    /// Grows the grid to contain the map-frame box `[lo, hi]`.
    fn ensure(&mut self, lo: Vector2<f64>, hi: Vector2<f64>) {
        let res = self.cfg.resolution;
        let pad = 64.0 * res;
        let (cur_lo, cur_hi) = if self.width == 0 {
            (lo - Vector2::repeat(pad), hi + Vector2::repeat(pad))
        } else {
            let cur_hi = self.origin + Vector2::new(self.width as f64, self.height as f64) * res;
            if lo.x >= self.origin.x && lo.y >= self.origin.y && hi.x < cur_hi.x && hi.y < cur_hi.y
            {
                return;
            }
            let new_lo = Vector2::new(
                if lo.x < self.origin.x {
                    lo.x - pad
                } else {
                    self.origin.x
                },
                if lo.y < self.origin.y {
                    lo.y - pad
                } else {
                    self.origin.y
                },
            );
            let new_hi = Vector2::new(
                if hi.x >= cur_hi.x {
                    hi.x + pad
                } else {
                    cur_hi.x
                },
                if hi.y >= cur_hi.y {
                    hi.y + pad
                } else {
                    cur_hi.y
                },
            );
            (new_lo, new_hi)
        };
        // Keep the origin on the existing cell lattice.
        let shift = if self.width == 0 {
            (0i64, 0i64)
        } else {
            (
                ((self.origin.x - cur_lo.x) / res).ceil() as i64,
                ((self.origin.y - cur_lo.y) / res).ceil() as i64,
            )
        };
        let new_origin = if self.width == 0 {
            cur_lo
        } else {
            self.origin - Vector2::new(shift.0 as f64, shift.1 as f64) * res
        };
        let w = ((cur_hi.x - new_origin.x) / res).ceil() as usize + 1;
        let h = ((cur_hi.y - new_origin.y) / res).ceil() as usize + 1;
        let mut cells = vec![0f32; w * h];
        let mut observed = vec![false; w * h];
        for y in 0..self.height {
            for x in 0..self.width {
                let (nx, ny) = (x + shift.0 as usize, y + shift.1 as usize);
                cells[ny * w + nx] = self.cells[y * self.width + x];
                observed[ny * w + nx] = self.observed[y * self.width + x];
            }
        }
        self.origin = new_origin;
        self.width = w;
        self.height = h;
        self.cells = cells;
        self.observed = observed;
    }

    #[inline]
    fn cell(&self, p: &Vector2<f64>) -> (i64, i64) {
        let u = (p - self.origin) / self.cfg.resolution;
        (u.x.floor() as i64, u.y.floor() as i64)
    }

    /// Log-odds of the cell at `(x, y)`; 0 (unknown) outside the grid.
    #[inline]
    fn at(&self, x: i64, y: i64) -> f32 {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.cells[y as usize * self.width + x as usize]
        } else {
            0.0
        }
    }

    /// Whether the map-frame point `p` lies in confidently free space: its
    /// cell and the 8 around it all have log-odds at or below `threshold`
    /// (negative), so a point a cell away from a wall is never judged free.
    pub fn is_free(&self, p: &Vector2<f64>, threshold: f32) -> bool {
        let (cx, cy) = self.cell(p);
        (-1..=1).all(|dy| (-1..=1).all(|dx| self.at(cx + dx, cy + dy) <= threshold))
    }

    #[inline]
    fn update(&mut self, x: i64, y: i64, delta: f32) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            let i = y as usize * self.width + x as usize;
            self.cells[i] = (self.cells[i] + delta).clamp(-self.cfg.clamp, self.cfg.clamp);
            self.observed[i] = true;
        }
    }

    /// Whether the cell containing the map-frame point `p` has ever been
    /// observed (a beam ended in it or passed through it).
    pub fn is_observed(&self, p: &Vector2<f64>) -> bool {
        let (x, y) = self.cell(p);
        x >= 0
            && y >= 0
            && (x as usize) < self.width
            && (y as usize) < self.height
            && self.observed[y as usize * self.width + x as usize]
    }

    /// Integrates one scan: `points` are beam end points in the sensor frame,
    /// `sensor_pose` the sensor pose in the map frame. Cells along each beam
    /// (Bresenham) get a miss, the end cell a hit.
    pub fn integrate(&mut self, sensor_pose: &Isometry2<f64>, points: &[Vector2<f64>]) {
        let origin = sensor_pose.translation.vector;
        let ends: Vec<Vector2<f64>> = points
            .iter()
            .filter(|p| p.norm() <= self.cfg.max_range)
            .map(|p| (sensor_pose * Point2::from(*p)).coords)
            .collect();
        let (mut lo, mut hi) = (origin, origin);
        for e in &ends {
            lo = lo.inf(e);
            hi = hi.sup(e);
        }
        self.ensure(lo, hi);
        let s = self.cell(&origin);
        let (hit, miss) = (self.cfg.hit, self.cfg.miss);
        for e in &ends {
            let t = self.cell(e);
            bresenham(s, t, |x, y| self.update(x, y, miss));
            self.update(t.0, t.1, hit);
        }
    }

    /// Occupancy probability in percent of every cell, `-1` for unobserved
    /// cells, as an [`OccupancyGrid`]. Returns `None` before the first scan.
    pub fn to_occupancy_grid(&self) -> Option<OccupancyGrid> {
        let data = self
            .cells
            .iter()
            .zip(&self.observed)
            .map(|(&l, &seen)| {
                if seen {
                    let p = 1.0 - 1.0 / (1.0 + f64::from(l).exp());
                    (p * 100.0).round().clamp(0.0, 100.0) as i8
                } else {
                    UNKNOWN
                }
            })
            .collect();
        OccupancyGrid::from_data(
            u32::try_from(self.width).ok()?,
            u32::try_from(self.height).ok()?,
            self.cfg.resolution,
            [self.origin.x, self.origin.y],
            data,
        )
        .ok()
    }
}

/// Calls `f` for every cell on the line from `a` to `b`, excluding `b`.
fn bresenham(a: (i64, i64), b: (i64, i64), mut f: impl FnMut(i64, i64)) {
    let (mut x, mut y) = a;
    let dx = (b.0 - a.0).abs();
    let dy = -(b.1 - a.1).abs();
    let sx = if a.0 < b.0 { 1 } else { -1 };
    let sy = if a.1 < b.1 { 1 } else { -1 };
    let mut err = dx + dy;
    while (x, y) != b {
        f(x, y);
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x += sx;
        }
        if e2 <= dx {
            err += dx;
            y += sy;
        }
    }
}

/// Error writing a map.
#[derive(Debug, thiserror::Error)]
#[error("{}: cannot write map: {source}", path.display())]
pub struct MapWriteError {
    /// File being written.
    pub path: PathBuf,
    /// Cause.
    pub source: std::io::Error,
}

/// Grid value at or above which a pixel is written occupied (black). As `map_saver`.
pub const PGM_OCCUPIED_THRESHOLD: i8 = 65;
/// Grid value at or below which a pixel is written free (white). As `map_saver`.
pub const PGM_FREE_THRESHOLD: i8 = 25;

/// Writes `grid` as `<base>.pgm` and `<base>.yaml` in the ROS `map_server`
/// format (trinary, like `map_saver`): occupied 0, free 254, unknown 205;
/// image row 0 is the top (largest y) and the YAML `origin` is the map-frame
/// position of the lower-left pixel. Returns the two paths.
pub fn write_pgm_yaml(
    grid: &OccupancyGrid,
    base: &Path,
) -> Result<(PathBuf, PathBuf), MapWriteError> {
    let pgm = base.with_extension("pgm");
    let yaml = base.with_extension("yaml");
    let (w, h) = (grid.width() as usize, grid.height() as usize);
    let mut bytes = format!(
        "P5\n# hng occupancy map, {} m/cell\n{w} {h}\n255\n",
        grid.resolution()
    )
    .into_bytes();
    bytes.reserve(w * h);
    for row in grid.data().chunks(w).rev() {
        bytes.extend(row.iter().map(|&v| match v {
            v if v >= PGM_OCCUPIED_THRESHOLD => 0u8,
            v if (0..=PGM_FREE_THRESHOLD).contains(&v) => 254,
            _ => 205,
        }));
    }
    let write = |path: &Path, data: &[u8]| -> Result<(), MapWriteError> {
        std::fs::File::create(path)
            .and_then(|mut f| f.write_all(data))
            .map_err(|source| MapWriteError {
                path: path.to_path_buf(),
                source,
            })
    };
    write(&pgm, &bytes)?;
    let image = pgm
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let o = grid.origin();
    let text = format!(
        "image: {image}\nmode: trinary\nresolution: {}\norigin: [{}, {}, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        grid.resolution(),
        o[0],
        o[1]
    );
    write(&yaml, text.as_bytes())?;
    Ok((pgm, yaml))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planning::{FREE, OCCUPIED};

    #[test]
    fn bresenham_covers_line() {
        let mut v = Vec::new();
        bresenham((0, 0), (4, 2), |x, y| v.push((x, y)));
        assert_eq!(v.len(), 4, "{v:?}");
        assert_eq!(v[0], (0, 0));
        v.push((4, 2));
        for w in v.windows(2) {
            assert!(
                (w[1].0 - w[0].0).abs() <= 1 && (w[1].1 - w[0].1).abs() <= 1,
                "{v:?}"
            );
        }
        let mut v = Vec::new();
        bresenham((2, 2), (2, 2), |x, y| v.push((x, y)));
        assert!(v.is_empty());
    }

    #[test]
    fn integrates_wall_and_free_space() {
        let mut m = LogOddsMap::new(MapperConfig::default());
        let pts: Vec<Vector2<f64>> = (-10..=10)
            .map(|i| Vector2::new(2.0, f64::from(i) * 0.05))
            .collect();
        for _ in 0..5 {
            m.integrate(&Isometry2::new(Vector2::new(1.0, 1.0), 0.0), &pts);
        }
        let g = m.to_occupancy_grid().expect("grid");
        let (wx, wy) = g.world_to_cell(3.02, 1.0);
        assert!(
            g.get(wx, wy).is_some_and(|v| v >= 90),
            "{:?}",
            g.get(wx, wy)
        );
        let (fx, fy) = g.world_to_cell(2.0, 1.0);
        assert!(
            g.get(fx, fy).is_some_and(|v| v <= 20),
            "{:?}",
            g.get(fx, fy)
        );
        let (ux, uy) = g.world_to_cell(0.0, 3.0);
        assert_eq!(g.get(ux, uy), Some(UNKNOWN));
        // Observed: where beams ended or passed; not: beside them and off the grid.
        assert!(m.is_observed(&Vector2::new(3.02, 1.0)));
        assert!(m.is_observed(&Vector2::new(2.0, 1.0)));
        assert!(!m.is_observed(&Vector2::new(0.0, 3.0)));
        assert!(!m.is_observed(&Vector2::new(500.0, -500.0)));
        // Growing keeps old content in place.
        m.integrate(&Isometry2::new(Vector2::new(-20.0, -20.0), 0.0), &pts);
        let g2 = m.to_occupancy_grid().expect("grid");
        let (wx, wy) = g2.world_to_cell(3.02, 1.0);
        assert!(g2.get(wx, wy).is_some_and(|v| v >= 90));
        assert!(g2.width() > g.width());
    }

    #[test]
    fn pgm_yaml_layout() {
        let mut g = OccupancyGrid::new(3, 2, 0.5, [-1.0, 2.0], UNKNOWN).expect("grid");
        g.set(0, 0, OCCUPIED); // bottom-left: last image row, first column
        g.set(2, 1, FREE); // top-right: first image row, last column
        let dir = std::env::temp_dir().join(format!("hng-map-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let (pgm, yaml) = write_pgm_yaml(&g, &dir.join("m")).expect("write");
        let bytes = std::fs::read(&pgm).expect("pgm");
        let pixels = &bytes[bytes.len() - 6..];
        assert_eq!(pixels, &[205, 205, 254, 0, 205, 205]);
        assert!(bytes.starts_with(b"P5\n"));
        let y = std::fs::read_to_string(&yaml).expect("yaml");
        assert!(y.contains("image: m.pgm\n"), "{y}");
        assert!(y.contains("origin: [-1, 2, 0.0]"), "{y}");
        assert!(y.contains("resolution: 0.5\n"), "{y}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
