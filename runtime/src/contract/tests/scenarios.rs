//! Deterministic multi-agent scenarios from the paper.

use std::time::Duration;

use super::{manager, module, ms, sim};
use crate::contract::sim::Sim;
use crate::contract::{
    AgentEvent, CommandArbiter, DropReason, ModuleId, NeedSpec, Priority, Verdict,
};

const MANAGER: ModuleId = ModuleId(0);
const SECURITY: ModuleId = ModuleId(1);
const INTERFACE: ModuleId = ModuleId(2);
const ROBOT: ModuleId = ModuleId(3);
const LASER: ModuleId = ModuleId(4);
const PLANNING: ModuleId = ModuleId(5);
const SERVO: ModuleId = ModuleId(6);
const SLAM: ModuleId = ModuleId(7);
const GPS: ModuleId = ModuleId(8);
const MAPS: ModuleId = ModuleId(9);

fn p(s: &str) -> Priority {
    s.parse().unwrap()
}

/// The navigation example of the paper (5.8, Table 1). Need ranks follow
/// Table 1; the Interface's needs are ordered "Robot control" then "Reach
/// goal", which is what gives the paper's 2.2.1.1 for the servo's control query.
fn navigation() -> Sim {
    let mut s = sim();
    s.add(manager(0, &["Robot integrity", "Human control"]));
    s.add(module(
        1,
        0.5,
        &["Robot integrity"],
        &[("Robot control", 1), ("LIDAR data", 2)],
    ));
    s.add(module(
        2,
        0.5,
        &["Human control"],
        &[("Robot control", 1), ("Reach goal", 2)],
    ));
    s.add(module(3, 0.9, &["Robot control", "Odometry"], &[]));
    s.add(module(4, 0.9, &["LIDAR data"], &[]));
    s.add(module(
        5,
        0.6,
        &["Reach goal"],
        &[("Reach waypoint", 1), ("Mapping", 2)],
    ));
    s.add(module(
        6,
        0.6,
        &["Reach waypoint"],
        &[("Robot control", 1), ("Localization", 2)],
    ));
    s.add(module(
        7,
        0.8,
        &["Localization", "Mapping"],
        &[("Odometry", 1), ("LIDAR data", 2)],
    ));
    s.add(module(8, 0.5, &["Localization"], &[]));
    s.add(module(9, 0.25, &["Mapping"], &[]));
    s
}

fn prio(s: &Sim, id: ModuleId) -> Option<Priority> {
    s.agent(id).and_then(|a| a.priority())
}

fn need_prio(s: &Sim, id: ModuleId, need: u16) -> Option<Priority> {
    s.agent(id)
        .and_then(|a| a.contract(need))
        .map(|c| c.priority)
}

