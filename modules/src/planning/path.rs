//! Planning's path geometry: the followed path (projection, the point at an arc length) and
//! the nearest acceptable cell; the planned path's publisher.

use hng_runtime::msg::{FrameId, Header, PathInfo, Pose2D, closest_on_segment};
use hng_runtime::{Context, ModuleResult, SlicePublisher};

/// Most poses a published path holds; a longer path is thinned (its last pose kept).
pub(crate) const MAX_PATH_POSES: usize = 2048;

/// Publishes Planning's whole path ([`PathInfo`] on `planning/path`) when it changes: a new
/// plan, another goal, or no path any more (an empty path).
pub(crate) struct PathOut {
    out: SlicePublisher<PathInfo>,
    /// What was published last: goal id, number of points, first and last point.
    sent: Option<(u32, usize, [f64; 2], [f64; 2])>,
}

impl std::fmt::Debug for PathOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PathOut").field("sent", &self.sent).finish()
    }
}

impl PathOut {
    pub(crate) fn new(ctx: &mut Context, channel: &str) -> ModuleResult<PathOut> {
        Ok(PathOut {
            out: ctx.slice_publisher(channel, MAX_PATH_POSES)?,
            sent: None,
        })
    }

    /// The path now (`points` in `map`, empty when none) of goal `goal_id` (0: none).
    pub(crate) fn update(
        &mut self,
        goal_id: u32,
        points: &[[f64; 2]],
        length_m: f64,
    ) -> ModuleResult {
        let key = (
            goal_id,
            points.len(),
            points.first().copied().unwrap_or_default(),
            points.last().copied().unwrap_or_default(),
        );
        if self.sent == Some(key) {
            return Ok(());
        }
        let poses = path_poses(points);
        let info = PathInfo {
            header: Header {
                frame_id: FrameId::MAP,
                ..Header::default()
            },
            goal_id: if points.is_empty() { 0 } else { goal_id },
            length_m,
        };
        self.out.publish_copy(info, &poses)?;
        self.sent = Some(key);
        Ok(())
    }
}

/// The poses of a path (heading: along the next segment), at most [`MAX_PATH_POSES`].
pub(crate) fn path_poses(points: &[[f64; 2]]) -> Vec<Pose2D> {
    let step = points.len().div_ceil(MAX_PATH_POSES).max(1);
    let mut keep: Vec<[f64; 2]> = points.iter().step_by(step).copied().collect();
    if let Some(last) = points.last()
        && keep.last() != Some(last)
    {
        if keep.len() == MAX_PATH_POSES {
            keep.pop();
        }
        keep.push(*last);
    }
    let heading = |a: [f64; 2], b: [f64; 2]| (b[1] - a[1]).atan2(b[0] - a[0]);
    (0..keep.len())
        .map(|i| {
            let p = keep[i];
            let theta = match (keep.get(i + 1), i.checked_sub(1).map(|j| keep[j])) {
                (Some(&next), _) => heading(p, next),
                (None, Some(prev)) => heading(prev, p),
                (None, None) => 0.0,
            };
            Pose2D::new(p[0], p[1], theta)
        })
        .collect()
}

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
            let (t, d) = closest_on_segment(p, self.points[i], self.points[i + 1]);
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
