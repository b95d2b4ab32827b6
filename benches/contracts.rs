//! `decide_N`: deciding one query among N candidate proposals
//! (`hng_runtime::contract::select_best`). Budget: < 5 ms for N = 1000.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use std::time::Duration;

use criterion::BatchSize;
use hng::bench::contracts::proposals;
use hng_runtime::contract::{
    AgentConfig, ContractAgent, Envelope, Message, ModuleId, Propose, select_best,
};

fn decide(c: &mut Criterion) {
    let mut group = c.benchmark_group("decide_N");
    for n in [10usize, 100, 1000] {
        let props = proposals(n);
        group.bench_with_input(BenchmarkId::from_parameter(n), &props, |b, p| {
            b.iter(|| select_best(black_box(p)).map(|best| best.provider))
        });
    }
    group.finish();
}

/// The whole decision inside a Manager's agent: N `Propose` messages handled,
/// then the deadline tick that accepts the best and rejects the N-1 others.
fn decide_agent(c: &mut Criterion) {
    let mut group = c.benchmark_group("decide_N_agent");
    for n in [10usize, 100, 1000] {
        let props = proposals(n);
        let setup = || {
            let cfg = AgentConfig::manager(ModuleId(u32::MAX), &["Localization"]);
            let mut m = ContractAgent::new(cfg).expect("valid manager config");
            let call = m.tick(Duration::ZERO);
            assert_eq!(call.len(), 1, "one call for proposals");
            let envs: Vec<Envelope> = props
                .iter()
                .map(|p| Envelope {
                    from: p.provider,
                    body: Message::Propose(Propose {
                        query_id: 1,
                        need: 1,
                        value: p.value,
                        channel: p.channel.clone(),
                    }),
                })
                .collect();
            (m, envs)
        };
        group.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter_batched(
                setup,
                |(mut m, envs)| {
                    let t = Duration::from_millis(1);
                    for e in &envs {
                        black_box(m.handle(e, t));
                    }
                    let out = m.tick(Duration::from_millis(60));
                    assert_eq!(out.len(), envs.len(), "1 accept + N-1 rejects");
                    m.provider(1)
                },
                BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, decide, decide_agent);
criterion_main!(benches);
