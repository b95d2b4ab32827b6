//! Evaluation of SLAM on a CARMEN log against its corrected poses: relative
//! (per-scan) error, absolute trajectory error after alignment, each beside
//! the same figure for odometry alone, and speed.

use smart_default::SmartDefault;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Isometry2, Vector2};

use super::backend::{BackendConfig, Slam};
use super::carmen::{CarmenError, LogOptions, pose_from, read_log_with};
use super::frontend::{EstimateSource, SlamConfig};
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
    #[error("{}: {scans} laser scans (FLASER or ROBOTLASER1 lines), need at least 2", path.display())]
    TooFewScans {
        /// Log file.
        path: PathBuf,
        /// Scans found.
        scans: usize,
    },
    /// A folder could not be listed.
    #[error("{}: cannot list: {source}", path.display())]
    Dir {
        /// Folder.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A folder holds no `.log` or `.clf` files.
    #[error("{}: no .log or .clf files", path.display())]
    EmptyDir {
        /// Folder.
        path: PathBuf,
    },
}

/// How to evaluate.
#[derive(Debug, Clone, PartialEq, SmartDefault)]
pub struct EvalOptions {
    /// Reading the log (field of view of `FLASER` scans).
    #[default(LogOptions::default())]
    pub log: LogOptions,
    /// Front end.
    #[default(SlamConfig::default())]
    pub slam: SlamConfig,
    /// Back end (loop closure on by default, optimised inline).
    #[default(BackendConfig::default())]
    pub backend: BackendConfig,
    /// Also run the front end alone, for its absolute trajectory error. Default true.
    #[default(true)]
    pub compare_front_end: bool,
    /// Write the map as `<base>.pgm` + `<base>.yaml`.
    pub map_out: Option<PathBuf>,
}

/// The figures of one log.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamEval {
    /// The log.
    pub log: PathBuf,
    /// Scans processed.
    pub scans: usize,
    /// Beams of the first scan.
    pub beams: usize,
    /// Lines skipped (unknown or unused message types, comments).
    pub skipped_lines: usize,
    /// NaN, infinite or negative readings (treated as no reading).
    pub invalid_ranges: usize,
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
    /// The same mean errors for the front end alone (no loop closure, no
    /// optimisation): translation (m); NaN if not run.
    pub front_end_trans_err_mean_m: f64,
    /// Front end alone: mean rotation error (deg); NaN if not run.
    pub front_end_rot_err_mean_deg: f64,
    /// The same errors for the odometry alone: mean translation (m).
    pub odom_trans_err_mean_m: f64,
    /// Odometry alone: mean rotation error (deg).
    pub odom_rot_err_mean_deg: f64,
    /// Absolute trajectory error (RMSE of positions after the best rigid
    /// alignment) of the full pipeline (m).
    pub ate_rmse_m: f64,
    /// Absolute trajectory error of the front end alone, no loop closure (m);
    /// NaN if not run.
    pub ate_front_end_rmse_m: f64,
    /// Absolute trajectory error of the odometry alone (m).
    pub odom_ate_rmse_m: f64,
    /// Scans where the match was rejected and odometry kept.
    pub fallbacks: usize,
    /// Mean quality Q over matched scans.
    pub mean_quality: f64,
    /// Pose-graph nodes.
    pub nodes: usize,
    /// Loop closures accepted.
    pub loop_closures: usize,
    /// Loop-closure matches tried.
    pub loop_closures_tried: usize,
    /// Scans per second of the full pipeline (front end, back end, final map).
    pub scans_per_s: f64,
    /// Scans per second of the front end alone (NaN if not run).
    pub front_end_scans_per_s: f64,
    /// Duration of the log by its scan timestamps (s; 0 if it has none).
    pub log_duration_s: f64,
}

impl SlamEval {
    /// How many times faster than real time the full pipeline ran (NaN without timestamps).
    pub fn realtime_factor(&self) -> f64 {
        if self.log_duration_s > 0.0 && self.scans > 0 {
            self.log_duration_s * self.scans_per_s / self.scans as f64
        } else {
            f64::NAN
        }
    }

