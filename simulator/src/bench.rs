//! Benchmark workloads, shared by `benches/sim.rs` and `hng bench sim --json`.

use std::time::Instant;

use hng_runtime::msg::closest_on_segment;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::Result;
use crate::sensors::{LidarScan, SensorOutput};
use crate::sim::{Simulator, secs_to_ns};
use crate::world::{Pose2D, Wall, World};

/// A 20 x 20 m square with `n_walls` walls in total (the 4 outer ones plus random segments
/// 0.5-3 m long that keep 1.5 m clear of the robot in the centre). Deterministic for a seed.
#[must_use]
pub fn wall_world(n_walls: usize, seed: u64) -> World {
    let mut w = World::empty(Pose2D::new(10.0, 10.0, 0.0));
    w.name = format!("bench-{n_walls}-walls");
    w.seed = seed;
    w.walls = vec![
        Wall::new([0.0, 0.0], [20.0, 0.0]),
        Wall::new([20.0, 0.0], [20.0, 20.0]),
        Wall::new([20.0, 20.0], [0.0, 20.0]),
        Wall::new([0.0, 20.0], [0.0, 0.0]),
    ];
    w.walls.truncate(n_walls);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    while w.walls.len() < n_walls {
        let a = [rng.random_range(0.5..19.5), rng.random_range(0.5..19.5)];
        let len: f64 = rng.random_range(0.5..3.0);
        let dir: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let b = [
            (a[0] + len * dir.cos()).clamp(0.2, 19.8),
            (a[1] + len * dir.sin()).clamp(0.2, 19.8),
        ];
        if closest_on_segment([10.0, 10.0], a, b).1 > 1.5 {
            w.walls.push(Wall::new(a, b));
        }
    }
    w
}

/// Times `iterations` lidar scans (360 beams, 10 m range) in a 100-wall world; one sample in
/// nanoseconds per scan.
pub fn scan_360(iterations: usize) -> Result<Vec<u64>> {
    let mut sim = Simulator::new(wall_world(100, 1))?;
    for _ in 0..10 {
        std::hint::black_box(sim.scan_lidar());
    }
    let mut samples = Vec::with_capacity(iterations);
    for _ in 0..iterations {
        let t = Instant::now();
        std::hint::black_box(sim.scan_lidar());
        samples.push(u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX));
    }
    Ok(samples)
}

/// A simple deterministic wall-avoiding driver: forward unless something is within 0.8 m in
/// the front 60°, then turn towards the side with more room.
#[must_use]
pub fn wander(scan: &LidarScan) -> (f64, f64) {
    let n = scan.ranges.len();
    if n == 0 || scan.angle_increment <= 0.0 {
        return (0.0, 0.0);
    }
    let sector = |lo: f32, hi: f32| {
        scan.ranges
            .iter()
            .enumerate()
            .filter(|(i, _)| {
                let a = scan.angle_min + *i as f32 * scan.angle_increment;
                a >= lo && a <= hi
            })
            .map(|(_, r)| if *r == f32::NEG_INFINITY { 0.0 } else { *r })
            .fold(f32::INFINITY, f32::min)
    };
    let front = sector(-0.52, 0.52);
    if front < 0.8 {
        let left = sector(0.52, 1.6);
        let right = sector(-1.6, -0.52);
        (0.0, if left >= right { 1.5 } else { -1.5 })
    } else {
        (0.8, 0.1)
    }
}

/// Steps `sim` until its clock reaches `end_ns`, driving with [`wander`] on every scan.
fn wander_until(sim: &mut Simulator, out: &mut Vec<SensorOutput>, end_ns: u64) -> Result<()> {
    while sim.now_ns() < end_ns {
        out.clear();
        sim.step_into(out);
        for o in out.iter() {
            if let SensorOutput::Lidar(scan) = o {
                let (v, w) = wander(scan);
                sim.set_cmd_vel(v, w)?;
            }
        }
    }
    Ok(())
}

/// Like [`headless_10hz`], but returns one sample per simulated second: the wall time it took,
/// in nanoseconds (the realtime factor of a sample is 1e9 / sample).
pub fn headless_10hz_samples(sim_seconds: u32) -> Result<Vec<u64>> {
    let mut sim = Simulator::new(World::default_world())?;
    let mut out = Vec::new();
    let mut samples = Vec::with_capacity(sim_seconds as usize);
    for second in 1..=u64::from(sim_seconds) {
        let end = second * 1_000_000_000;
        let start = Instant::now();
        wander_until(&mut sim, &mut out, end)?;
        samples.push(u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX));
    }
    Ok(samples)
}

/// Runs the default world (lidar 10 Hz and the other default sensors, physics 100 Hz) with the
/// [`wander`] driver as fast as possible for `sim_seconds`; returns the realtime factor
/// (simulated seconds per wall second).
pub fn headless_10hz(sim_seconds: f64) -> Result<f64> {
    let mut sim = Simulator::new(World::default_world())?;
    let end = secs_to_ns(sim_seconds);
    let mut out = Vec::new();
    let start = Instant::now();
    wander_until(&mut sim, &mut out, end)?;
    let wall = start.elapsed().as_secs_f64();
    Ok(if wall > 0.0 {
        sim.now_ns() as f64 * 1e-9 / wall
    } else {
        f64::INFINITY
    })
}
