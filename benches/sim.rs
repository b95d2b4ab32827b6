//! Simulator benchmarks: one 360-beam lidar scan among 100 walls, one physics step, and one
//! simulated second of the default world with all default sensors.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use hng_simulator::render::{ImageParams, Renderer};
use hng_simulator::{SensorKind, SensorOutput, Simulator, World, bench};

fn sim_benches(c: &mut Criterion) {
    let Ok(mut scan_sim) = Simulator::new(bench::wall_world(100, 1)) else {
        eprintln!("cannot build the 100-wall world");
        return;
    };
    c.bench_function("sim/lidar_scan_360_beams_100_walls", |b| {
        b.iter(|| black_box(scan_sim.scan_lidar()))
    });

    let Ok(mut step_sim) = Simulator::new(bench::wall_world(100, 1)) else {
        return;
    };
    for kind in [
        SensorKind::Lidar,
        SensorKind::Odometry,
        SensorKind::Gps,
        SensorKind::Camera,
        SensorKind::GroundTruth,
    ] {
        step_sim.set_sensor_enabled(kind, false);
    }
    let mut out = Vec::new();
    c.bench_function("sim/physics_step", |b| {
        b.iter(|| {
            let _ = step_sim.set_cmd_vel(0.5, 0.3);
            out.clear();
            step_sim.step_into(&mut out);
            black_box(&out);
        })
    });

    let Ok(mut world_sim) = Simulator::new(World::default_world()) else {
        return;
    };
    c.bench_function("sim/default_world_1_simulated_second", |b| {
        b.iter(|| {
            let end = world_sim.now_ns() + 1_000_000_000;
            while world_sim.now_ns() < end {
                out.clear();
                world_sim.step_into(&mut out);
                for o in &out {
                    if let SensorOutput::Lidar(scan) = o {
                        let (v, w) = bench::wander(scan);
                        let _ = world_sim.set_cmd_vel(v, w);
                    }
                }
            }
            black_box(&out);
        })
    });
}

/// One camera image (320 x 240 RGB8, 230 KB) of the default world, without and with pixel
/// noise.
fn render_benches(c: &mut Criterion) {
    let world = World::default_world();
    let start = world.robot.start;
    for (case, sigma) in [("clean", 0.0), ("noise_3", 3.0)] {
        let params = ImageParams {
            noise_sigma: sigma,
            ..ImageParams::default()
        };
        let Ok(r) = Renderer::new(&world, params) else {
            eprintln!("cannot build the renderer");
            return;
        };
        let mut img = vec![0u8; params.image_bytes()];
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
        c.bench_function(
            &format!("sim/render_camera_320x240_default_world_{case}"),
            |b| {
                b.iter(|| {
                    r.render(start, 1.0, Some(&mut rng), &mut img);
                    black_box(&img);
                })
            },
        );
    }
}

criterion_group!(benches, sim_benches, render_benches);
criterion_main!(benches);
