//! `hng bench sim`: the simulator's speed.
//!
//! Cases: `scan_360` (one 360-beam, 10 m lidar scan in a 20 x 20 m world with 100 walls; one
//! sample per scan) and `headless_10hz` (the default world with every default sensor, lidar at
//! 10 Hz, physics at 100 Hz and a wall-avoiding driver, as fast as possible; one sample per
//! simulated second = the wall time it took; `realtime_factor` = simulated seconds per wall
//! second over the whole run).

use anyhow::{Context as _, Result};
use clap::Args;
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_simulator::bench;

/// Arguments of `hng bench sim`.
#[derive(Debug, Clone, Args)]
pub struct SimArgs {
    /// Scans timed in `scan_360`.
    #[arg(long, default_value_t = 20_000)]
    pub scans: usize,
    /// Simulated seconds run in `headless_10hz`.
    #[arg(long, default_value_t = 300)]
    pub sim_seconds: u32,
    /// One JSON object per case instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Runs both cases and returns their rows.
pub fn rows(args: &SimArgs) -> Result<Vec<BenchRow>> {
    let mut scan = bench::scan_360(args.scans.max(1)).context("scan_360: building the world")?;
    let total: u64 = scan.iter().sum();
    let p = Percentiles::of(&mut scan);
    let scan_row = BenchRow::new("sim", "scan_360", p)
        .with("beams", 360)
        .with("walls", 100)
        .with("max_range_m", 10.0)
        .with("mean_ns", total / p.samples.max(1))
        .with("target_p50_ns", 100_000)
        .with("meets_target", p.p50_ns < 100_000);

    let mut secs = bench::headless_10hz_samples(args.sim_seconds.max(1))
        .context("headless_10hz: building the default world")?;
    let wall_ns: u64 = secs.iter().sum();
    let n = secs.len();
    let factor = if wall_ns > 0 {
        n as f64 * 1e9 / wall_ns as f64
    } else {
        f64::INFINITY
    };
    let p = Percentiles::of(&mut secs);
    let headless_row = BenchRow::new("sim", "headless_10hz", p)
        .with("unit", "wall ns per simulated second")
        .with("sim_seconds", n as u64)
        .with("lidar_hz", 10)
        .with("physics_hz", 100)
        .with("realtime_factor", (factor * 10.0).round() / 10.0)
        .with("target_realtime_factor", 200)
        .with("meets_target", factor >= 200.0);
    Ok(vec![scan_row, headless_row])
}

/// `hng bench sim`.
pub fn run(args: &SimArgs) -> Result<()> {
    let rows = rows(args)?;
    super::print_rows(&rows, args.json);
    Ok(())
}
