//! SLAM benchmarks (hng-modules::slam): scan matching and mapping per scan,
//! on the Intel CARMEN log if present (`../shared/data/carmen/`), otherwise
//! on synthetic scans of a rectangular room.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use hng_modules::nalgebra::{Isometry2, Point2, Vector2};
use hng_modules::slam::{
    LaserConfig, LogOddsMap, MapperConfig, MatcherConfig, ReferenceMap, match_scan, pose_from,
    read_log, scan_normals,
};

/// (scan end points in the sensor frame, true pose) for a run of scans.
fn scans() -> Vec<(Vec<Vector2<f64>>, Isometry2<f64>)> {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/carmen/intel-corrected.log");
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
                            let tx = if d.x > 1e-9 {
                                (5.0 - o.x) / d.x
                            } else if d.x < -1e-9 {
                                (-5.0 - o.x) / d.x
                            } else {
                                f64::INFINITY
                            };
                            let ty = if d.y > 1e-9 {
                                (4.0 - o.y) / d.y
                            } else if d.y < -1e-9 {
                                (-4.0 - o.y) / d.y
                            } else {
                                f64::INFINITY
                            };
                            let t = tx.min(ty);
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

criterion_group!(slam, benches);
criterion_main!(slam);
