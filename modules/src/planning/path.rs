//! Planning's path geometry: the followed path (projection, the point at an arc length) and
//! the nearest acceptable cell.

#[derive(Debug, Clone)]
pub(crate) struct PathState {
    pub(crate) points: Vec<[f64; 2]>,
    pub(crate) cum: Vec<f64>,
    pub(crate) seg: usize,
}

impl PathState {
    pub(crate) fn new(points: Vec<[f64; 2]>) -> PathState {
        let mut cum = vec![0.0];
        for w in points.windows(2) {
            let l = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            cum.push(cum.last().copied().unwrap_or(0.0) + l);
        }
        PathState {
            points,
            cum,
            seg: 0,
        }
    }

    pub(crate) fn total(&self) -> f64 {
        self.cum.last().copied().unwrap_or(0.0)
    }

    /// Projects `p` on the path from the current segment on; returns (arc length, distance).
    pub(crate) fn project(&mut self, p: [f64; 2]) -> (f64, f64) {
        let n = self.points.len();
        if n < 2 {
            let q = self.points.first().copied().unwrap_or(p);
            return (0.0, (q[0] - p[0]).hypot(q[1] - p[1]));
        }
        let mut best = (f64::INFINITY, self.seg, 0.0);
        for i in self.seg..n - 1 {
            let (a, b) = (self.points[i], self.points[i + 1]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let l2 = dx * dx + dy * dy;
            let t = if l2 > 0.0 {
                (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let d = (a[0] + t * dx - p[0]).hypot(a[1] + t * dy - p[1]);
            if d < best.0 {
                best = (d, i, t);
            }
        }
        self.seg = best.1;
        let seg_len = self.cum[best.1 + 1] - self.cum[best.1];
        (self.cum[best.1] + best.2 * seg_len, best.0)
    }

    /// The point at arc length `s` (clamped) and the heading of its segment.
    pub(crate) fn at(&self, s: f64) -> ([f64; 2], f64) {
        let n = self.points.len();
        if n < 2 {
            return (self.points.first().copied().unwrap_or([0.0, 0.0]), 0.0);
        }
        let s = s.clamp(0.0, self.total());
        let i = match self.cum.iter().position(|&c| c > s) {
            Some(k) => k.saturating_sub(1).min(n - 2),
            None => n - 2,
        };
        let (a, b) = (self.points[i], self.points[i + 1]);
        let l = self.cum[i + 1] - self.cum[i];
        let t = if l > 0.0 { (s - self.cum[i]) / l } else { 1.0 };
        let heading = (b[1] - a[1]).atan2(b[0] - a[0]);
        (
            [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])],
            heading,
        )
    }
}

/// The cell nearest to `c` (Chebyshev rings up to `max_ring`) that `ok` accepts.
pub(crate) fn nearest_cell(
    c: (i64, i64),
    max_ring: i64,
    ok: impl Fn(i64, i64) -> bool,
) -> Option<(i64, i64)> {
    let mut best: Option<((i64, i64), i64)> = None;
    for ring in 0..=max_ring {
        for dx in -ring..=ring {
            for dy in -ring..=ring {
                if dx.abs().max(dy.abs()) != ring {
                    continue;
                }
                let (x, y) = (c.0 + dx, c.1 + dy);
                let d2 = dx * dx + dy * dy;
                if ok(x, y) && best.is_none_or(|(_, bd)| d2 < bd) {
                    best = Some(((x, y), d2));
                }
            }
        }
        if best.is_some() {
            break;
        }
    }
    best.map(|(c, _)| c)
}
