//! Scan-to-map matching: a multi-resolution correlative scan matcher
//! (branch-and-bound over a likelihood field, as in Olson 2009 and
//! Cartographer's real-time CSM), followed by point-to-line ICP refinement.

use nalgebra::{Isometry2, Matrix3, Vector2, Vector3};
use smart_default::SmartDefault;

/// A lower bound on a likelihood field's value at a map-frame point (see
/// [`LikelihoodField::build_with_floor`]).
pub type FieldFloor<'a> = &'a dyn Fn(&Vector2<f64>) -> f32;

/// A likelihood field over a local map: each cell holds
/// `exp(-d² / 2σ²)`, `d` the distance from the cell centre to the nearest map
/// point, plus max-pooled copies for branch-and-bound.
#[derive(Debug, Clone)]
pub struct LikelihoodField {
    resolution: f64,
    origin: Vector2<f64>,
    width: usize,
    height: usize,
    /// `levels[h][y * width + x]` = max of the fine field over cells
    /// `[x, x + 2^h) × [y, y + 2^h)`; `levels[0]` is the fine field.
    levels: Vec<Vec<f32>>,
    /// Per fine cell: 1 + index of the nearest map point within the kernel, or 0 (so the
    /// table starts as zeroed memory, whose pages only the cells written touch).
    nearest: Vec<u32>,
}

/// Side of the tiles the field's coarse levels are pooled by (cells).
const TILE: usize = 16;

/// The field's cells in tiles of [`TILE`] x [`TILE`], row-major, to pool only the tiles that
/// can hold a non-zero value. A map's points lie along walls, so most of the bounding box
/// is empty: pooling only the live tiles gives the same levels for a fraction of the work.
#[derive(Debug, Clone, Copy)]
struct Tiles {
    width: usize,
    height: usize,
    across: usize,
    down: usize,
}

impl Tiles {
    fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            across: width.div_ceil(TILE),
            down: height.div_ceil(TILE),
        }
    }

    fn len(&self) -> usize {
        self.across * self.down
    }

    /// Marks the tiles of cells `[x0, x1] x [y0, y1]` live.
    fn mark(&self, live: &mut [bool], x0: usize, x1: usize, y0: usize, y1: usize) {
        for ty in y0 / TILE..=y1 / TILE {
            for tx in x0 / TILE..=x1 / TILE {
                live[ty * self.across + tx] = true;
            }
        }
    }

    /// The tiles with a live tile within `s` cells to their right or below (themselves
    /// included).
    fn dilate(&self, live: &[bool], s: usize) -> Vec<bool> {
        let d = s.div_ceil(TILE);
        let mut out = vec![false; live.len()];
        for ty in 0..self.down {
            for tx in 0..self.across {
                out[ty * self.across + tx] = (ty..=(ty + d).min(self.down - 1)).any(|y| {
                    (tx..=(tx + d).min(self.across - 1)).any(|x| live[y * self.across + x])
                });
            }
        }
        out
    }

    /// The row and column ranges of the live tiles.
    fn live<'a>(
        &'a self,
        live: &'a [bool],
    ) -> impl Iterator<Item = (std::ops::Range<usize>, std::ops::Range<usize>)> + 'a {
        live.iter().enumerate().filter(|(_, l)| **l).map(|(i, _)| {
            let (tx, ty) = (i % self.across, i / self.across);
            (
                ty * TILE..((ty + 1) * TILE).min(self.height),
                tx * TILE..((tx + 1) * TILE).min(self.width),
            )
        })
    }
}

impl LikelihoodField {
    /// Builds the field from map-frame points. `depth` is the number of
    /// coarser levels for branch-and-bound. Returns `None` if `points` is empty.
    pub fn build(
        points: &[Vector2<f64>],
        resolution: f64,
        sigma: f64,
        depth: usize,
    ) -> Option<Self> {
        Self::build_with_floor(points, resolution, sigma, depth, None)
    }

