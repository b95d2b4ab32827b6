//! Property tests: random module graphs, the arbiter, priorities, the wire.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use proptest::prelude::*;

use super::{manager, ms, sim};
use crate::contract::sim::{Edge, Sim};
use crate::contract::{
    AgentConfig, CommandArbiter, ContractAgent, DropReason, Envelope, Message, ModuleId, NeedSpec,
    Priority, Query, QueryKind, Selected, ServiceOffer, Verdict, decode, encode,
};

const SERVICES: usize = 6;

#[derive(Debug, Clone)]
struct ModSpec {
    provides: Vec<usize>,
    needs: Vec<(usize, bool)>,
    apt: bool,
    q: f64,
}

#[derive(Debug, Clone)]
struct Graph {
    objectives: Vec<usize>,
    modules: Vec<ModSpec>,
}

fn svc(i: usize) -> String {
    format!("s{i}")
}

/// `layered`: a module only needs services of lower index than all it
/// provides (a DAG of services, so "apt" is well defined bottom-up).
fn graph(layered: bool) -> impl Strategy<Value = Graph> {
    let module = (
        prop::collection::btree_set(0..SERVICES, 1..=2),
        prop::collection::vec((0..SERVICES, prop::bool::weighted(0.7)), 0..=3),
        prop::bool::weighted(0.85),
        -1.0f64..1.0,
    )
        .prop_map(move |(provides, needs, apt, q)| {
            let min = provides.iter().copied().min().unwrap_or(0);
            let mut seen = BTreeSet::new();
            let needs = needs
                .into_iter()
                .filter(|_| !layered || min > 0)
                .map(|(s, req)| {
                    if layered {
                        (s % min.max(1), req)
                    } else {
                        (s, req)
                    }
                })
                .filter(|(s, _)| !provides.contains(s))
                .filter(|(s, _)| seen.insert(*s))
                .collect();
            ModSpec {
                provides: provides.into_iter().collect(),
                needs,
                apt,
                q,
            }
        });
    (
        prop::collection::btree_set(0..SERVICES, 1..=4),
        prop::collection::vec(module, 2..=12),
    )
        .prop_map(|(objectives, modules)| Graph {
            objectives: objectives.into_iter().collect(),
            modules,
        })
}

fn build(g: &Graph) -> Sim {
    let mut s = sim();
    let objectives: Vec<String> = g.objectives.iter().map(|&i| svc(i)).collect();
    let names: Vec<&str> = objectives.iter().map(String::as_str).collect();
    s.add(manager(0, &names));
    for (i, m) in g.modules.iter().enumerate() {
        let mut cfg = AgentConfig::new(ModuleId(i as u32 + 1));
        for &p in &m.provides {
            cfg = cfg.provide(ServiceOffer::new(svc(p), ""));
        }
        for (rank, &(n, required)) in (1u16..).zip(&m.needs) {
            cfg = cfg.need(if required {
                NeedSpec::required(svc(n), rank)
            } else {
                NeedSpec::optional(svc(n), rank, 0.2)
            });
        }
        let mut a = ContractAgent::new(cfg).unwrap();
        a.set_quality(m.q);
        a.set_aptitude(m.apt);
        s.add(a);
    }
    s
}

/// For a layered graph: can each service be provided by an apt module whose
/// required needs are (recursively) satisfiable?
fn apt_services(g: &Graph) -> Vec<bool> {
    let mut apt = vec![false; SERVICES];
    for s in 0..SERVICES {
        apt[s] = g.modules.iter().any(|m| {
            m.provides.contains(&s)
                && m.apt
                && m.needs.iter().all(|&(n, req)| !req || (n < s && apt[n]))
        });
    }
    apt
}

fn successors(edges: &[Edge]) -> BTreeMap<ModuleId, Vec<ModuleId>> {
    let mut succ: BTreeMap<ModuleId, Vec<ModuleId>> = BTreeMap::new();
    for e in edges {
        succ.entry(e.client).or_default().push(e.provider);
    }
    succ
}

/// Edges whose contract both client and provider hold, whatever priority
/// each believes in.
fn held_edges(s: &Sim) -> Vec<Edge> {
    s.edges()
        .into_iter()
        .filter(|e| {
            s.agent(e.provider).is_some_and(|p| {
                p.client_contracts()
                    .any(|c| c.client == e.client && c.need == e.need)
            })
        })
        .collect()
}

