//! The `sample_N` benchmark (`hng bench rm --json`): the sampler's own CPU cost.

use std::os::unix::process::CommandExt;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::cgroup::{CgroupRun, CgroupSupport, unique_run_id};
use crate::error::{Result, RmError};
use crate::sampler::{ModuleTarget, Sampler, SamplerConfig};

/// Result of [`sample_n`].
#[derive(Debug, Clone, Serialize)]
pub struct SampleBench {
    /// Number of processes sampled.
    pub processes: usize,
    /// Sampling rate, Hz.
    pub rate_hz: f64,
    /// Whether the processes had their own cgroups (CPU from the cgroup counter).
    pub cgroups: bool,
    /// Number of passes done.
    pub passes: usize,
    /// Wall time of the measurement, s.
    pub wall_s: f64,
    /// CPU time (user + system) of the sampling thread (`getrusage(RUSAGE_THREAD)`)
    /// over the measurement, as % of one core: the RM's cost.
    pub cpu_percent_of_one_core: f64,
    /// The same from `getrusage(RUSAGE_SELF)` (whole process, including any other
    /// thread of the caller).
    pub process_cpu_percent_of_one_core: f64,
    /// Duration of each pass in ns.
    pub pass_latency_ns: Vec<u64>,
    /// Median of `pass_latency_ns`.
    pub pass_latency_p50_ns: u64,
    /// 99th percentile of `pass_latency_ns`.
    pub pass_latency_p99_ns: u64,
}

/// Child processes killed and reaped when dropped (the benchmarks' `sleep` processes).
pub struct Sleepers(pub Vec<Child>);

impl Drop for Sleepers {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
        }
        for c in &mut self.0 {
            let _ = c.wait();
        }
    }
}

fn cpu_time(who: nix::sys::resource::UsageWho) -> Result<Duration> {
    let u = nix::sys::resource::getrusage(who).map_err(|e| {
        RmError::io(
            "getrusage",
            "RUSAGE",
            std::io::Error::from_raw_os_error(e as i32),
        )
    })?;
    let tv = |t: nix::sys::time::TimeVal| {
        Duration::from_secs(u64::try_from(t.tv_sec()).unwrap_or(0))
            + Duration::from_micros(u64::try_from(t.tv_usec()).unwrap_or(0))
    };
    Ok(tv(u.user_time()) + tv(u.system_time()))
}

fn percentile(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// Options of [`sample_n_with`].
#[derive(Debug, Clone, PartialEq)]
pub struct SampleBenchOptions {
    /// Number of `sleep` processes.
    pub processes: usize,
    /// Sampling rate, Hz.
    pub rate_hz: f64,
    /// Measurement duration.
    pub duration: Duration,
    /// Put each process in its own cgroup (when writable) so the sampler reads the
    /// cgroup CPU counter every pass and `stat` every `cgroup_stat_every` passes.
    pub per_module_cgroups: bool,
}

/// Spawns `n` `sleep` processes, samples them at `rate_hz` for `duration` (PSS at the
/// default rate), and returns the sampler's own CPU cost and per-pass latencies. The
/// processes are killed and reaped before returning (also on error).
pub fn sample_n(n: usize, rate_hz: f64, duration: Duration) -> Result<SampleBench> {
    sample_n_with(&SampleBenchOptions {
        processes: n,
        rate_hz,
        duration,
        per_module_cgroups: false,
    })
}

/// [`sample_n`] with options. With `per_module_cgroups` and no writable cgroup, the
/// processes are sampled from /proc only (`SampleBench::cgroups` says which).
pub fn sample_n_with(opts: &SampleBenchOptions) -> Result<SampleBench> {
    let (n, rate_hz, duration) = (opts.processes, opts.rate_hz, opts.duration);
    let config = SamplerConfig {
        rate_hz,
        ..SamplerConfig::default()
    };
    let mut sampler = Sampler::new(config)?;
    let support = if opts.per_module_cgroups {
        CgroupSupport::detect()
    } else {
        CgroupSupport::none("not requested")
    };
    let run = CgroupRun::create(&support, "bench-rm", &unique_run_id())?;
    let mut cgroups = Vec::with_capacity(n);
    let mut sleepers = Sleepers(Vec::with_capacity(n));
    for i in 0..n {
        let cg = run.module(&format!("sleep{i}"))?;
        let placement = cg.placement()?;
        let mut cmd = Command::new("sleep");
        cmd.arg("3600")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        if !placement.is_empty() {
            // SAFETY: place_self is async-signal-safe (getpid + write only).
            unsafe {
                cmd.pre_exec(move || placement.place_self());
            }
        }
        let child = cmd.spawn().map_err(|e| RmError::io("spawn", "sleep", e))?;
        let pid = i32::try_from(child.id())
            .map_err(|_| RmError::Config(format!("pid {} does not fit i32", child.id())))?;
        sleepers.0.push(child);
        sampler
            .add(ModuleTarget::new(format!("sleep{i}"), pid).with_cgroup_cpu(cg.cpu_counter()))?;
        cgroups.push(cg);
    }
    let with_cgroups = cgroups.iter().any(|c| c.cpu_counter().is_some());
    let period = sampler.period();
    let passes = ((duration.as_secs_f64() * rate_hz).round() as usize).max(1);
    let mut latency = Vec::with_capacity(passes);

    let start_thread = cpu_time(nix::sys::resource::UsageWho::RUSAGE_THREAD)?;
    let start_self = cpu_time(nix::sys::resource::UsageWho::RUSAGE_SELF)?;
    let start = Instant::now();
    let mut next = start;
    for _ in 0..passes {
        let t0 = Instant::now();
        sampler.sample(t0);
        latency.push(u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX));
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let thread = cpu_time(nix::sys::resource::UsageWho::RUSAGE_THREAD)? - start_thread;
    let process = cpu_time(nix::sys::resource::UsageWho::RUSAGE_SELF)? - start_self;
    drop(sleepers);
    for cg in cgroups {
        // The sleeps were killed and reaped: the groups are empty.
        cg.remove()?;
    }
    run.remove()?;

    let mut sorted = latency.clone();
    sorted.sort_unstable();
    Ok(SampleBench {
        processes: n,
        rate_hz,
        cgroups: with_cgroups,
        passes,
        wall_s: wall,
        cpu_percent_of_one_core: 100.0 * thread.as_secs_f64() / wall,
        process_cpu_percent_of_one_core: 100.0 * process.as_secs_f64() / wall,
        pass_latency_p50_ns: percentile(&sorted, 0.5),
        pass_latency_p99_ns: percentile(&sorted, 0.99),
        pass_latency_ns: latency,
    })
}