    /// [`LikelihoodField::build`], every fine cell raised to at least
    /// `floor(cell centre)` (before the max-pooled levels are made).
    pub fn build_with_floor(
        points: &[Vector2<f64>],
        resolution: f64,
        sigma: f64,
        depth: usize,
        floor: Option<FieldFloor<'_>>,
    ) -> Option<Self> {
        let first = points.first()?;
        let (mut lo, mut hi) = (*first, *first);
        for p in points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let kernel = (3.0 * sigma / resolution).ceil().max(1.0) as i64;
        // Zero margin on every side, wider than the kernel plus the coarsest
        // window, so max-pooled levels are exact on the stored index range.
        let margin = (kernel + (1i64 << depth) + 1) as f64;
        let origin = lo - Vector2::repeat(margin * resolution);
        let width = (((hi.x - lo.x) / resolution).ceil() + 2.0 * margin + 1.0) as usize;
        let height = (((hi.y - lo.y) / resolution).ceil() + 2.0 * margin + 1.0) as usize;
        let mut fine = vec![0f32; width * height];
        let mut nearest = vec![0u32; width * height];
        // Tiles of TILE x TILE cells that may hold a non-zero value: only they are pooled
        // into the coarser levels (the others stay zero, as a full pass would leave them).
        let tiles = Tiles::new(width, height);
        let mut active = vec![floor.is_some(); tiles.len()];
        let inv2s2 = 1.0 / (2.0 * sigma * sigma);
        let mut gx: Vec<f64> = Vec::with_capacity(2 * kernel as usize + 1);
        for (k, p) in points.iter().enumerate() {
            let u = (p - origin) / resolution;
            let (cx, cy) = (u.x.floor() as i64, u.y.floor() as i64);
            // The Gaussian is separable: exp(-(dx²+dy²)/2σ²) = gx·gy.
            let (x0, x1) = ((cx - kernel).max(0), (cx + kernel).min(width as i64 - 1));
            let (y0, y1) = ((cy - kernel).max(0), (cy + kernel).min(height as i64 - 1));
            if x0 > x1 || y0 > y1 {
                continue;
            }
            tiles.mark(
                &mut active,
                x0 as usize,
                x1 as usize,
                y0 as usize,
                y1 as usize,
            );
            gx.clear();
            gx.extend((x0..=x1).map(|x| {
                let dx = (x as f64 + 0.5 - u.x) * resolution;
                (-dx * dx * inv2s2).exp()
            }));
            for y in y0..=y1 {
                let dy = (y as f64 + 0.5 - u.y) * resolution;
                let gy = (-dy * dy * inv2s2).exp();
                for (x, g) in (x0..=x1).zip(&gx) {
                    let v = (g * gy) as f32;
                    let i = y as usize * width + x as usize;
                    if v > fine[i] {
                        fine[i] = v;
                        nearest[i] = k as u32 + 1;
                    }
                }
            }
        }
        if let Some(floor) = floor {
            for y in 0..height {
                for x in 0..width {
                    let c = origin + Vector2::new(x as f64 + 0.5, y as f64 + 0.5) * resolution;
                    let i = y * width + x;
                    fine[i] = fine[i].max(floor(&c));
                }
            }
        }
        let mut levels = vec![fine];
        for h in 1..=depth {
            let prev = &levels[h - 1];
            let s = 1usize << (h - 1);
            // A cell reads up to `s` cells right and down: its tile is live if one of the
            // tiles within `s` cells right and down was.
            active = tiles.dilate(&active, s);
            let mut next = vec![0f32; width * height];
            for (ys, xs) in tiles.live(&active) {
                for y in ys {
                    let y2 = (y + s).min(height - 1);
                    for x in xs.clone() {
                        let x2 = (x + s).min(width - 1);
                        next[y * width + x] = prev[y * width + x]
                            .max(prev[y * width + x2])
                            .max(prev[y2 * width + x])
                            .max(prev[y2 * width + x2]);
                    }
                }
            }
            levels.push(next);
        }
        Some(Self {
            resolution,
            origin,
            width,
            height,
            levels,
            nearest,
        })
    }

