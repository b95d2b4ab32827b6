//! `hng bench rm`: the resource manager's sampling cost.
//!
//! Cases `sample_10`, `sample_50`, `sample_200`: N `sleep` processes sampled at 10 Hz for
//! `--seconds` (CPU time and RSS from a kept-open `/proc/PID/stat` every pass, PSS from
//! `smaps_rollup` every 50 passes, staggered). Each row: the per-pass latency percentiles
//! (`p50_ns` ... `samples` = passes), `cpu_percent` = CPU time of the sampling thread
//! (`getrusage(RUSAGE_THREAD)`) over wall time, in % of one core: the RM's cost. With
//! `--cgroups` every process gets its own cgroup (when writable) and the CPU comes from
//! the cgroup counter (`cgroups` says whether that happened). Target: under 0.5 % of one
//! core for 50 modules.

use std::time::Duration;

use anyhow::{Context as _, Result};
use clap::Args;
use hng_rm::bench::{SampleBenchOptions, sample_n_with};
use hng_runtime::stats::{BenchRow, Percentiles};

/// Arguments of `hng bench rm`.
#[derive(Debug, Clone, Args)]
pub struct RmArgs {
    /// Seconds of sampling per case.
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// Sampling rate, Hz.
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    /// One cgroup per process (CPU from the cgroup counter), when cgroups are writable.
    #[arg(long)]
    pub cgroups: bool,
    /// One JSON object per case instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The target for 50 modules, % of one core.
pub const TARGET_CPU_PERCENT_50: f64 = 0.5;

/// Runs the three cases and returns their rows.
pub fn rows(args: &RmArgs) -> Result<Vec<BenchRow>> {
    anyhow::ensure!(
        args.seconds.is_finite() && args.seconds > 0.0,
        "--seconds must be a positive number"
    );
    anyhow::ensure!(
        args.rate_hz.is_finite() && args.rate_hz > 0.0,
        "--rate-hz must be a positive number"
    );
    let mut out = Vec::new();
    for n in [10usize, 50, 200] {
        let case = format!("sample_{n}");
        let b = sample_n_with(&SampleBenchOptions {
            processes: n,
            rate_hz: args.rate_hz,
            duration: Duration::from_secs_f64(args.seconds),
            per_module_cgroups: args.cgroups,
        })
        .with_context(|| format!("{case}: sampling {n} sleep processes"))?;
        let mut lat = b.pass_latency_ns.clone();
        let p = Percentiles::of(&mut lat);
        let cpu = (b.cpu_percent_of_one_core * 1000.0).round() / 1000.0;
        let mut row = BenchRow::new("rm", &case, p)
            .with("processes", n as u64)
            .with("rate_hz", args.rate_hz)
            .with("seconds", (b.wall_s * 100.0).round() / 100.0)
            .with("cgroups", b.cgroups)
            .with("cpu_percent", cpu)
            .with(
                "process_cpu_percent",
                (b.process_cpu_percent_of_one_core * 1000.0).round() / 1000.0,
            );
        if n == 50 {
            row = row
                .with("target_cpu_percent", TARGET_CPU_PERCENT_50)
                .with("meets_target", cpu < TARGET_CPU_PERCENT_50);
        }
        out.push(row);
    }
    Ok(out)
}

/// `hng bench rm`.
pub fn run(args: &RmArgs) -> Result<()> {
    let rows = rows(args)?;
    crate::bench::print_rows(&rows, args.json);
    Ok(())
}
