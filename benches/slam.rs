//! SLAM benchmarks (hng-modules::slam).
//!
//! 1. Whole logs (`tests/data/carmen/*.log`): every scan of each log through the front end
//!    alone and through the whole pipeline (front end, pose graph, loop closures, inline
//!    optimisation, final map), one JSON line per (pipeline, log) with the per-scan time
//!    distribution (`p50_ns`, `p99_ns`, `max_ns`, `samples`), `scans_per_s` and
//!    `realtime_factor` (log duration / processing time), on one core; `cpu_s`,
//!    `scans_per_cpu_s` and `realtime_factor_cpu` are the same from the thread's CPU time,
//!    which a loaded machine does not inflate.
//! 2. Criterion micro-benchmarks: scan matching and mapping per scan on the Intel log
//!    (synthetic scans of a rectangular room if it is missing).
//!
//! `cargo bench --bench slam` (`-- --logs-only` skips the criterion part).

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

use criterion::Criterion;
use hng_modules::nalgebra::{Isometry2, Point2, Vector2};
use hng_modules::slam::{
    BackendConfig, LaserConfig, LogOddsMap, MapperConfig, MatcherConfig, ReferenceMap, Slam,
    SlamConfig, logs_in, match_scan, pose_from, read_log, scan_normals,
};

fn carmen_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/carmen")
}

fn percentile(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    let k = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[k]
}

/// CPU seconds used by this thread so far (the evaluation runs on one thread, so this is its
/// cost on one core whatever the machine's load; 0 if the clock cannot be read).
fn thread_cpu_s() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(0.0)
}

/// Runs every log through the front end alone and the whole pipeline; one JSON line each.
fn whole_logs() {
    let Ok(logs) = logs_in(&carmen_dir()) else {
        println!("no logs in {}", carmen_dir().display());
        return;
    };
    for path in logs {
        let Ok(log) = read_log(&path) else {
            println!("cannot read {}", path.display());
            continue;
        };
        let scans: Vec<_> = log.scans().collect();
        let deltas = log.odometry_deltas();
        let Some(first) = scans.first() else {
            continue;
        };
        let ts: Vec<f64> = scans.iter().map(|s| s.timestamp).collect();
        let duration = ts.iter().copied().fold(f64::MIN, f64::max)
            - ts.iter().copied().fold(f64::MAX, f64::min);
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        for (case, loop_closure) in [("front_end", false), ("pipeline", true)] {
            let mut slam = Slam::new(
                SlamConfig::default(),
                BackendConfig {
                    loop_closure,
                    ..BackendConfig::default()
                },
                pose_from(first.laser_pose),
            );
            let mut ns = Vec::with_capacity(scans.len());
            let cpu0 = thread_cpu_s();
            let t0 = Instant::now();
            for (s, d) in scans.iter().zip(&deltas) {
                let t = Instant::now();
                black_box(slam.process(d, &s.laser, &s.ranges));
                ns.push(t.elapsed().as_nanos() as u64);
            }
            let tf = Instant::now();
            slam.finish();
            ns.push(tf.elapsed().as_nanos() as u64);
            let total = t0.elapsed().as_secs_f64();
            let cpu = thread_cpu_s() - cpu0;
            let mut sorted = ns.clone();
            sorted.sort_unstable();
            let rate = scans.len() as f64 / total;
            // JSON has no NaN: a log without timestamps has no real-time factor.
            let factor = |t: f64| {
                if duration > 0.0 {
                    format!("{:.1}", duration / t)
                } else {
                    "null".to_owned()
                }
            };
            let (realtime, realtime_cpu) = (factor(total), factor(cpu));
            println!(
                "{{\"bench\":\"slam\",\"case\":\"{case}/{name}\",\"p50_ns\":{},\"p99_ns\":{},\"max_ns\":{},\"samples\":{},\"scans_per_s\":{:.1},\"realtime_factor\":{realtime},\"cpu_s\":{:.2},\"scans_per_cpu_s\":{:.1},\"realtime_factor_cpu\":{realtime_cpu},\"loop_closures\":{}}}",
                percentile(&sorted, 0.5),
                percentile(&sorted, 0.99),
                sorted.last().copied().unwrap_or(0),
                ns.len(),
                rate,
                cpu,
                scans.len() as f64 / cpu.max(1e-9),
                slam.stats().closures
            );
        }
    }
}