    /// Index (into the points the field was built from) of the map point
    /// nearest to the centre of the cell containing `p`, if one is within
    /// the kernel radius (3σ).
    #[inline]
    pub fn nearest(&self, p: &Vector2<f64>) -> Option<usize> {
        let u = self.cell_coords(p);
        let (x, y) = (u.x.floor() as i64, u.y.floor() as i64);
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            let k = self.nearest[y as usize * self.width + x as usize];
            (k != 0).then(|| k as usize - 1)
        } else {
            None
        }
    }

    /// Cell size (m).
    pub fn resolution(&self) -> f64 {
        self.resolution
    }

    /// Number of coarse levels.
    pub fn depth(&self) -> usize {
        self.levels.len() - 1
    }

    #[inline]
    fn at(&self, level: usize, x: i64, y: i64) -> f32 {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.levels[level][y as usize * self.width + x as usize]
        } else {
            0.0
        }
    }

    /// Continuous cell coordinates of a map-frame point.
    #[inline]
    fn cell_coords(&self, p: &Vector2<f64>) -> Vector2<f64> {
        (p - self.origin) / self.resolution
    }

    /// Bilinearly interpolated field value and its gradient (per metre) at a
    /// map-frame point.
    pub fn interpolate(&self, p: &Vector2<f64>) -> (f64, Vector2<f64>) {
        let u = self.cell_coords(p) - Vector2::repeat(0.5);
        let (x0, y0) = (u.x.floor(), u.y.floor());
        let (fx, fy) = (u.x - x0, u.y - y0);
        let (x, y) = (x0 as i64, y0 as i64);
        let v00 = f64::from(self.at(0, x, y));
        let v10 = f64::from(self.at(0, x + 1, y));
        let v01 = f64::from(self.at(0, x, y + 1));
        let v11 = f64::from(self.at(0, x + 1, y + 1));
        let v = (1.0 - fy) * ((1.0 - fx) * v00 + fx * v10) + fy * ((1.0 - fx) * v01 + fx * v11);
        let gx = (1.0 - fy) * (v10 - v00) + fy * (v11 - v01);
        let gy = (1.0 - fx) * (v01 - v00) + fx * (v11 - v10);
        (v, Vector2::new(gx, gy) / self.resolution)
    }

    /// Mean interpolated field value of `points` (sensor frame) at `pose`, in [0, 1].
    pub fn score(&self, points: &[Vector2<f64>], pose: &Isometry2<f64>) -> f64 {
        if points.is_empty() {
            return 0.0;
        }
        let s: f64 = points
            .iter()
            .map(|p| {
                self.interpolate(&(pose * nalgebra::Point2::from(*p)).coords)
                    .0
            })
            .sum();
        s / points.len() as f64
    }
}

/// Scan matcher parameters. Defaults suit a 2D lidar indoors with wheel odometry.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct MatcherConfig {
    /// Likelihood field cell size (m). Default 0.05.
    #[default(0.05)]
    pub resolution: f64,
    /// Gaussian width of the likelihood field (m). Default 0.05.
    #[default(0.05)]
    pub sigma: f64,
    /// Half-width of the translational search window around the prior (m). Default 0.35.
    #[default(0.35)]
    pub linear_window: f64,
    /// Half-width of the rotational search window (rad). Default 15°.
    #[default(15f64.to_radians())]
    pub angular_window: f64,
    /// Coarse levels of branch-and-bound (coarsest step `2^depth` cells). Default 3.
    #[default(3)]
    pub depth: usize,
    /// Penalty weight on the squared distance from the prior (1/m²). Default 2.
    #[default(2.0)]
    pub translation_weight: f64,
    /// Penalty weight on the squared rotation from the prior (1/rad²). Default 2.
    #[default(2.0)]
    pub rotation_weight: f64,
    /// Point-to-line ICP iterations. Default 15; 0 disables refinement.
    #[default(15)]
    pub refine_iterations: usize,
    /// Ranges beyond this are ignored when choosing the angular step (m). Default 15.
    #[default(15.0)]
    pub max_range_for_step: f64,
}

/// Result of [`match_scan`].
#[derive(Debug, Clone, PartialEq)]
pub struct MatchResult {
    /// Estimated sensor pose in the map frame.
    pub pose: Isometry2<f64>,
    /// Mean field value of the scan at `pose` (bilinear), in [0, 1]: 1 means
    /// every point lies on a map point.
    pub score: f64,
    /// Best correlative (grid) score before refinement, penalty included.
    pub csm_score: f64,
    /// Covariance of (x, y, θ) from the ICP Hessian scaled by the residual
    /// variance (a Laplace approximation, see [`refine`]).
    pub covariance: Matrix3<f64>,
    /// Information of `(x, y, θ)` from the scan alone (the ICP Hessian scaled by
    /// the residual variance, without the grid prior): near zero along a
    /// direction the scene does not constrain, such as a corridor's axis.
    pub information: Matrix3<f64>,
    /// Branch-and-bound nodes scored.
    pub nodes: usize,
}