#[test]
fn contract_scenario_paper_5_8_navigation_tree_and_priorities() {
    let mut s = navigation();
    s.run_for(ms(2000));
    // Contract tree of Figure 3.
    assert_eq!(s.provider_of(MANAGER, 1), Some(SECURITY));
    assert_eq!(s.provider_of(MANAGER, 2), Some(INTERFACE));
    assert_eq!(s.provider_of(SECURITY, 1), Some(ROBOT));
    assert_eq!(s.provider_of(SECURITY, 2), Some(LASER));
    assert_eq!(s.provider_of(INTERFACE, 1), Some(ROBOT));
    assert_eq!(s.provider_of(INTERFACE, 2), Some(PLANNING));
    assert_eq!(s.provider_of(PLANNING, 1), Some(SERVO));
    assert_eq!(s.provider_of(PLANNING, 2), Some(SLAM), "SLAM beats Maps");
    assert_eq!(s.provider_of(SERVO, 1), Some(ROBOT));
    assert_eq!(s.provider_of(SERVO, 2), Some(SLAM), "V_SLAM > V_GPS");
    assert_eq!(s.provider_of(SLAM, 1), Some(ROBOT));
    assert_eq!(s.provider_of(SLAM, 2), Some(LASER));
    assert!(!s.agent(GPS).unwrap().is_active());
    assert!(!s.agent(MAPS).unwrap().is_active());
    // The paper's numbers.
    assert_eq!(need_prio(&s, MANAGER, 1), Some(p("1")));
    assert_eq!(need_prio(&s, MANAGER, 2), Some(p("2")));
    assert_eq!(need_prio(&s, SECURITY, 1), Some(p("1.1")));
    assert_eq!(need_prio(&s, INTERFACE, 1), Some(p("2.1")));
    assert_eq!(need_prio(&s, SERVO, 1), Some(p("2.2.1.1")));
    // Module priorities = most important client contract.
    assert_eq!(prio(&s, MANAGER), Some(Priority::ROOT));
    assert_eq!(prio(&s, ROBOT), Some(p("1.1")));
    assert_eq!(prio(&s, LASER), Some(p("1.2")));
    assert_eq!(prio(&s, PLANNING), Some(p("2.2")));
    assert_eq!(prio(&s, SERVO), Some(p("2.2.1")));
    assert_eq!(prio(&s, SLAM), Some(p("2.2.1.2")));
    assert_eq!(need_prio(&s, SLAM, 1), Some(p("2.2.1.2.1")));
    // Both sides agree on every contract, and nothing was dropped on the wire.
    assert_eq!(s.edges(), s.agreed_edges());
    assert_eq!(s.edges().len(), 12);
    assert_eq!(s.drops().total(), 0);

    // Driver arbitration on the robot: security > operator > servo.
    let robot = s.agent(ROBOT).unwrap();
    let mut arb = CommandArbiter::new(ms(300));
    arb.sync(
        robot
            .client_contracts()
            .filter(|c| c.service == "Robot control")
            .map(|c| (c.client, c.priority)),
    );
    assert_eq!(arb.holders(), 3);
    let now = s.now();
    assert_eq!(arb.on_command(SERVO, now), Verdict::Accept);
    assert_eq!(arb.on_command(INTERFACE, now), Verdict::Accept);
    assert_eq!(
        arb.on_command(SERVO, now),
        Verdict::Ignore(DropReason::Preempted)
    );
    assert_eq!(arb.on_command(SECURITY, now), Verdict::Accept);
    assert_eq!(
        arb.on_command(INTERFACE, now),
        Verdict::Ignore(DropReason::Preempted)
    );
    assert_eq!(
        arb.on_command(GPS, now),
        Verdict::Ignore(DropReason::NoContract)
    );
}

#[test]
fn contract_scenario_paper_5_8_localization_switches_and_recovers() {
    let mut s = navigation();
    s.run_for(ms(2000));
    assert_eq!(s.provider_of(SERVO, 2), Some(SLAM));

    // SLAM's quality drops below GPS's minus the threshold.
    s.with(SLAM, |a, _| {
        a.set_quality(0.2);
        Vec::new()
    });
    let t0 = s.now();
    let mut switched_at = None;
    while s.now() < t0 + ms(2000) {
        s.run_for(ms(10));
        if switched_at.is_none() && s.provider_of(SERVO, 2) == Some(GPS) {
            switched_at = Some(s.now() - t0);
        }
    }
    let switched_at = switched_at.expect("localization never switched to GPS");
    assert!(switched_at <= ms(450), "switch took {switched_at:?}");
    assert_eq!(s.provider_of(SERVO, 2), Some(GPS));
    assert!(s.agent(GPS).unwrap().is_active());
    // Mapping stays on SLAM (Maps is not better by the threshold), so SLAM's
    // priority now derives from the mapping contract, and its own needs follow.
    assert_eq!(s.provider_of(PLANNING, 2), Some(SLAM));
    assert_eq!(prio(&s, SLAM), Some(p("2.2.2")));
    assert_eq!(need_prio(&s, SLAM, 1), Some(p("2.2.2.1")));
    assert_eq!(prio(&s, GPS), Some(p("2.2.1.2")));
    assert_eq!(s.edges(), s.agreed_edges());

    // A dip that stays within the hysteresis does not switch back.
    s.with(SLAM, |a, _| {
        a.set_quality(0.55);
        Vec::new()
    });
    s.run_for(ms(1500));
    assert_eq!(s.provider_of(SERVO, 2), Some(GPS));

    // Recovery: SLAM is better again by more than the threshold.
    s.with(SLAM, |a, _| {
        a.set_quality(0.8);
        Vec::new()
    });
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(SERVO, 2), Some(SLAM));
    assert!(!s.agent(GPS).unwrap().is_active());
    assert_eq!(prio(&s, SLAM), Some(p("2.2.1.2")));
    assert_eq!(s.edges(), s.agreed_edges());
    assert_eq!(s.drops().total(), 0);
}