fn assert_acyclic(edges: &[Edge]) -> Result<(), TestCaseError> {
    let succ = successors(edges);
    // Kahn's algorithm: acyclic iff every node gets removed.
    let nodes: BTreeSet<ModuleId> = edges.iter().flat_map(|e| [e.client, e.provider]).collect();
    let mut indeg: BTreeMap<ModuleId, usize> = nodes.iter().map(|&n| (n, 0)).collect();
    for e in edges {
        *indeg.entry(e.provider).or_default() += 1;
    }
    let mut ready: Vec<ModuleId> = indeg
        .iter()
        .filter(|(_, d)| **d == 0)
        .map(|(n, _)| *n)
        .collect();
    let mut removed = 0;
    while let Some(n) = ready.pop() {
        removed += 1;
        for &m in succ.get(&n).into_iter().flatten() {
            if let Some(d) = indeg.get_mut(&m) {
                *d -= 1;
                if *d == 0 {
                    ready.push(m);
                }
            }
        }
    }
    prop_assert_eq!(removed, nodes.len(), "cycle in contract graph {:?}", edges);
    Ok(())
}

/// Rooted at the Manager: every active module is reachable from it. Only
/// holds once the tree has settled: while a cancel or a priority update is
/// in flight, a provider may still hold a contract its client already left.
fn assert_rooted(s: &Sim, edges: &[Edge]) -> Result<(), TestCaseError> {
    let succ = successors(edges);
    let mut seen = BTreeSet::from([ModuleId(0)]);
    let mut stack = vec![ModuleId(0)];
    while let Some(n) = stack.pop() {
        for &m in succ.get(&n).into_iter().flatten() {
            if seen.insert(m) {
                stack.push(m);
            }
        }
    }
    for a in s.agents() {
        if a.is_active() {
            prop_assert!(
                seen.contains(&a.id()),
                "{} active but not under the Manager",
                a.id()
            );
        }
    }
    Ok(())
}