#[derive(Clone, Copy)]
struct Cand {
    angle: usize,
    dx: i64,
    dy: i64,
    score: f64,
}

struct Search<'a> {
    field: &'a LikelihoodField,
    /// Per angle: base cells of the rotated, prior-translated points.
    cells: Vec<Vec<(i64, i64)>>,
    angles: Vec<f64>,
    window: i64,
    wt: f64,
    wr: f64,
    res: f64,
    inv_n: f64,
    /// The best leaves found, at most `keep`, pairwise farther apart than
    /// `sep` cells or `sep_angle` angle steps; best first is not kept sorted.
    top: Vec<Cand>,
    keep: usize,
    sep: i64,
    sep_angle: usize,
    nodes: usize,
}

impl Search<'_> {
    /// Closest value to 0 in `[a, a + len)`.
    fn nearest0(a: i64, len: i64) -> i64 {
        if a > 0 {
            a
        } else if a + len - 1 < 0 {
            a + len - 1
        } else {
            0
        }
    }

    fn score(&mut self, level: usize, angle: usize, dx: i64, dy: i64) -> Cand {
        self.nodes += 1;
        let mut s = 0f32;
        for &(x, y) in &self.cells[angle] {
            s += self.field.at(level, x + dx, y + dy);
        }
        let len = 1i64 << level;
        let (nx, ny) = (Self::nearest0(dx, len), Self::nearest0(dy, len));
        let t2 = ((nx * nx + ny * ny) as f64) * self.res * self.res;
        let a = self.angles[angle];
        let penalty = (-(self.wt * t2 + self.wr * a * a)).exp();
        Cand {
            angle,
            dx,
            dy,
            score: f64::from(s) * self.inv_n * penalty,
        }
    }

    /// Score a candidate must beat to matter: the worst kept leaf once
    /// `keep` leaves are kept.
    fn threshold(&self) -> f64 {
        if self.top.len() < self.keep.max(1) {
            f64::NEG_INFINITY
        } else {
            self.top
                .iter()
                .map(|c| c.score)
                .fold(f64::INFINITY, f64::min)
        }
    }

    /// Keeps leaf `c`: it replaces a kept leaf near it if it scores higher
    /// (and is dropped if it does not), else it is added and the worst kept
    /// leaf dropped beyond `keep`.
    fn keep_leaf(&mut self, c: Cand) {
        let near = self.top.iter().position(|t| {
            (t.dx - c.dx).abs() <= self.sep
                && (t.dy - c.dy).abs() <= self.sep
                && t.angle.abs_diff(c.angle) <= self.sep_angle
        });
        match near {
            Some(i) if self.top[i].score < c.score => self.top[i] = c,
            Some(_) => {}
            None => {
                self.top.push(c);
                if self.top.len() > self.keep.max(1)
                    && let Some(w) = self
                        .top
                        .iter()
                        .enumerate()
                        .min_by(|a, b| a.1.score.total_cmp(&b.1.score))
                        .map(|(i, _)| i)
                {
                    self.top.swap_remove(w);
                }
            }
        }
    }

    fn descend(&mut self, level: usize, mut cands: Vec<Cand>) {
        cands.sort_unstable_by(|a, b| b.score.total_cmp(&a.score));
        for c in cands {
            if c.score <= self.threshold() {
                break;
            }
            if level == 0 {
                self.keep_leaf(c);
                continue;
            }
            let half = 1i64 << (level - 1);
            let mut children = Vec::with_capacity(4);
            for oy in [0, half] {
                for ox in [0, half] {
                    let (x, y) = (c.dx + ox, c.dy + oy);
                    if x <= self.window && y <= self.window {
                        children.push(self.score(level - 1, c.angle, x, y));
                    }
                }
            }
            self.descend(level - 1, children);
        }
    }
}