#[test]
fn contract_scenario_paper_4_2_feedback_corrects_biased_provider() {
    let (a_id, b_id) = (ModuleId(1), ModuleId(2));
    let mut s = sim();
    s.add(manager(0, &["Task"]));
    s.add(module(1, 0.9, &["Task"], &[])); // optimistic but bad
    s.add(module(2, 0.3, &["Task"], &[])); // pessimistic but good
    let truth = |id: ModuleId| if id == a_id { -0.6 } else { 0.7 };

    let mut history = Vec::new();
    for _ in 0..3000 {
        s.run_for(ms(10));
        let current = s.provider_of(MANAGER, 1);
        if let Some(prov) = current {
            // The Manager evaluates (unbiased) what it gets.
            s.with(MANAGER, |m, _| {
                m.evaluate_provider(1, prov, truth(prov));
                Vec::new()
            });
        }
        if history.last() != Some(&current) {
            history.push(current);
        }
    }
    assert_eq!(
        history,
        vec![None, Some(a_id), Some(b_id)],
        "A first, then B for good"
    );
    let now = s.now();
    let va = s.agent(a_id).unwrap().value(now).unwrap();
    let vb = s.agent(b_id).unwrap().value(now).unwrap();
    assert!(vb > va, "V_B {vb} must stay above V_A {va}");
    assert!(va > 0.8, "A's penalty has decayed: {va}");
}

#[test]
fn contract_scenario_provider_death_next_best_takes_over() {
    let mut s = sim();
    s.add(manager(0, &["Task"]));
    s.add(module(1, 0.9, &["Task"], &[]));
    s.add(module(2, 0.6, &["Task"], &[]));
    s.add(module(3, 0.3, &["Task"], &[]));
    s.run_for(ms(500));
    assert_eq!(s.provider_of(MANAGER, 1), Some(ModuleId(1)));

    // Watchdog-reported death: replaced at once, without a new call.
    s.kill(ModuleId(1), true);
    assert_eq!(s.provider_of(MANAGER, 1), Some(ModuleId(2)));
    s.run_for(ms(5));
    assert!(s.agent(ModuleId(2)).unwrap().is_active());

    // Silent death: detected by the value-report timeout.
    s.kill(ModuleId(2), false);
    let t0 = s.now();
    while s.provider_of(MANAGER, 1) == Some(ModuleId(2)) {
        s.run_for(ms(10));
        assert!(s.now() - t0 < ms(2000), "silent provider never replaced");
    }
    let took = s.now() - t0;
    assert!(took >= ms(800) && took <= ms(1300), "took {took:?}");
    assert_eq!(s.provider_of(MANAGER, 1), Some(ModuleId(3)));
    s.run_for(ms(100));
    assert!(s.agent(ModuleId(3)).unwrap().is_active());
}

