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
//! A summary goes to stderr: the error's distribution and bias, the reference's displacement,
//! the laser's offset in the odometry frame, and each source's own noise by the
//! three-cornered hat (reference, front end, odometry: docs/slam.md, diagnosis).
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
    if let Some(f) = env::<u8>("UNKNOWN_FLOOR") {
        cfg.wide.unknown_floor = f == 1;
    }
    if let Some(u) = env("UNKNOWN") {
        cfg.unknown_score = Some(u);
    } else if std::env::var("UNKNOWN").is_ok_and(|v| v == "off") {
        cfg.unknown_score = None;
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
    let mut rows: Vec<Row> = Vec::new();
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
            rows.push(Row {
                gt,
                est,
                odo: *d,
                ref_icp: icp,
                resid,
            });
        }
        prev = e.pose;
    }
    summary(&rows);
    Ok(())
}

/// One consecutive pair: the reference, front-end and odometry steps, where the data put
/// the scan given the reference's map, and the residual there.
struct Row {
    gt: Isometry2<f64>,
    est: Isometry2<f64>,
    odo: Isometry2<f64>,
    ref_icp: Isometry2<f64>,
    resid: f64,
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// Value at quantile `q` (nearest rank) of `v`.
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s.get(((q * s.len() as f64) as usize).min(s.len().saturating_sub(1)))
        .copied()
        .unwrap_or(f64::NAN)
}

/// The offset `o` (sensor position in the odometry frame) that best explains `a`'s steps
/// as `o⁻¹·b·o` in translation (linear least squares: `a_t − b_t = (R(θ_b) − I)·o`).
fn fit_offset(pairs: &[(Isometry2<f64>, Isometry2<f64>)]) -> Vector2<f64> {
    let (mut m, mut v) = (nalgebra::Matrix2::zeros(), Vector2::zeros());
    for (a, b) in pairs {
        let j = b.rotation.to_rotation_matrix().into_inner() - nalgebra::Matrix2::identity();
        let r = a.translation.vector - b.translation.vector;
        m += j.transpose() * j;
        v += j.transpose() * r;
    }
    m.try_inverse()
        .map(|i| i * v)
        .unwrap_or_else(Vector2::zeros)
}

/// Three-cornered hat: the mean squares of the pairwise differences of three independent
/// measurements give each one's own: `σ_a² = (V_ab + V_ac − V_bc) / 2`. Per component
/// (x cm, y cm, θ deg) of the steps `a`, `b`, `c`; a negative estimate is printed as such.
fn hat(a: &[Isometry2<f64>], b: &[Isometry2<f64>], c: &[Isometry2<f64>]) -> [[f64; 3]; 3] {
    let comp = |p: &Isometry2<f64>, q: &Isometry2<f64>| {
        let d = p.inverse() * q;
        [
            d.translation.x * 100.0,
            d.translation.y * 100.0,
            d.rotation.angle().to_degrees(),
        ]
    };
    let ms = |x: &[Isometry2<f64>], y: &[Isometry2<f64>], i: usize| {
        mean(
            &x.iter()
                .zip(y)
                .map(|(p, q)| comp(p, q)[i].powi(2))
                .collect::<Vec<_>>(),
        )
    };
    let sgn = |v: f64| v.signum() * v.abs().sqrt();
    let (ab, ac, bc): (Vec<f64>, Vec<f64>, Vec<f64>) = (
        (0..3).map(|i| ms(a, b, i)).collect(),
        (0..3).map(|i| ms(a, c, i)).collect(),
        (0..3).map(|i| ms(b, c, i)).collect(),
    );
    [
        std::array::from_fn(|i| sgn((ab[i] + ac[i] - bc[i]) / 2.0)),
        std::array::from_fn(|i| sgn((ab[i] + bc[i] - ac[i]) / 2.0)),
        std::array::from_fn(|i| sgn((ac[i] + bc[i] - ab[i]) / 2.0)),
    ]
}

