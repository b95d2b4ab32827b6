//! Per-scan diagnostics of the SLAM front end on a CARMEN log, as CSV on stdout (one row per
//! consecutive pair of scans), for finding where the per-scan error comes from.
//!
//! `cargo run --release -p hng-modules --example slam_diag -- LOG > scans.csv`
//!
//! Columns: `k`; the reference step from the corrected log `gt_x gt_y gt_th` (scan k in the
//! frame of scan k−1, m and rad); the front end's step `est_*`; the odometry's step `odo_*`;
//! the match `score`, `source` and the largest standard deviation of its covariance
//! (`cov_max_m`); and, as a check of the reference itself, where the data put scan k when
//! the local map is built from the *corrected* poses of the previous scans and matching
//! starts at scan k's corrected pose: `ref_icp_*` (the ICP refinement alone) and `ref_csm_*`
//! (correlative search + ICP), each as scan k's displacement from its corrected pose, in
//! scan k's frame. With a perfect reference and an unbiased matcher these are zero.
//!
//! `ref_resid_mm` is the mean point-to-line distance of scan k's points to that map after the
//! refinement (distances capped at 10 cm): the smaller, the better the beam geometry and the
//! reference agree with the scans (compare geometry variants with it).
//!
//! Environment: `FOV` (degrees), `ANGLE_OFFSET` (degrees added to every beam's angle), and
//! the front end's `LOCAL`, `MATCH_RANGE`, `UNKNOWN`, `CANDS` as in `slam_eval`; `OFFSET_X` (m) moves the
//! reference poses forward along the heading.

use std::path::PathBuf;

use hng_modules::slam::{
    EstimateSource, LogOptions, MatcherConfig, ReferenceMap, SlamConfig, SlamFrontEnd, match_scan,
    pose_from, read_log_with, refine, scan_normals,
};
use nalgebra::{Isometry2, Point2, Vector2};

fn env<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

fn xyt(p: &Isometry2<f64>) -> String {
    format!(
        "{:.5},{:.5},{:.6}",
        p.translation.x,
        p.translation.y,
        p.rotation.angle()
    )
}

/// Mean point-to-line distance (m, each capped at 10 cm) of `pts` at `pose` to `r`, over
/// the points with a nearby map point that has a normal.
fn residual(r: &ReferenceMap, pts: &[Vector2<f64>], pose: &Isometry2<f64>) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for p in pts {
        let q = (pose * Point2::from(*p)).coords;
        if let Some(k) = r.field.nearest(&q)
            && let Some(nrm) = r.normals[k]
        {
            sum += nrm.dot(&(q - r.points[k])).abs().min(0.1);
            n += 1;
        }
    }
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let log = PathBuf::from(
        std::env::args()
            .nth(1)
            .ok_or("usage: slam_diag LOG > scans.csv")?,
    );
    let mut lopts = LogOptions::default();
    if let Some(d) = env::<f64>("FOV") {
        lopts.fov = Some(d.to_radians());
    }
    let mut cfg = SlamConfig::default();
    if let Some(n) = env("LOCAL") {
        cfg.local_map_scans = n;
    }
    if let Some(r) = env("MATCH_RANGE") {
        cfg.match_max_range = r;
    }
    let angle_offset = env::<f64>("ANGLE_OFFSET").unwrap_or(0.0).to_radians();
    if let Some(u) = env("UNKNOWN") {
        cfg.unknown_score = Some(u);
    }
    if let Some(c) = env("CANDS") {
        cfg.wide.candidates = c;
    }
    let offset = Isometry2::new(Vector2::new(env("OFFSET_X").unwrap_or(0.0), 0.0), 0.0);
    let log = read_log_with(&log, &lopts)?;
    let scans: Vec<_> = log
        .scans()
        .cloned()
        .map(|mut s| {
            s.laser.angle_min += angle_offset;
            s
        })
        .collect();
    let deltas = log.odometry_deltas();
    let truth: Vec<Isometry2<f64>> = scans
        .iter()
        .map(|s| pose_from(s.laser_pose) * offset)
        .collect();
    let pts: Vec<Vec<Vector2<f64>>> = scans
        .iter()
        .map(|s| {
            s.laser
                .points(&s.ranges)
                .into_iter()
                .filter(|p| p.norm() <= cfg.match_max_range)
                .collect()
        })
        .collect();
    let mcfg = MatcherConfig::default();
    let mut fe = SlamFrontEnd::new(cfg, truth[0]);
    let mut prev = truth[0];
    println!(
        "k,gt_x,gt_y,gt_th,est_x,est_y,est_th,odo_x,odo_y,odo_th,score,source,cov_max_m,\
         ref_icp_x,ref_icp_y,ref_icp_th,ref_csm_x,ref_csm_y,ref_csm_th,ref_resid_mm"
    );
    for (k, (s, d)) in scans.iter().zip(&deltas).enumerate() {
        let e = fe.process_scan(d, &s.laser, &s.ranges);
        if k > 0 {
            let gt = truth[k - 1].inverse() * truth[k];
            let est = prev.inverse() * e.pose;
            let cov_max = e
                .covariance
                .fixed_view::<2, 2>(0, 0)
                .symmetric_eigenvalues();
            let cov_max = cov_max.max().max(0.0).sqrt();
            let from = k.saturating_sub(cfg.local_map_scans);
            let (mut mp, mut mn) = (Vec::new(), Vec::new());
            for j in from..k {
                let rot = truth[j].rotation;
                for (p, n) in pts[j].iter().zip(scan_normals(&pts[j])) {
                    mp.push((truth[j] * Point2::from(*p)).coords);
                    mn.push(n.map(|n| rot * n));
                }
            }
            let (icp, csm, resid) = match ReferenceMap::build(mp, mn, &mcfg) {
                Some(r) => {
                    let (p, _) = refine(&r, &pts[k], &truth[k], mcfg.refine_iterations);
                    let c = match_scan(&r, &pts[k], &truth[k], &mcfg)
                        .map(|m| m.pose)
                        .unwrap_or(truth[k]);
                    (
                        truth[k].inverse() * p,
                        truth[k].inverse() * c,
                        residual(&r, &pts[k], &p),
                    )
                }
                None => (Isometry2::identity(), Isometry2::identity(), f64::NAN),
            };
            let source = match e.source {
                EstimateSource::Matched => "matched",
                EstimateSource::OdometryFallback => "odometry",
                EstimateSource::Prior => "prior",
            };
            println!(
                "{k},{},{},{},{:.4},{source},{:.4},{},{},{:.3}",
                xyt(&gt),
                xyt(&est),
                xyt(d),
                e.score,
                cov_max,
                xyt(&icp),
                xyt(&csm),
                resid * 1000.0
            );
        }
        prev = e.pose;
    }
    Ok(())
}