/// Matches `points` (sensor frame) against `field`, searching around `prior`.
/// Returns `None` if there are no points.
pub fn match_scan(
    map: &ReferenceMap,
    points: &[Vector2<f64>],
    prior: &Isometry2<f64>,
    cfg: &MatcherConfig,
) -> Option<MatchResult> {
    let (cands, nodes) = search_candidates(map, points, prior, cfg, 1, 0.0, 0.0);
    let (csm_pose, csm_score) = cands.into_iter().next()?;
    let (pose, covariance, information) =
        refine_with_information(map, points, &csm_pose, cfg.refine_iterations);
    let score = map.field.score(points, &pose);
    Some(MatchResult {
        pose,
        score,
        csm_score,
        covariance,
        information,
        nodes,
    })
}

/// The correlative search of [`match_scan`] keeping the `keep` best grid
/// poses that lie pairwise more than `min_separation` metres or
/// `min_angle` radians apart (non-maximum suppression), best first, with
/// their penalised grid scores and the number of nodes scored. Exact for
/// `keep = 1` (the branch-and-bound optimum); for more, the separation is
/// judged against the leaves kept so far, so the set is a good, not a
/// proven, set of distinct local optima.
pub fn search_candidates(
    map: &ReferenceMap,
    points: &[Vector2<f64>],
    prior: &Isometry2<f64>,
    cfg: &MatcherConfig,
    keep: usize,
    min_separation: f64,
    min_angle: f64,
) -> (Vec<(Isometry2<f64>, f64)>, usize) {
    if points.is_empty() {
        return (Vec::new(), 0);
    }
    let field = &map.field;
    let res = field.resolution;
    let max_r = points
        .iter()
        .map(|p| p.norm())
        .fold(0.0f64, f64::max)
        .clamp(1.0, cfg.max_range_for_step.max(1.0));
    // Step such that the farthest point moves by about one cell.
    let step = (1.0 - res * res / (2.0 * max_r * max_r))
        .clamp(-1.0, 1.0)
        .acos()
        .max(1e-4);
    let na = (cfg.angular_window / step).ceil().max(0.0) as i64;
    let angles: Vec<f64> = (-na..=na).map(|i| i as f64 * step).collect();
    let theta0 = prior.rotation.angle();
    let t0 = prior.translation.vector;
    let cells: Vec<Vec<(i64, i64)>> = angles
        .iter()
        .map(|a| {
            let rot = nalgebra::Rotation2::new(theta0 + a);
            points
                .iter()
                .map(|p| {
                    let u = field.cell_coords(&(rot * p + t0));
                    (u.x.floor() as i64, u.y.floor() as i64)
                })
                .collect()
        })
        .collect();
    let depth = field.depth();
    let window = (cfg.linear_window / res).ceil().max(0.0) as i64;
    let mut search = Search {
        field,
        cells,
        angles: angles.clone(),
        window,
        wt: cfg.translation_weight,
        wr: cfg.rotation_weight,
        res,
        inv_n: 1.0 / points.len() as f64,
        top: Vec::new(),
        keep: keep.max(1),
        sep: (min_separation / res).floor() as i64,
        sep_angle: (min_angle / step).floor() as usize,
        nodes: 0,
    };
    let top = 1i64 << depth;
    let mut roots = Vec::new();
    for a in 0..angles.len() {
        let mut y = -window;
        while y <= window {
            let mut x = -window;
            while x <= window {
                roots.push(search.score(depth, a, x, y));
                x += top;
            }
            y += top;
        }
    }
    search.descend(depth, roots);
    let mut top = search.top;
    top.sort_by(|a, b| b.score.total_cmp(&a.score));
    let out = top
        .iter()
        .map(|c| {
            (
                Isometry2::new(
                    t0 + Vector2::new(c.dx as f64, c.dy as f64) * res,
                    theta0 + angles[c.angle],
                ),
                c.score,
            )
        })
        .collect();
    (out, search.nodes)
}

