//! Two-process ping-pong latency (criterion): the same paths as `hng bench ipc`.
//! Each measured iteration is one round trip; criterion reports its time (one-way = half).

use std::path::Path;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use hng::bench::ipc::{Mode, Session, Transport};

fn ipc(c: &mut Criterion) {
    let exe = Path::new(env!("CARGO_BIN_EXE_hng"));
    let mut g = c.benchmark_group("ipc_round_trip");
    g.sample_size(20);
    for mode in [Mode::Spin, Mode::Blocking] {
        for transport in [Transport::Hng, Transport::Iceoryx2, Transport::Uds] {
            for size in [64usize, 1 << 20] {
                let mut s = match Session::start(exe, transport, size, mode) {
                    Ok(s) => s,
                    Err(e) => {
                        eprintln!("skipping {transport}/{size}/{mode}: {e:#}");
                        continue;
                    }
                };
                let id = BenchmarkId::new(format!("{transport}/{mode}"), size);
                g.bench_function(id, |b| {
                    b.iter_custom(|iters| {
                        let mut total = std::time::Duration::ZERO;
                        for _ in 0..iters {
                            match s.round_trip() {
                                Ok(d) => total += d,
                                Err(e) => panic!("round trip failed: {e:#}"),
                            }
                        }
                        total
                    })
                });
                let _ = s.finish();
            }
        }
    }
    g.finish();
}

criterion_group!(benches, ipc);
criterion_main!(benches);