#[test]
fn contract_scenario_required_need_unmet_cancels_upward_then_recovers() {
    let (x, y, z) = (ModuleId(1), ModuleId(2), ModuleId(3));
    let mut s = sim();
    s.add(manager(0, &["Task"]));
    s.add(module(1, 0.9, &["Task"], &[("Sub", 1)])); // better, but needs Sub
    s.add(module(2, 0.4, &["Task"], &[]));
    s.run_for(ms(3000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(y));
    assert!(!s.agent(x).unwrap().is_active());
    assert!(s.agent(x).unwrap().needs_unmet());
    // Stable: X keeps refusing while its need is unmet.
    let mut switches = 0;
    for _ in 0..500 {
        s.run_for(ms(10));
        if s.provider_of(MANAGER, 1) != Some(y) {
            switches += 1;
        }
    }
    assert_eq!(switches, 0);

    // A provider of Sub appears: X's probe succeeds, X offers itself and wins.
    s.add(module(3, 0.5, &["Sub"], &[]));
    s.run_for(ms(3000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(x));
    assert_eq!(s.provider_of(x, 1), Some(z));
    assert!(!s.agent(y).unwrap().is_active());
    assert_eq!(s.edges(), s.agreed_edges());
}

#[test]
fn contract_scenario_degraded_mode_sheds_less_important_objectives() {
    let mut s = navigation();
    s.run_for(ms(2000));
    let ids: Vec<ModuleId> = s.agents().map(|a| a.id()).collect();
    for &id in &ids {
        s.with(id, |a, _| {
            a.set_min_priority(Some(p("1")));
            Vec::new()
        });
    }
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(SECURITY));
    assert_eq!(s.provider_of(MANAGER, 2), None);
    for id in [INTERFACE, PLANNING, SERVO, SLAM, GPS, MAPS] {
        assert!(!s.agent(id).unwrap().is_active(), "{id} still active");
    }
    assert_eq!(prio(&s, ROBOT), Some(p("1.1")));
    assert_eq!(s.agent(ROBOT).unwrap().client_contracts().count(), 1);
    assert!(s.agent(LASER).unwrap().is_active());

    for &id in &ids {
        s.with(id, |a, _| {
            a.set_min_priority(None);
            Vec::new()
        });
    }
    s.run_for(ms(2000));
    assert_eq!(s.provider_of(MANAGER, 2), Some(INTERFACE));
    assert_eq!(need_prio(&s, SERVO, 1), Some(p("2.2.1.1")));
    assert_eq!(s.edges().len(), 12);
    assert_eq!(s.edges(), s.agreed_edges());
}

#[test]
fn contract_scenario_serve_nothing_cancels_every_contract() {
    // The RM's most severe degraded mode (5.3: "a global stop of the system"): no query
    // of any priority is answered, so established contracts end too, not only new ones.
    let mut s = navigation();
    s.run_for(ms(2000));
    assert_eq!(s.edges().len(), 12);
    let ids: Vec<ModuleId> = s.agents().map(|a| a.id()).collect();
    for &id in &ids {
        s.with(id, |a, _| {
            a.set_lacking_resources(true);
            Vec::new()
        });
    }
    s.run_for(ms(1000));
    assert_eq!(s.edges(), Vec::new(), "contracts survived serve-nothing");
    assert_eq!(s.provider_of(MANAGER, 1), None);
    assert_eq!(s.provider_of(MANAGER, 2), None);
    for &id in ids.iter().filter(|&&id| id != MANAGER) {
        assert!(!s.agent(id).unwrap().is_active(), "{id} still active");
    }

    for &id in &ids {
        s.with(id, |a, _| {
            a.set_lacking_resources(false);
            Vec::new()
        });
    }
    s.run_for(ms(2000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(SECURITY));
    assert_eq!(s.provider_of(MANAGER, 2), Some(INTERFACE));
    assert_eq!(s.edges().len(), 12);
    assert_eq!(s.edges(), s.agreed_edges());
}

#[test]
fn contract_scenario_cycle_refused() {
    // A needs s2, B provides s2 and needs s1, which A provides: B must not
    // contract A (its ancestor) and takes C instead.
    let (a, b, c) = (ModuleId(1), ModuleId(2), ModuleId(3));
    let mut s = sim();
    s.add(manager(0, &["s1"]));
    s.add(module(1, 0.9, &["s1"], &[("s2", 1)]));
    s.add(module(2, 0.9, &["s2"], &[("s1", 1)]));
    s.add(module(3, 0.1, &["s1"], &[]));
    s.run_for(ms(2000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(a));
    assert_eq!(s.provider_of(a, 1), Some(b));
    assert_eq!(s.provider_of(b, 1), Some(c));
    assert_eq!(s.edges(), s.agreed_edges());
}

#[test]
fn contract_scenario_optional_need_lowers_value_not_aptitude() {
    let mut s = sim();
    s.add(manager(0, &["Task"]));
    let mut cfg = crate::contract::AgentConfig::new(ModuleId(1))
        .provide(crate::contract::ServiceOffer::new("Task", ""));
    cfg = cfg.need(NeedSpec::optional("Extra", 1, 0.3));
    let mut x = crate::contract::ContractAgent::new(cfg).unwrap();
    x.set_quality(0.7);
    s.add(x);
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(ModuleId(1)));
    let v = s.agent(ModuleId(1)).unwrap().value(s.now()).unwrap();
    assert!((v - 0.4).abs() < 1e-9, "{v}");
    s.add(module(2, 0.5, &["Extra"], &[]));
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(ModuleId(1), 1), Some(ModuleId(2)));
    let v = s.agent(ModuleId(1)).unwrap().value(s.now()).unwrap();
    assert!((v - 0.7).abs() < 1e-9, "{v}");
}

#[test]
fn contract_scenario_events_and_aptitude_loss() {
    let mut s = sim();
    s.add(manager(0, &["Task"]));
    s.add(module(1, 0.9, &["Task"], &[]));
    s.add(module(2, 0.5, &["Task"], &[]));
    s.run_for(ms(500));
    s.with(MANAGER, |m, _| {
        let ev = m.drain_events();
        assert!(ev.iter().any(|e| matches!(
            e,
            AgentEvent::ProviderSelected {
                need: 1,
                provider: ModuleId(1),
                ..
            }
        )));
        Vec::new()
    });
    // f = 0: the provider cancels, the next best takes over.
    s.with(ModuleId(1), |a, _| {
        a.set_aptitude(false);
        Vec::new()
    });
    s.run_for(ms(100));
    assert_eq!(s.provider_of(MANAGER, 1), Some(ModuleId(2)));
    // NaN quality is treated as f = 0 too.
    s.with(ModuleId(2), |a, _| {
        a.set_quality(f64::NAN);
        Vec::new()
    });
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(MANAGER, 1), None);
    s.with(ModuleId(1), |a, _| {
        a.set_aptitude(true);
        Vec::new()
    });
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(MANAGER, 1), Some(ModuleId(1)));
}