/// Normals of a scan's points (same frame as the points), from the line
/// through each point's two neighbours in beam order. `None` where a neighbour
/// is missing, too far away (`> max(0.2 m, 0.1·range)`) or the three points are
/// not collinear within 3 cm.
pub fn scan_normals(points: &[Vector2<f64>]) -> Vec<Option<Vector2<f64>>> {
    (0..points.len())
        .map(|i| {
            let (a, p, b) = (
                points.get(i.checked_sub(1)?)?,
                &points[i],
                points.get(i + 1)?,
            );
            let gap = (0.1 * p.norm()).max(0.2);
            if (p - a).norm() > gap || (b - p).norm() > gap {
                return None;
            }
            let t = b - a;
            let len = t.norm();
            if len < 1e-6 {
                return None;
            }
            let n = Vector2::new(-t.y, t.x) / len;
            ((p - a).dot(&n).abs() <= 0.03).then_some(n)
        })
        .collect()
}

/// The reference a scan is matched against: map-frame points with normals
/// and their likelihood field.
#[derive(Debug, Clone)]
pub struct ReferenceMap {
    /// Likelihood field of `points` (with nearest-point lookup).
    pub field: LikelihoodField,
    /// Map-frame points.
    pub points: Vec<Vector2<f64>>,
    /// Map-frame unit normals (see [`scan_normals`]).
    pub normals: Vec<Option<Vector2<f64>>>,
}

impl ReferenceMap {
    /// Builds the field; `None` if there are no points or the lengths differ.
    pub fn build(
        points: Vec<Vector2<f64>>,
        normals: Vec<Option<Vector2<f64>>>,
        cfg: &MatcherConfig,
    ) -> Option<Self> {
        Self::build_with_floor(points, normals, cfg, None)
    }

    /// [`ReferenceMap::build`] with a floor on the field
    /// ([`LikelihoodField::build_with_floor`]).
    pub fn build_with_floor(
        points: Vec<Vector2<f64>>,
        normals: Vec<Option<Vector2<f64>>>,
        cfg: &MatcherConfig,
        floor: Option<FieldFloor<'_>>,
    ) -> Option<Self> {
        if points.len() != normals.len() {
            return None;
        }
        let field = LikelihoodField::build_with_floor(
            &points,
            cfg.resolution,
            cfg.sigma,
            cfg.depth,
            floor,
        )?;
        Some(Self {
            field,
            points,
            normals,
        })
    }
}

/// Point-to-line ICP (Censi 2008 style residuals `n·(T·p − m)`) from `start`,
/// correspondences from the field's nearest-point table, Huber-weighted, with
/// `start` as a weak prior (σ = one cell, one degree) so directions the scene
/// does not constrain (a corridor's axis) stay where the grid search put them.
/// Returns the pose and the covariance `σ_r²·H⁻¹` (`σ_r` the weighted residual
/// RMS, at least 1 cm).
pub fn refine(
    map: &ReferenceMap,
    points: &[Vector2<f64>],
    start: &Isometry2<f64>,
    iterations: usize,
) -> (Isometry2<f64>, Matrix3<f64>) {
    let (pose, cov, _) = refine_with_information(map, points, start, iterations);
    (pose, cov)
}

