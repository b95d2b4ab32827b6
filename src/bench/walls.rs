//! `hng bench walls`: wall detection (split-and-merge, `hng_modules::walls`) per 360-beam scan,
//! on a simulated scan of the default world and of the 100-wall bench world (the criterion
//! bench `benches/walls.rs` times the same calls). Target: p50 under 50 us.

use std::time::Instant;

use anyhow::{Context as _, Result};
use clap::Args;
use hng_modules::walls::{WallDetector, WallDetectorConfig};
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_simulator::{Simulator, World, bench};

/// Arguments of `hng bench walls`.
#[derive(Debug, Clone, Args)]
pub struct WallsArgs {
    /// Detections timed per case.
    #[arg(long, default_value_t = 20_000)]
    pub scans: usize,
    /// One JSON object per case instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// `hng bench walls`.
pub fn run(args: &WallsArgs) -> Result<()> {
    let mut rows = Vec::new();
    for (name, world) in [
        ("default_world", World::default_world()),
        ("100_walls", bench::wall_world(100, 1)),
    ] {
        let mut sim = Simulator::new(world).with_context(|| format!("building {name}"))?;
        let scan = sim.scan_lidar();
        let mut det = WallDetector::new(WallDetectorConfig::default());
        let mut walls = Vec::new();
        let mut samples = Vec::with_capacity(args.scans.max(1));
        for _ in 0..args.scans.max(1) {
            let t = Instant::now();
            det.detect(
                f64::from(scan.angle_min),
                f64::from(scan.angle_increment),
                f64::from(scan.range_min),
                std::hint::black_box(&scan.ranges),
                &mut walls,
            );
            std::hint::black_box(walls.len());
            samples.push(t.elapsed().as_nanos() as u64);
        }
        let p = Percentiles::of(&mut samples);
        rows.push(
            BenchRow::new("walls", &format!("detect_{name}"), p)
                .with("beams", scan.ranges.len() as u64)
                .with("walls_found", walls.len() as u64)
                .with("target_p50_ns", 50_000)
                .with("meets_target", p.p50_ns < 50_000),
        );
    }
    super::print_rows(&rows, args.json);
    Ok(())
}
