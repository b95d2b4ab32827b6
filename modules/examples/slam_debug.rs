//! Per-scan diagnostics of the front end on a CARMEN log: prints the scans whose relative
//! error exceeds a threshold, with the match score and source.
//!
//! `cargo run --release -p hng-modules --example slam_debug -- <log> [wide_below] [thresh_m]`
//!
//! Front end alone (no loop closure) unless `LC=1`: then the whole pipeline, and at the end
//! each accepted loop closure's error against the corrected log and the final trajectory's
//! mean per-scan error. Parameters to try, from the environment: `WIDE_WEIGHT`,
//! `MATCH_RANGE`, `FUSE` (1: fuse with odometry), `FUSE_SCALE`, `ODOM_NOISE`, `LOCAL`
//! (local-map scans), `CANDS` (wide-search candidates), `SIGMA` (field width), `TW` (prior
//! penalty weights), `UNKNOWN_FLOOR` (0 or 1), `RERENDER` (m, the back end's
//! `rerender_after`). Ends with the mean per-scan error.

use std::path::PathBuf;
use std::str::FromStr;

use hng_modules::slam::{BackendConfig, LikelihoodField, Slam, SlamConfig, pose_from, read_log};
use nalgebra::{Isometry2, Point2, Vector2};

/// Sets `v` from the environment variable `name`, when it is set.
fn env<T: FromStr>(name: &str, v: &mut T) -> Result<(), T::Err> {
    if let Ok(s) = std::env::var(name) {
        *v = s.parse()?;
    }
    Ok(())
}

/// Sets `v` from the environment variable `name` (`1`: true), when it is set.
fn env_flag(name: &str, v: &mut bool) {
    if let Ok(s) = std::env::var(name) {
        *v = s == "1";
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let log = PathBuf::from(
        args.next()
            .ok_or("usage: slam_debug <log> [wide_below] [thresh_m]")?,
    );
    let mut cfg = SlamConfig::default();
    if let Some(w) = args.next() {
        cfg.wide_below_score = w.parse()?;
    }
    env("WIDE_WEIGHT", &mut cfg.wide.weight)?;
    env("MATCH_RANGE", &mut cfg.match_max_range)?;
    env_flag("FUSE", &mut cfg.fuse_odometry);
    env("ODOM_NOISE", &mut cfg.odom_trans_noise)?;
    env("FUSE_SCALE", &mut cfg.match_information_scale)?;
    env_flag("CV", &mut cfg.constant_velocity_hypothesis);
    env("FREE", &mut cfg.free_space_penalty)?;
    env("CANDS", &mut cfg.wide.candidates)?;
    env("LOCAL", &mut cfg.local_map_scans)?;
    env("SIGMA", &mut cfg.matcher.sigma)?;
    env_flag("UNKNOWN_FLOOR", &mut cfg.wide.unknown_floor);
    let loop_closure = std::env::var("LC").is_ok_and(|v| v == "1");
    env("TW", &mut cfg.matcher.translation_weight)?;
    env("TW", &mut cfg.matcher.rotation_weight)?;
    let thresh: f64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(0.1);
    let log = read_log(&log)?;
    let scans: Vec<_> = log.scans().collect();
    let deltas = log.odometry_deltas();
    let truth: Vec<_> = scans.iter().map(|s| pose_from(s.laser_pose)).collect();
    let mut slam = Slam::new(
        cfg,
        BackendConfig {
            loop_closure,
            rerender_after: std::env::var("RERENDER")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(0.1),
            ..BackendConfig::default()
        },
        truth[0],
    );
    let mut prev = truth[0];
    let mut est_poses: Vec<Isometry2<f64>> = Vec::new();
    // Score of scan k against the previous `w` scans rendered at `poses`, at `pose`.
    let ctx = |poses: &[Isometry2<f64>], k: usize, pose: &Isometry2<f64>| -> f64 {
        let w = 5.min(k);
        let mut pts: Vec<Vector2<f64>> = Vec::new();
        for j in k - w..k {
            for q in scans[j].laser.points(&scans[j].ranges) {
                pts.push((poses[j] * Point2::from(q)).coords);
            }
        }
        let own = scans[k].laser.points(&scans[k].ranges);
        LikelihoodField::build(&pts, 0.05, 0.05, 0)
            .map(|f| f.score(&own, pose))
            .unwrap_or(0.0)
    };
    let (mut sum_t, mut sum_r) = (0.0, 0.0);
    for (k, (s, d)) in scans.iter().zip(&deltas).enumerate() {
        let e = slam.process(d, &s.laser, &s.ranges);
        if k > 0 {
            let gt = truth[k - 1].inverse() * truth[k];
            let est = prev.inverse() * e.pose;
            let err = gt.inverse() * est;
            sum_t += err.translation.vector.norm();
            sum_r += err.rotation.angle().abs().to_degrees();
            if err.translation.vector.norm() > thresh {
                let oe = gt.inverse() * d;
                let mut ep = est_poses.clone();
                ep.push(e.pose);
                println!(
                    "   truth frame: score at truth {:.3} at est step {:.3} at odom step {:.3}; est frame: at est {:.3} at truth step {:.3}",
                    ctx(&truth, k, &truth[k]),
                    ctx(&truth, k, &(truth[k - 1] * est)),
                    ctx(&truth, k, &(truth[k - 1] * d)),
                    ctx(&ep, k, &e.pose),
                    ctx(&ep, k, &(prev * gt)),
                );
                let dup = s.ranges == scans[k - 1].ranges;
                println!(
                    "scan {k} line {} dt {:.3} dup {dup}: odom err ({:.3},{:.3}) est step ({:.3},{:.3}) odom step ({:.3},{:.3}): err {:.3} m ({:.3},{:.3}) {:.2} deg, score {:.3} {:?}, gt step {:.2} m {:.1} deg",
                    s.line,
                    s.timestamp - scans[k - 1].timestamp,
                    oe.translation.x,
                    oe.translation.y,
                    est.translation.x,
                    est.translation.y,
                    d.translation.x,
                    d.translation.y,
                    err.translation.vector.norm(),
                    err.translation.x,
                    err.translation.y,
                    err.rotation.angle().to_degrees(),
                    e.score,
                    e.source,
                    gt.translation.vector.norm(),
                    gt.rotation.angle().to_degrees()
                );
            }
        }
        prev = e.pose;
        est_poses.push(e.pose);
    }
    let n = (scans.len() - 1) as f64;
    println!("mean {:.4} m {:.3} deg", sum_t / n, sum_r / n);
    slam.finish();
    for c in slam.closures() {
        let (Some(a), Some(b)) = (slam.node_scan(c.from), slam.node_scan(c.to)) else {
            continue;
        };
        let gt = truth[a].inverse() * truth[b];
        let err = gt.inverse() * c.measurement;
        println!(
            "closure scan {a} -> {b} score {:.3}: err {:.3} m {:.2} deg (gt {:.2} m)",
            c.score,
            err.translation.vector.norm(),
            err.rotation.angle().to_degrees(),
            gt.translation.vector.norm()
        );
    }
    if loop_closure {
        let t = slam.trajectory();
        let (mut st, mut sr) = (0.0, 0.0);
        for k in 1..t.len() {
            let err = (truth[k - 1].inverse() * truth[k]).inverse() * (t[k - 1].inverse() * t[k]);
            st += err.translation.vector.norm();
            sr += err.rotation.angle().abs().to_degrees();
        }
        println!("with loop closure: mean {:.4} m {:.3} deg", st / n, sr / n);
    }
    Ok(())
}
