//! The `sample_N` benchmark as a test: a short run checks the result is well formed;
//! the full runs (`cargo test -p hng-rm --test bench_numbers -- --ignored --nocapture`)
//! print the numbers reported in the README and compare with procfs's own parser.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hng_rm::bench::{SampleBenchOptions, sample_n, sample_n_with};
use hng_rm::sampler::{ModuleTarget, Sampler, SamplerConfig};

#[test]
fn sample_n_is_well_formed() {
    let r = sample_n(10, 20.0, Duration::from_millis(500)).expect("bench runs");
    assert_eq!(r.processes, 10);
    assert_eq!(r.passes, 10);
    assert_eq!(r.pass_latency_ns.len(), 10);
    assert!(r.pass_latency_ns.iter().all(|&ns| ns > 0));
    assert!(r.pass_latency_p50_ns <= r.pass_latency_p99_ns);
    assert!(r.wall_s >= 0.45, "{}", r.wall_s);
    assert!(r.cpu_percent_of_one_core.is_finite() && r.cpu_percent_of_one_core >= 0.0);
}

#[test]
#[ignore = "takes ~20 s; prints the benchmark numbers"]
fn print_sample_n_numbers() {
    for n in [10, 50, 200] {
        let r = sample_n(n, 10.0, Duration::from_secs(5)).expect("bench runs");
        println!(
            "sample_{n}: RM thread {:.3}% of one core (process {:.3}%), pass p50 {} µs p99 {} µs, {} passes",
            r.cpu_percent_of_one_core,
            r.process_cpu_percent_of_one_core,
            r.pass_latency_p50_ns / 1000,
            r.pass_latency_p99_ns / 1000,
            r.passes
        );
    }
}

#[test]
#[ignore = "takes ~15 s; prints the benchmark numbers with one cgroup per process"]
fn print_sample_n_numbers_with_cgroups() {
    for n in [10, 50, 200] {
        let r = sample_n_with(&SampleBenchOptions {
            processes: n,
            rate_hz: 10.0,
            duration: Duration::from_secs(5),
            per_module_cgroups: true,
        })
        .expect("bench runs");
        println!(
            "sample_{n} (cgroups: {}): RM thread {:.3}% of one core, pass p50 {} µs p99 {} µs",
            r.cgroups,
            r.cpu_percent_of_one_core,
            r.pass_latency_p50_ns / 1000,
            r.pass_latency_p99_ns / 1000,
        );
    }
}

#[test]
#[ignore = "prints per-process cost of our pread path vs procfs::Process::stat"]
fn compare_with_procfs_parse() {
    let n = 50;
    let mut children: Vec<_> = (0..n)
        .map(|_| {
            Command::new("sleep")
                .arg("60")
                .stdout(Stdio::null())
                .spawn()
                .expect("spawn sleep")
        })
        .collect();
    let pids: Vec<i32> = children
        .iter()
        .map(|c| i32::try_from(c.id()).expect("pid"))
        .collect();
    let rounds = 200;
    // Ours, without PSS (PSS is read at 1/10 of the rate by default).
    let mut s = Sampler::new(SamplerConfig {
        pss_every: 0,
        ..SamplerConfig::default()
    })
    .expect("sampler");
    for (i, &pid) in pids.iter().enumerate() {
        s.add(ModuleTarget::new(format!("m{i}"), pid)).expect("add");
    }
    let t = Instant::now();
    for _ in 0..rounds {
        s.sample(Instant::now());
    }
    let ours = t.elapsed().as_nanos() / (rounds * n) as u128;
    // procfs: open + read + parse every field.
    let t = Instant::now();
    let mut sum = 0u64;
    for _ in 0..rounds {
        for &pid in &pids {
            let st = procfs::process::Process::new(pid)
                .and_then(|p| p.stat())
                .expect("procfs stat");
            sum = sum.wrapping_add(st.utime + st.stime + st.minflt);
        }
    }
    let theirs = t.elapsed().as_nanos() / (rounds * n) as u128;
    // smaps_rollup cost per process.
    let t = Instant::now();
    for _ in 0..rounds {
        for &pid in &pids {
            let text = std::fs::read(format!("/proc/{pid}/smaps_rollup")).expect("smaps");
            sum = sum.wrapping_add(text.len() as u64);
        }
    }
    let smaps = t.elapsed().as_nanos() / (rounds * n) as u128;
    println!(
        "per process: pread stat {ours} ns, procfs Process::stat {theirs} ns, smaps_rollup {smaps} ns ({sum})"
    );
    for c in &mut children {
        let _ = c.kill();
        let _ = c.wait();
    }
}