/// Prints, on stderr, where the per-scan error comes from (docs/slam.md, diagnosis).
fn summary(rows: &[Row]) {
    if rows.is_empty() {
        return;
    }
    let err: Vec<Isometry2<f64>> = rows.iter().map(|r| r.gt.inverse() * r.est).collect();
    let et: Vec<f64> = err
        .iter()
        .map(|e| e.translation.vector.norm() * 100.0)
        .collect();
    let er: Vec<f64> = err
        .iter()
        .map(|e| e.rotation.angle().abs().to_degrees())
        .collect();
    let mut sorted = et.clone();
    sorted.sort_by(|a, b| b.total_cmp(a));
    let worst = 30.min(sorted.len() - 1);
    eprintln!(
        "front end: mean {:.2} cm {:.3} deg; p50 {:.2} p90 {:.2} max {:.2} cm; without the worst {worst} scans {:.2} cm",
        mean(&et),
        mean(&er),
        quantile(&et, 0.5),
        quantile(&et, 0.9),
        sorted[0],
        mean(&sorted[worst..])
    );
    eprintln!(
        "signed mean error (scan frame): along {:+.2} cm, side {:+.2} cm, {:+.3} deg; mean |along| {:.2} |side| {:.2} cm",
        mean(
            &err.iter()
                .map(|e| e.translation.x * 100.0)
                .collect::<Vec<_>>()
        ),
        mean(
            &err.iter()
                .map(|e| e.translation.y * 100.0)
                .collect::<Vec<_>>()
        ),
        mean(
            &err.iter()
                .map(|e| e.rotation.angle().to_degrees())
                .collect::<Vec<_>>()
        ),
        mean(
            &err.iter()
                .map(|e| e.translation.x.abs() * 100.0)
                .collect::<Vec<_>>()
        ),
        mean(
            &err.iter()
                .map(|e| e.translation.y.abs() * 100.0)
                .collect::<Vec<_>>()
        ),
    );
    let disp: Vec<f64> = rows
        .iter()
        .map(|r| r.ref_icp.translation.vector.norm() * 100.0)
        .collect();
    eprintln!(
        "reference poses against a map of the reference's own previous scans: displaced by the data {:.2} cm {:.3} deg mean (p50 {:.2} cm); residual {:.1} mm",
        mean(&disp),
        mean(
            &rows
                .iter()
                .map(|r| r.ref_icp.rotation.angle().abs().to_degrees())
                .collect::<Vec<_>>()
        ),
        quantile(&disp, 0.5),
        mean(
            &rows
                .iter()
                .map(|r| r.resid * 1000.0)
                .filter(|v| v.is_finite())
                .collect::<Vec<_>>()
        ),
    );
    let o = fit_offset(&rows.iter().map(|r| (r.est, r.odo)).collect::<Vec<_>>());
    let oi = Isometry2::new(o, 0.0);
    let odo: Vec<Isometry2<f64>> = rows.iter().map(|r| oi.inverse() * r.odo * oi).collect();
    let oe = fit_offset(&rows.iter().map(|r| (r.est, r.gt)).collect::<Vec<_>>());
    eprintln!(
        "frame offsets: laser in the odometry frame ({:.1}, {:.1}) cm; reference frame vs the front end's ({:.1}, {:.1}) cm",
        o.x * 100.0,
        o.y * 100.0,
        oe.x * 100.0,
        oe.y * 100.0
    );
    let still: Vec<usize> = (0..rows.len())
        .filter(|&i| rows[i].odo.translation.vector.norm() < 0.05)
        .collect();
    for (name, idx) in [
        ("all pairs", (0..rows.len()).collect::<Vec<_>>()),
        ("turns in place", still),
    ] {
        if idx.len() < 10 {
            continue;
        }
        let g: Vec<_> = idx.iter().map(|&i| rows[i].gt).collect();
        let e: Vec<_> = idx.iter().map(|&i| rows[i].est).collect();
        let d: Vec<_> = idx.iter().map(|&i| odo[i]).collect();
        let h = hat(&g, &e, &d);
        eprintln!(
            "three-cornered hat, {name} ({}): own noise rms along/side cm, deg: reference {:.2}/{:.2}/{:.2}, front end {:.2}/{:.2}/{:.2}, odometry (offset-corrected) {:.2}/{:.2}/{:.2}",
            idx.len(),
            h[0][0],
            h[0][1],
            h[0][2],
            h[1][0],
            h[1][1],
            h[1][2],
            h[2][0],
            h[2][1],
            h[2][2]
        );
    }
}