#[test]
fn contract_scenario_deterministic() {
    let run = || {
        let mut s = navigation();
        s.run_for(ms(1500));
        s.with(SLAM, |a, _| {
            a.set_quality(0.1);
            Vec::new()
        });
        s.run_for(Duration::from_secs(2));
        (s.edges(), s.delivered())
    };
    assert_eq!(run(), run());
}

/// A provider that starts after its client gave up (the usual order when a whole system
/// starts at once) is called as soon as the transport sees it, not after the retry period.
#[test]
fn contract_scenario_new_provider_is_called_at_once() {
    use crate::contract::{AgentConfig, ContractAgent, Message};
    let queries = |out: &[crate::contract::Outgoing]| {
        out.iter()
            .filter(|o| matches!(o.envelope.body, Message::Query(_)))
            .count()
    };
    let mut m = ContractAgent::new(AgentConfig::manager(MANAGER, &["Reach goal"])).unwrap();
    assert_eq!(queries(&m.tick(ms(0))), 1, "the objective is called");
    m.set_provider_count("Reach goal", 0);
    assert_eq!(queries(&m.tick(ms(60))), 0, "no proposal: the call fails");
    assert_eq!(queries(&m.tick(ms(100))), 0, "waiting for the retry period");
    m.set_provider_count("Reach goal", 0);
    assert_eq!(
        queries(&m.tick(ms(110))),
        0,
        "no new provider: still waiting"
    );
    m.set_provider_count("Reach goal", 1);
    assert_eq!(
        queries(&m.tick(ms(120))),
        1,
        "a provider appeared: called at once"
    );
}

/// The navigation tree built by agents woken only at their own deadlines (and on messages),
/// as the module executor runs them, instead of every 10 ms.
fn navigation_by_deadlines() -> Sim {
    let ticked = navigation();
    let mut s = Sim::new(crate::contract::sim::SimConfig {
        tick: Duration::ZERO,
        ..Default::default()
    });
    for a in ticked.agents() {
        s.add(a.clone());
    }
    s
}

#[test]
fn contract_scenario_agents_woken_at_their_deadlines_build_the_same_tree_with_few_wakeups() {
    let mut ticked = navigation();
    let mut woken = navigation_by_deadlines();
    ticked.run_for(ms(2000));
    woken.run_for(ms(2000));
    assert_eq!(woken.edges(), ticked.edges());
    assert_eq!(woken.edges(), woken.agreed_edges());
    assert_eq!(woken.edges().len(), 12);
    assert_eq!(
        woken.stuck(),
        0,
        "no agent asked to be ticked again at once"
    );

    // A quiet stretch: heartbeats and refreshes only (every 200 ms by default).
    let (t0, w0) = (ticked.ticks(), woken.ticks());
    ticked.run_for(ms(10_000));
    woken.run_for(ms(10_000));
    let (t, w) = (ticked.ticks() - t0, woken.ticks() - w0);
    assert_eq!(t, 10 * 1000, "10 agents, every 10 ms");
    assert!(w < t / 5, "deadline wake-ups {w} vs ticks {t}");
    assert_eq!(woken.edges(), ticked.edges());

    // The tree re-forms the same way when SLAM dies (found by timeout, no watchdog).
    ticked.kill(SLAM, false);
    woken.kill(SLAM, false);
    ticked.run_for(ms(3000));
    woken.run_for(ms(3000));
    assert!(woken.provider_of(SERVO, 2).is_some_and(|p| p != SLAM));
    assert_eq!(woken.edges(), ticked.edges());
    assert_eq!(woken.stuck(), 0);
}
