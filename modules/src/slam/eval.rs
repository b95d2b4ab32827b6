//! Evaluation of the front end on a CARMEN log against its corrected poses.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Isometry2;

use super::carmen::{CarmenError, pose_from, read_log};
use super::frontend::{EstimateSource, SlamConfig, SlamFrontEnd};
use super::mapping::{MapWriteError, write_pgm_yaml};

/// Why [`eval_slam`] failed.
#[derive(Debug, thiserror::Error)]
pub enum SlamEvalError {
    /// The log could not be read or parsed.
    #[error(transparent)]
    Log(#[from] CarmenError),
    /// The map could not be written.
    #[error(transparent)]
    Map(#[from] MapWriteError),
    /// The log has fewer than two scans.
    #[error("{}: {scans} laser scans, need at least 2", path.display())]
    TooFewScans {
        /// Log file.
        path: PathBuf,
        /// Scans found.
        scans: usize,
    },
}

/// Relative-motion errors of the front end against the log's corrected poses.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamEval {
    /// Scans processed.
    pub scans: usize,
    /// Mean translation error of the motion between consecutive scans (m).
    pub trans_err_mean_m: f64,
    /// 95th percentile of the translation error (m).
    pub trans_err_p95_m: f64,
    /// Mean rotation error of the motion between consecutive scans (deg).
    pub rot_err_mean_deg: f64,
    /// 95th percentile of the rotation error (deg).
    pub rot_err_p95_deg: f64,
    /// Largest translation error (m).
    pub trans_err_max_m: f64,
    /// Largest rotation error (deg).
    pub rot_err_max_deg: f64,
    /// The same errors for the odometry prior alone: mean translation (m).
    pub odom_trans_err_mean_m: f64,
    /// Odometry prior alone: mean rotation error (deg).
    pub odom_rot_err_mean_deg: f64,
    /// Scans where the match was rejected and odometry kept.
    pub fallbacks: usize,
    /// Mean quality Q over matched scans.
    pub mean_quality: f64,
    /// Mean wall time per scan (matching + mapping), microseconds.
    pub mean_us_per_scan: f64,
}

/// Translation (m) and rotation (rad) of `a⁻¹·b`.
fn rel_err(a: &Isometry2<f64>, b: &Isometry2<f64>) -> (f64, f64) {
    let e = a.inverse() * b;
    (e.translation.vector.norm(), e.rotation.angle().abs())
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// Nearest-rank 95th percentile.
fn p95(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return 0.0;
    }
    let k = ((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1;
    s[k]
}

/// Runs [`SlamFrontEnd`] with default parameters over a CARMEN log.
///
/// The prior is the log's raw odometry ([`super::CarmenLog::odometry_deltas`]),
/// never the corrected poses; the front end starts at the first corrected
/// pose only to put the map in the same frame. For each pair of consecutive
/// scans `k−1, k`, the estimated relative motion is compared with the relative
/// motion of the corrected laser poses. Optionally writes the map as
/// `<out_map>.pgm` + `<out_map>.yaml`.
pub fn eval_slam(log_path: &Path, out_map: Option<&Path>) -> Result<SlamEval, SlamEvalError> {
    eval_slam_with(log_path, out_map, SlamConfig::default())
}

/// [`eval_slam`] with explicit parameters.
pub fn eval_slam_with(
    log_path: &Path,
    out_map: Option<&Path>,
    cfg: SlamConfig,
) -> Result<SlamEval, SlamEvalError> {
    let log = read_log(log_path)?;
    let scans: Vec<_> = log.scans().collect();
    if scans.len() < 2 {
        return Err(SlamEvalError::TooFewScans {
            path: log_path.to_path_buf(),
            scans: scans.len(),
        });
    }
    let deltas = log.odometry_deltas();
    let truth: Vec<Isometry2<f64>> = scans.iter().map(|s| pose_from(s.laser_pose)).collect();
    let mut fe = SlamFrontEnd::new(cfg, truth[0]);
    let mut est = Vec::with_capacity(scans.len());
    let mut fallbacks = 0;
    let mut q = Vec::new();
    let t0 = Instant::now();
    for (s, d) in scans.iter().zip(&deltas) {
        let e = fe.process(d, &s.ranges);
        match e.source {
            EstimateSource::Matched => q.push(e.quality),
            EstimateSource::OdometryFallback => fallbacks += 1,
            EstimateSource::Prior => {}
        }
        est.push(e.pose);
    }
    let mean_us_per_scan = t0.elapsed().as_secs_f64() * 1e6 / scans.len() as f64;
    let (mut te, mut re, mut ote, mut ore) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for k in 1..scans.len() {
        let gt = truth[k - 1].inverse() * truth[k];
        let (t, r) = rel_err(&gt, &(est[k - 1].inverse() * est[k]));
        te.push(t);
        re.push(r.to_degrees());
        let (t, r) = rel_err(&gt, &deltas[k]);
        ote.push(t);
        ore.push(r.to_degrees());
    }
    if let (Some(base), Some(grid)) = (out_map, fe.map().to_occupancy_grid()) {
        write_pgm_yaml(&grid, base)?;
    }
    Ok(SlamEval {
        scans: scans.len(),
        trans_err_mean_m: mean(&te),
        trans_err_p95_m: p95(&te),
        rot_err_mean_deg: mean(&re),
        rot_err_p95_deg: p95(&re),
        trans_err_max_m: te.iter().copied().fold(0.0, f64::max),
        rot_err_max_deg: re.iter().copied().fold(0.0, f64::max),
        odom_trans_err_mean_m: mean(&ote),
        odom_rot_err_mean_deg: mean(&ore),
        fallbacks,
        mean_quality: mean(&q),
        mean_us_per_scan,
    })
}