/// (scan end points in the sensor frame, true pose) for a run of scans.
fn scans() -> Vec<(Vec<Vector2<f64>>, Isometry2<f64>)> {
    let path = carmen_dir().join("intel-corrected.log");
    let laser = LaserConfig::default();
    match read_log(&path) {
        Ok(log) => {
            println!("using {}", path.display());
            log.scans()
                .skip(300)
                .take(40)
                .map(|s| (laser.points(&s.ranges), pose_from(s.laser_pose)))
                .collect()
        }
        Err(e) => {
            println!("synthetic scans ({e})");
            (0..40)
                .map(|k| {
                    let pose = Isometry2::new(Vector2::new(k as f64 * 0.1 - 2.0, 0.0), 0.0);
                    let pts = (0..180)
                        .filter_map(|i| {
                            let a = -std::f64::consts::FRAC_PI_2 + f64::from(i).to_radians();
                            let d = Vector2::new(a.cos(), a.sin());
                            // Room [-5, 5] x [-4, 4] seen from `pose`.
                            let o = pose.translation.vector;
                            let t = wall_distance(o.x, d.x, 5.0).min(wall_distance(o.y, d.y, 4.0));
                            t.is_finite().then(|| d * t)
                        })
                        .collect();
                    (pts, pose)
                })
                .collect()
        }
    }
}

fn reference(scans: &[(Vec<Vector2<f64>>, Isometry2<f64>)], cfg: &MatcherConfig) -> ReferenceMap {
    let mut pts = Vec::new();
    let mut normals = Vec::new();
    for (s, pose) in scans {
        for (p, n) in s.iter().zip(scan_normals(s)) {
            pts.push((pose * Point2::from(*p)).coords);
            normals.push(n.map(|n| pose.rotation * n));
        }
    }
    ReferenceMap::build(pts, normals, cfg).expect("reference map")
}

fn benches(c: &mut Criterion) {
    let data = scans();
    let cfg = MatcherConfig::default();
    let (k, local) = (25usize, 15usize);
    let refmap = reference(&data[k - local..k], &cfg);
    let (scan, truth) = &data[k];
    // Prior off by 15 cm and 5 degrees, like a poor odometry step.
    let prior = truth * Isometry2::new(Vector2::new(0.1, -0.11), 5f64.to_radians());
    let m = match_scan(&refmap, scan, &prior, &cfg).expect("match");
    let err = truth.inverse() * m.pose;
    println!(
        "match check: error {:.3} m {:.3} deg, score {:.2}, {} B&B nodes, {} points, {} map points",
        err.translation.vector.norm(),
        err.rotation.angle().to_degrees(),
        m.score,
        m.nodes,
        scan.len(),
        refmap.points.len()
    );

    let mut g = c.benchmark_group("slam_per_scan");
    g.bench_function("match_scan_csm_bnb_plus_icp", |b| {
        b.iter(|| match_scan(black_box(&refmap), black_box(scan), &prior, &cfg))
    });
    g.bench_function("build_reference_map_15_scans", |b| {
        b.iter(|| reference(black_box(&data[k - local..k]), &cfg))
    });
    let mut map = LogOddsMap::new(MapperConfig::default());
    for (s, p) in &data {
        map.integrate(p, s);
    }
    let mut i = 0usize;
    g.bench_function("mapping_integrate_scan", |b| {
        b.iter(|| {
            let (s, p) = &data[i % data.len()];
            i += 1;
            map.integrate(black_box(p), black_box(s));
        })
    });
    g.finish();
}

fn main() {
    whole_logs();
    if std::env::args().any(|a| a == "--logs-only") {
        return;
    }
    let mut c = Criterion::default().configure_from_args();
    benches(&mut c);
    c.final_summary();
}

/// Distance along a ray from `o` in direction `d` (one axis) to the wall at `±half`
/// ahead of it (infinite for a ray parallel to the walls).
fn wall_distance(o: f64, d: f64, half: f64) -> f64 {
    if d > 1e-9 {
        (half - o) / d
    } else if d < -1e-9 {
        (-half - o) / d
    } else {
        f64::INFINITY
    }
}