    /// The figures on one line: mean relative errors of the pipeline, the front end alone and
    /// odometry, their ATEs, the loop closures and the speeds (pipeline / front end).
    pub fn summary(&self) -> String {
        format!(
            "rel {:5.2} cm {:.3} deg | front end {:5.2} cm {:.3} deg | odometry {:5.2} cm \
             {:.3} deg | ATE {:.3} / {:.3} / {:.3} m | {} closures | {:.0} / {:.0} scans/s",
            self.trans_err_mean_m * 100.0,
            self.rot_err_mean_deg,
            self.front_end_trans_err_mean_m * 100.0,
            self.front_end_rot_err_mean_deg,
            self.odom_trans_err_mean_m * 100.0,
            self.odom_rot_err_mean_deg,
            self.ate_rmse_m,
            self.ate_front_end_rmse_m,
            self.odom_ate_rmse_m,
            self.loop_closures,
            self.scans_per_s,
            self.front_end_scans_per_s,
        )
    }
}

/// Translation (m) and rotation (rad) of `a⁻¹·b`.
fn rel_err(a: &Isometry2<f64>, b: &Isometry2<f64>) -> (f64, f64) {
    let e = a.inverse() * b;
    (e.translation.vector.norm(), e.rotation.angle().abs())
}

/// Per pair of consecutive scans, the translation (m) and rotation (deg)
/// error of the estimated motion against the reference motion.
fn relative_errors(est: &[Isometry2<f64>], truth: &[Isometry2<f64>]) -> (Vec<f64>, Vec<f64>) {
    let n = est.len().min(truth.len());
    (1..n)
        .map(|k| {
            let gt = truth[k - 1].inverse() * truth[k];
            let (t, r) = rel_err(&gt, &(est[k - 1].inverse() * est[k]));
            (t, r.to_degrees())
        })
        .unzip()
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

/// Absolute trajectory error: RMSE of the positions of `est` against `truth`
/// after the rigid transform (rotation and translation, no scale) that best
/// aligns them in the least-squares sense (Umeyama 1991 in 2D).
pub fn ate_rmse(est: &[Isometry2<f64>], truth: &[Isometry2<f64>]) -> f64 {
    let n = est.len().min(truth.len());
    if n == 0 {
        return 0.0;
    }
    let e: Vec<Vector2<f64>> = est[..n].iter().map(|p| p.translation.vector).collect();
    let t: Vec<Vector2<f64>> = truth[..n].iter().map(|p| p.translation.vector).collect();
    let ce = e.iter().sum::<Vector2<f64>>() / n as f64;
    let ct = t.iter().sum::<Vector2<f64>>() / n as f64;
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (a, b) in e.iter().zip(&t) {
        let (a, b) = (a - ce, b - ct);
        sxx += a.x * b.x + a.y * b.y;
        sxy += a.x * b.y - a.y * b.x;
    }
    let rot = nalgebra::Rotation2::new(sxy.atan2(sxx));
    let s: f64 = e
        .iter()
        .zip(&t)
        .map(|(a, b)| (rot * (a - ce) + ct - b).norm_squared())
        .sum();
    (s / n as f64).sqrt()
}

/// [`eval_slam_with`] with default options and an optional map output.
pub fn eval_slam(log_path: &Path, out_map: Option<&Path>) -> Result<SlamEval, SlamEvalError> {
    eval_slam_with(
        log_path,
        &EvalOptions {
            map_out: out_map.map(Path::to_path_buf),
            ..EvalOptions::default()
        },
    )
}

/// Runs SLAM over a CARMEN log and compares it with the log's corrected poses.
///
/// The prior is the log's raw odometry ([`super::CarmenLog::odometry_deltas`]),
/// never the corrected poses; SLAM starts at the first corrected pose only to
/// put the map in the same frame. Relative error: for each pair of
/// consecutive scans, the estimated motion against the corrected one.
/// Absolute error: [`ate_rmse`] of the final (optimised) trajectory.
pub fn eval_slam_with(log_path: &Path, opts: &EvalOptions) -> Result<SlamEval, SlamEvalError> {
    let log = read_log_with(log_path, &opts.log)?;
    let scans: Vec<_> = log.scans().collect();
    if scans.len() < 2 {
        return Err(SlamEvalError::TooFewScans {
            path: log_path.to_path_buf(),
            scans: scans.len(),
        });
    }
    let deltas = log.odometry_deltas();
    let truth: Vec<Isometry2<f64>> = scans.iter().map(|s| pose_from(s.laser_pose)).collect();
    let run = |backend: BackendConfig| {
        let mut slam = Slam::new(opts.slam, backend, truth[0]);
        let (mut fallbacks, mut q) = (0, Vec::new());
        let t0 = Instant::now();
        for (s, d) in scans.iter().zip(&deltas) {
            let e = slam.process(d, &s.laser, &s.ranges);
            match e.source {
                EstimateSource::Matched => q.push(e.quality),
                EstimateSource::OdometryFallback => fallbacks += 1,
                EstimateSource::Prior => {}
            }
        }
        slam.finish();
        let rate = scans.len() as f64 / t0.elapsed().as_secs_f64().max(1e-9);
        (slam, fallbacks, q, rate)
    };
    let (slam, fallbacks, q, scans_per_s) = run(opts.backend);
    let est = slam.trajectory();
    let (fe_ate, fe_rate, fe_rel) = if opts.compare_front_end && opts.backend.loop_closure {
        let (fe, _, _, rate) = run(BackendConfig {
            loop_closure: false,
            ..opts.backend
        });
        let fe_est = fe.trajectory();
        (
            ate_rmse(&fe_est, &truth),
            rate,
            relative_errors(&fe_est, &truth),
        )
    } else if !opts.backend.loop_closure {
        (
            ate_rmse(&est, &truth),
            scans_per_s,
            relative_errors(&est, &truth),
        )
    } else {
        (f64::NAN, f64::NAN, (vec![f64::NAN], vec![f64::NAN]))
    };
    let mut odom = vec![truth[0]];
    for d in &deltas[1..] {
        let last = odom[odom.len() - 1];
        odom.push(last * d);
    }
    let (te, re) = relative_errors(&est, &truth);
    let (ote, ore) = relative_errors(&odom, &truth);
    if let (Some(base), Some(grid)) = (&opts.map_out, slam.map().to_occupancy_grid()) {
        write_pgm_yaml(&grid, base)?;
    }
    let stats = slam.stats();
    let ts: Vec<f64> = scans.iter().map(|s| s.timestamp).collect();
    let duration = ts.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - ts.iter().copied().fold(f64::INFINITY, f64::min);
    Ok(SlamEval {
        log: log_path.to_path_buf(),
        scans: scans.len(),
        beams: scans[0].ranges.len(),
        skipped_lines: log.skipped_lines(),
        invalid_ranges: log.invalid_ranges,
        trans_err_mean_m: mean(&te),
        trans_err_p95_m: p95(&te),
        rot_err_mean_deg: mean(&re),
        rot_err_p95_deg: p95(&re),
        trans_err_max_m: te.iter().copied().fold(0.0, f64::max),
        rot_err_max_deg: re.iter().copied().fold(0.0, f64::max),
        front_end_trans_err_mean_m: mean(&fe_rel.0),
        front_end_rot_err_mean_deg: mean(&fe_rel.1),
        odom_trans_err_mean_m: mean(&ote),
        odom_rot_err_mean_deg: mean(&ore),
        ate_rmse_m: ate_rmse(&est, &truth),
        ate_front_end_rmse_m: fe_ate,
        odom_ate_rmse_m: ate_rmse(&odom, &truth),
        fallbacks,
        mean_quality: mean(&q),
        nodes: stats.nodes,
        loop_closures: stats.closures,
        loop_closures_tried: stats.closures_tried,
        scans_per_s,
        front_end_scans_per_s: fe_rate,
        log_duration_s: if duration.is_finite() && duration > 0.0 {
            duration
        } else {
            0.0
        },
    })
}

/// The `.log` and `.clf` files of a folder, sorted by name.
pub fn logs_in(dir: &Path) -> Result<Vec<PathBuf>, SlamEvalError> {
    let rd = std::fs::read_dir(dir).map_err(|source| SlamEvalError::Dir {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut out: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .is_some_and(|x| x.eq_ignore_ascii_case("log") || x.eq_ignore_ascii_case("clf"))
        })
        .collect();
    out.sort();
    if out.is_empty() {
        return Err(SlamEvalError::EmptyDir {
            path: dir.to_path_buf(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ate_is_invariant_to_a_rigid_motion() {
        let truth: Vec<Isometry2<f64>> = (0..20)
            .map(|k| Isometry2::new(Vector2::new(k as f64 * 0.3, (k as f64 * 0.4).sin()), 0.0))
            .collect();
        let moved: Vec<_> = truth
            .iter()
            .map(|p| Isometry2::new(Vector2::new(3.0, -1.0), 0.7) * p)
            .collect();
        assert!(ate_rmse(&moved, &truth) < 1e-9);
        let mut bent = moved.clone();
        bent[10].translation.vector.x += 1.0;
        let a = ate_rmse(&bent, &truth);
        assert!(a > 0.1 && a < 1.0 / (20f64).sqrt() + 1e-9, "{a}");
    }
}
