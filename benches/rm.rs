//! Resource manager sampling cost (criterion): one sampling pass over N `sleep`
//! processes (N = 10, 50, 200). Passes run back to back here, so caches are warmer than
//! at 10 Hz; `hng bench rm --json` (`hng_rm::bench::sample_n`) measures the RM's own CPU
//! at the real rate.

use std::process::{Command, Stdio};
use std::time::Instant;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use hng_rm::bench::Sleepers;
use hng_rm::sampler::{ModuleTarget, Sampler, SamplerConfig};

fn spawn_sleepers(n: usize) -> Result<Sleepers, String> {
    let mut s = Sleepers(Vec::with_capacity(n));
    for _ in 0..n {
        let c = Command::new("sleep")
            .arg("3600")
            .stdout(Stdio::null())
            .spawn()
            .map_err(|e| format!("spawn sleep: {e}"))?;
        s.0.push(c);
    }
    Ok(s)
}

fn sampling_pass(c: &mut Criterion) {
    let mut g = c.benchmark_group("rm_sampling_pass");
    for n in [10usize, 50, 200] {
        let sleepers = match spawn_sleepers(n) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("skipping N={n}: {e}");
                continue;
            }
        };
        let mut sampler = match Sampler::new(SamplerConfig::default()) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("skipping N={n}: {e}");
                continue;
            }
        };
        let mut ok = true;
        for (i, child) in sleepers.0.iter().enumerate() {
            let Ok(pid) = i32::try_from(child.id()) else {
                ok = false;
                break;
            };
            if let Err(e) = sampler.add(ModuleTarget::new(format!("sleep{i}"), pid)) {
                eprintln!("skipping N={n}: {e}");
                ok = false;
                break;
            }
        }
        if !ok {
            continue;
        }
        g.bench_function(BenchmarkId::new("processes", n), |b| {
            b.iter(|| sampler.sample(Instant::now()).len());
        });
        drop(sleepers);
    }
    g.finish();
}

criterion_group!(benches, sampling_pass);
criterion_main!(benches);