/// [`refine`], also returning the scan's own information (the ICP Hessian
/// over the residual variance, without the grid prior).
pub fn refine_with_information(
    map: &ReferenceMap,
    points: &[Vector2<f64>],
    start: &Isometry2<f64>,
    iterations: usize,
) -> (Isometry2<f64>, Matrix3<f64>, Matrix3<f64>) {
    const HUBER: f64 = 0.02;
    const MAX_RESIDUAL: f64 = 0.1;
    let res = map.field.resolution;
    let x0 = Vector3::new(
        start.translation.x,
        start.translation.y,
        start.rotation.angle(),
    );
    let prior_info = Vector3::new(
        1.0 / (res * res),
        1.0 / (res * res),
        1.0 / 1f64.to_radians().powi(2),
    );
    let mut xi = x0;
    let mut h_icp = Matrix3::zeros();
    for _ in 0..iterations {
        let (s, c) = xi.z.sin_cos();
        let mut h = Matrix3::zeros();
        let mut g = Vector3::zeros();
        let (mut wr2, mut wsum, mut n) = (0.0, 0.0, 0usize);
        for p in points {
            let q = Vector2::new(c * p.x - s * p.y + xi.x, s * p.x + c * p.y + xi.y);
            let Some(k) = map.field.nearest(&q) else {
                continue;
            };
            let Some(nrm) = map.normals[k] else {
                continue;
            };
            let r = nrm.dot(&(q - map.points[k]));
            if r.abs() > MAX_RESIDUAL {
                continue;
            }
            let w = if r.abs() <= HUBER {
                1.0
            } else {
                HUBER / r.abs()
            };
            let dq = Vector2::new(-s * p.x - c * p.y, c * p.x - s * p.y);
            let j = Vector3::new(nrm.x, nrm.y, nrm.dot(&dq));
            h += j * j.transpose() * w;
            g += j * (w * r);
            wr2 += w * r * r;
            wsum += w;
            n += 1;
        }
        if n < 3 {
            break;
        }
        let sigma2 = (wr2 / (wsum - 3.0).max(1.0)).max(1e-4);
        h_icp = h / sigma2;
        let d = xi - x0;
        let mut hp = h_icp;
        let mut gp = g / sigma2;
        for i in 0..3 {
            hp[(i, i)] += prior_info[i];
            gp[i] += prior_info[i] * d[i];
        }
        let Some(inv) = hp.try_inverse() else {
            break;
        };
        let delta = -(inv * gp);
        if !delta.iter().all(|v| v.is_finite()) {
            break;
        }
        xi += delta;
        if delta.xy().norm() < 1e-5 && delta.z.abs() < 1e-6 {
            break;
        }
    }
    let mut hp = h_icp;
    for i in 0..3 {
        hp[(i, i)] += prior_info[i];
    }
    let covariance = hp
        .try_inverse()
        .unwrap_or_else(|| Matrix3::from_diagonal_element(f64::INFINITY));
    (Isometry2::new(xi.xy(), xi.z), covariance, h_icp)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A room with walls and some clutter, as points ordered along each segment.
    fn room() -> Vec<Vector2<f64>> {
        let segs = [
            ((-4.0, -3.0), (4.0, -3.0)),
            ((4.0, -3.0), (4.0, 3.0)),
            ((4.0, 3.0), (-4.0, 3.0)),
            ((-4.0, 3.0), (-4.0, -3.0)),
            ((1.0, 1.0), (2.0, 1.0)),
            ((-2.0, -1.0), (-2.0, 0.0)),
            ((0.0, -2.0), (0.7, -1.3)),
        ];
        let mut pts = Vec::new();
        for ((ax, ay), (bx, by)) in segs {
            let a = Vector2::new(ax, ay);
            let b: Vector2<f64> = Vector2::new(bx, by);
            let n = ((b - a).norm() / 0.02).round() as usize;
            for i in 0..n {
                pts.push(a + (b - a) * (i as f64 / n as f64));
            }
        }
        pts
    }

    fn reference(depth: usize) -> ReferenceMap {
        let pts = room();
        let normals = scan_normals(&pts);
        let cfg = MatcherConfig {
            depth,
            ..Default::default()
        };
        ReferenceMap::build(pts, normals, &cfg).expect("map")
    }

    /// The coarse levels pooled over live tiles only are bit for bit those of a pass over
    /// every cell (depths up to 6: pooling windows wider than a tile too).
    #[test]
    fn levels_pooled_by_live_tiles_equal_a_full_pass() {
        let pts = room();
        for (res, depth) in [(0.05, 3), (0.05, 6), (0.1, 5), (0.02, 2)] {
            let f = LikelihoodField::build(&pts, res, res, depth).expect("field");
            let (w, h) = (f.width, f.height);
            for lvl in 1..=depth {
                let prev = &f.levels[lvl - 1];
                let s = 1usize << (lvl - 1);
                for y in 0..h {
                    for x in 0..w {
                        let (x2, y2) = ((x + s).min(w - 1), (y + s).min(h - 1));
                        let want = prev[y * w + x]
                            .max(prev[y * w + x2])
                            .max(prev[y2 * w + x])
                            .max(prev[y2 * w + x2]);
                        assert_eq!(
                            f.levels[lvl][y * w + x].to_bits(),
                            want.to_bits(),
                            "res {res} depth {depth} level {lvl} cell ({x}, {y})"
                        );
                    }
                }
            }
        }
    }

    /// The room seen from `pose` (sensor frame), every 3rd point.
    fn scan_from(pose: &Isometry2<f64>) -> Vec<Vector2<f64>> {
        let inv = pose.inverse();
        room()
            .iter()
            .step_by(3)
            .map(|p| (inv * nalgebra::Point2::from(*p)).coords)
            .collect()
    }

    #[test]
    fn recovers_offset_pose() {
        let field = reference(3);
        let truth = Isometry2::new(Vector2::new(0.3, -0.2), 0.2);
        let scan = scan_from(&truth);
        let prior = Isometry2::new(Vector2::new(0.1, 0.0), 0.1);
        let m = match_scan(&field, &scan, &prior, &MatcherConfig::default()).expect("match");
        let err = truth.inverse() * m.pose;
        assert!(err.translation.vector.norm() < 0.01, "{:?}", m.pose);
        assert!(
            err.rotation.angle().abs() < 0.2f64.to_radians(),
            "{:?}",
            m.pose
        );
        assert!(m.score > 0.8, "{}", m.score);
        assert!(
            m.covariance[(0, 0)] > 0.0 && m.covariance[(0, 0)] < 1e-4,
            "{}",
            m.covariance
        );
    }

    /// Branch-and-bound must find the same optimum as exhaustive search.
    #[test]
    fn branch_and_bound_equals_brute_force() {
        let field = reference(3);
        let truth = Isometry2::new(Vector2::new(0.27, -0.13), 0.11);
        let scan = scan_from(&truth);
        let prior = Isometry2::new(Vector2::new(0.1, 0.0), 0.05);
        let cfg = MatcherConfig {
            refine_iterations: 0,
            angular_window: 0.1,
            ..Default::default()
        };
        let m = match_scan(&field, &scan, &prior, &cfg).expect("match");
        let cfg0 = MatcherConfig { depth: 0, ..cfg };
        let field0 = reference(0);
        let b = match_scan(&field0, &scan, &prior, &cfg0).expect("match");
        assert!(
            (m.csm_score - b.csm_score).abs() < 1e-6,
            "{} vs {}",
            m.csm_score,
            b.csm_score
        );
        assert!(
            m.nodes < b.nodes / 3,
            "bnb {} vs brute {}",
            m.nodes,
            b.nodes
        );
    }

    /// Keeping several coarse optima: the first is the single search's
    /// optimum, the others are distinct and not better.
    #[test]
    fn top_k_candidates_are_distinct_and_start_with_the_optimum() {
        let field = reference(3);
        let truth = Isometry2::new(Vector2::new(0.27, -0.13), 0.11);
        let scan = scan_from(&truth);
        let prior = Isometry2::new(Vector2::new(0.1, 0.0), 0.05);
        let cfg = MatcherConfig {
            refine_iterations: 0,
            ..Default::default()
        };
        let (one, _) = search_candidates(&field, &scan, &prior, &cfg, 1, 0.0, 0.0);
        let (four, _) = search_candidates(&field, &scan, &prior, &cfg, 4, 0.2, 0.1);
        assert_eq!(one.len(), 1);
        assert_eq!(four.len(), 4);
        assert!((four[0].1 - one[0].1).abs() < 1e-12, "{four:?} vs {one:?}");
        for w in four.windows(2) {
            assert!(w[0].1 >= w[1].1, "{four:?}");
        }
        for (i, a) in four.iter().enumerate() {
            for b in &four[i + 1..] {
                let d = (a.0.translation.vector - b.0.translation.vector).abs();
                let da = (a.0.rotation.angle() - b.0.rotation.angle()).abs();
                assert!(d.x > 0.2 || d.y > 0.2 || da > 0.1, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn normals_of_a_line() {
        let pts: Vec<Vector2<f64>> = (0..5)
            .map(|i| Vector2::new(1.0, f64::from(i) * 0.1))
            .collect();
        let n = scan_normals(&pts);
        assert!(n[0].is_none() && n[4].is_none());
        let n1 = n[1].expect("normal");
        assert!((n1.x.abs() - 1.0).abs() < 1e-12 && n1.y.abs() < 1e-12);
    }

    #[test]
    fn empty_inputs() {
        assert!(LikelihoodField::build(&[], 0.05, 0.05, 3).is_none());
        let field = reference(3);
        assert!(
            match_scan(
                &field,
                &[],
                &Isometry2::identity(),
                &MatcherConfig::default()
            )
            .is_none()
        );
    }
}
