//! Wall detection per scan (issue target: under 50 us for a 360-beam scan): split-and-merge on
//! a real simulated scan of the default world (walls, boxes, range noise), and on a scan of the
//! 100-wall bench world.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use hng_modules::walls::{WallDetector, WallDetectorConfig};
use hng_simulator::{Simulator, World, bench};

fn wall_benches(c: &mut Criterion) {
    for (name, world) in [
        ("default_world", World::default_world()),
        ("100_walls", bench::wall_world(100, 1)),
    ] {
        let Ok(mut sim) = Simulator::new(world) else {
            eprintln!("cannot build the {name} world");
            continue;
        };
        let scan = sim.scan_lidar();
        let mut det = WallDetector::new(WallDetectorConfig::default());
        let mut walls = Vec::new();
        det.detect(
            f64::from(scan.angle_min),
            f64::from(scan.angle_increment),
            f64::from(scan.range_min),
            &scan.ranges,
            &mut walls,
        );
        eprintln!(
            "walls/{name}: {} beams, {} walls detected",
            scan.ranges.len(),
            walls.len()
        );
        c.bench_function(
            &format!("walls/detect_{}_beams_{name}", scan.ranges.len()),
            |b| {
                b.iter(|| {
                    det.detect(
                        f64::from(scan.angle_min),
                        f64::from(scan.angle_increment),
                        f64::from(scan.range_min),
                        black_box(&scan.ranges),
                        &mut walls,
                    );
                    black_box(walls.len())
                })
            },
        );
    }
}

criterion_group!(benches, wall_benches);
criterion_main!(benches);