fn assert_priorities(s: &Sim) -> Result<(), TestCaseError> {
    for e in s.agreed_edges() {
        let client = s.agent(e.client).unwrap();
        let expect = client.priority().unwrap().child(e.need).unwrap();
        prop_assert_eq!(e.priority, expect);
    }
    for a in s.agents() {
        if a.config().manager {
            prop_assert_eq!(a.priority(), Some(Priority::ROOT));
            continue;
        }
        let best = Priority::most_important(a.client_contracts().map(|c| c.priority));
        prop_assert_eq!(a.priority(), best, "module {}", a.id());
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn contract_prop_layered_graphs(g in graph(true)) {
        let mut s = build(&g);
        s.run_until(ms(30_005));
        let settled = s.edges();
        s.run_until(ms(32_005));
        prop_assert_eq!(&settled, &s.edges(), "contract tree did not settle");
        prop_assert_eq!(s.edges(), s.agreed_edges(), "client and provider disagree");
        prop_assert_eq!(s.drops().total(), 0);
        assert_acyclic(&s.edges())?;
        assert_rooted(&s, &s.edges())?;
        assert_priorities(&s)?;
        // Every active module's required needs are served when an apt provider exists.
        let apt = apt_services(&g);
        for a in s.agents() {
            if !a.is_active() {
                continue;
            }
            for n in a.needs() {
                let sidx: usize = n.service[1..].parse().unwrap();
                if (n.is_required() || a.config().manager) && apt[sidx] {
                    prop_assert!(
                        a.provider(n.rank).is_some(),
                        "{} need {} ({}) unserved though an apt provider exists",
                        a.id(), n.rank, n.service
                    );
                }
            }
        }
        // Rule (2): an objective with an apt provider is served.
        for (k, &o) in g.objectives.iter().enumerate() {
            if apt[o] {
                prop_assert!(s.provider_of(ModuleId(0), k as u16 + 1).is_some());
            }
        }
    }

    #[test]
    fn contract_prop_arbitrary_graphs_no_cycles(g in graph(false)) {
        let mut s = build(&g);
        for step in 0..12u64 {
            s.run_until(ms(step * 1000 + 5));
            // The client-side view may lag by one message, and a priority
            // update may be in flight; the contracts both sides hold must
            // never form a cycle.
            assert_acyclic(&held_edges(&s))?;
        }
        s.run_until(ms(20_005));
        assert_acyclic(&s.edges())?;
        assert_rooted(&s, &s.edges())?;
        assert_priorities(&s)?;
    }

    #[test]
    fn contract_prop_arbiter_obeys_most_important_live_client(
        ops in prop::collection::vec((0u8..4, 0u32..4, 1u16..4, 0u64..250), 1..60)
    ) {
        let freshness = ms(300);
        let mut arb = CommandArbiter::new(freshness);
        let mut holders: BTreeMap<u32, (Priority, Option<Duration>)> = BTreeMap::new();
        let mut now = Duration::ZERO;
        for (op, client, pr, dt) in ops {
            now += ms(dt);
            let prio = Priority::new(&[pr, (client as u16) + 1]).unwrap();
            match op {
                0 => {
                    arb.offer(ModuleId(client), prio, now);
                    holders.entry(client).and_modify(|h| h.0 = prio).or_insert((prio, None));
                }
                1 => {
                    arb.release(ModuleId(client));
                    holders.remove(&client);
                }
                _ => {
                    let verdict = arb.on_command(ModuleId(client), now);
                    if let Some(h) = holders.get_mut(&client) {
                        h.1 = Some(now);
                        let winner = holders
                            .iter()
                            .filter(|(_, (_, t))| t.is_some_and(|t| now - t < freshness))
                            .min_by_key(|(id, (p, _))| (*p, **id))
                            .map(|(id, _)| *id);
                        let expect = if winner == Some(client) {
                            Verdict::Accept
                        } else {
                            Verdict::Ignore(DropReason::Preempted)
                        };
                        prop_assert_eq!(verdict, expect);
                    } else {
                        prop_assert_eq!(verdict, Verdict::Ignore(DropReason::NoContract));
                    }
                }
            }
            // The active client is always a holder with no live holder more important.
            if let Some(a) = arb.active(now) {
                let (pa, _) = holders[&a.0];
                for (id, (p, t)) in &holders {
                    if t.is_some_and(|t| now - t < freshness) {
                        prop_assert!((pa, a.0) <= (*p, *id));
                    }
                }
            }
        }
    }

    #[test]
    fn contract_prop_priority_order_display_parse(
        a in prop::collection::vec(1u16.., 0..8),
        b in prop::collection::vec(1u16.., 0..8),
    ) {
        let pa = Priority::new(&a).unwrap();
        let pb = Priority::new(&b).unwrap();
        prop_assert_eq!(pa.cmp(&pb), a.cmp(&b));
        prop_assert_eq!(pa.to_string().parse::<Priority>().unwrap(), pa);
        if pa.descends_from(&pb) {
            prop_assert!(pa.admitted_by(&pb));
            prop_assert!(pb <= pa);
        }
        if pa <= pb {
            prop_assert!(pa.admitted_by(&pb));
        }
    }

    #[test]
    fn contract_prop_decode_never_panics(bytes in prop::collection::vec(any::<u8>(), 0..1100)) {
        let _ = decode(&bytes);
        let mut framed = vec![b'H', b'C', crate::contract::WIRE_VERSION];
        framed.extend_from_slice(&bytes);
        if let Ok(env) = decode(&framed) {
            // Whatever decodes re-encodes to something that decodes the same.
            let again = encode(&env).unwrap();
            prop_assert_eq!(decode(&again).unwrap(), env);
        }
    }

    #[test]
    fn contract_prop_query_roundtrip(
        id in any::<u32>(), qid in any::<u64>(), need in 1u16.., value in -10.0f64..10.0,
        parts in prop::collection::vec(1u16.., 0..crate::contract::MAX_DEPTH),
        lineage in prop::collection::btree_set(any::<u32>(), 0..crate::contract::MAX_LINEAGE),
        fb in proptest::option::of(-1.0f32..=1.0),
    ) {
        let env = Envelope {
            from: ModuleId(id),
            body: Message::Query(Query {
                query_id: qid,
                need,
                service: "Localization".into(),
                kind: QueryKind::Refresh,
                priority: Some(Priority::new(&parts).unwrap()),
                selected: Some(Selected { provider: ModuleId(id ^ 1), value }),
                feedback: fb,
                reply_by_ns: qid,
                lineage: lineage.into_iter().map(ModuleId).collect(),
            }),
        };
        let bytes = encode(&env).unwrap();
        prop_assert!(bytes.len() <= crate::contract::MAX_MESSAGE_LEN);
        prop_assert_eq!(decode(&bytes).unwrap(), env);
    }
}
