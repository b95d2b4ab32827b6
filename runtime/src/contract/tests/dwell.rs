//! No flapping: a client does not go back to the provider it just left before the dwell time,
//! unless the provider it went to is lost.

use std::time::Duration;

use super::{manager, module, ms, sim};
use crate::contract::ModuleId;
use crate::contract::sim::Sim;

const MANAGER: ModuleId = ModuleId(1);
const CLIENT: ModuleId = ModuleId(2);
const A: ModuleId = ModuleId(3);
const B: ModuleId = ModuleId(4);

/// A client of "Localization" with two providers; A is better at first.
fn setup() -> Sim {
    let mut s = sim();
    s.add(manager(MANAGER.0, &["Navigation"]));
    s.add(module(
        CLIENT.0,
        0.9,
        &["Navigation"],
        &[("Localization", 1)],
    ));
    s.add(module(A.0, 0.8, &["Localization"], &[]));
    s.add(module(B.0, 0.5, &["Localization"], &[]));
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(CLIENT, 1), Some(A));
    s
}

fn set_q(s: &mut Sim, id: ModuleId, q: f64) {
    s.with(id, |a, _| {
        a.set_quality(q);
        Vec::new()
    });
}

/// Runs until the client's provider is `want`; the time it took.
fn until_provider(s: &mut Sim, want: ModuleId, limit: Duration) -> Option<Duration> {
    let t0 = s.now();
    while s.now() < t0 + limit {
        s.run_for(ms(10));
        if s.provider_of(CLIENT, 1) == Some(want) {
            return Some(s.now() - t0);
        }
    }
    None
}

#[test]
fn a_switch_back_to_the_provider_just_left_waits_for_the_dwell_time() {
    let mut s = setup();
    // A degrades: B's better offer wins.
    set_q(&mut s, A, 0.2);
    let to_b = until_provider(&mut s, B, ms(1000)).expect("never switched to B");
    assert!(to_b <= ms(450), "{to_b:?}");
    // A recovers at once: its better offers come with every refresh (200 ms), but the client
    // stays on B for the dwell time (1 s from the switch).
    let switched = s.now();
    set_q(&mut s, A, 0.8);
    let back = until_provider(&mut s, A, ms(3000)).expect("never went back to A");
    let since_switch = s.now() - switched;
    assert!(
        since_switch >= ms(1000),
        "went back to A {since_switch:?} after leaving it (dwell 1 s), waited {back:?}"
    );
    assert!(since_switch <= ms(1500), "{since_switch:?}");
    assert_eq!(s.edges(), s.agreed_edges());
}

#[test]
fn a_lost_provider_is_left_for_the_one_just_left_at_once() {
    let mut s = setup();
    set_q(&mut s, A, 0.2);
    until_provider(&mut s, B, ms(1000)).expect("never switched to B");
    // B dies within the dwell time: back to A at once, dwell or not.
    s.kill(B, true);
    let back = until_provider(&mut s, A, ms(1000)).expect("never went back to A");
    assert!(back <= ms(100), "{back:?}");
}

#[test]
fn a_zero_dwell_switches_back_with_the_next_better_offer() {
    let mut s = sim();
    let timing = crate::contract::Timing {
        switch_back_dwell: Duration::ZERO,
        ..Default::default()
    };
    let with_timing = |a: crate::contract::ContractAgent| {
        let mut cfg = a.config().clone();
        cfg.timing = timing;
        crate::contract::ContractAgent::new(cfg).unwrap()
    };
    s.add(with_timing(manager(MANAGER.0, &["Navigation"])));
    let mut client = with_timing(module(
        CLIENT.0,
        0.9,
        &["Navigation"],
        &[("Localization", 1)],
    ));
    client.set_quality(0.9);
    s.add(client);
    for (id, q) in [(A, 0.8), (B, 0.5)] {
        let mut a = with_timing(module(id.0, q, &["Localization"], &[]));
        a.set_quality(q);
        s.add(a);
    }
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(CLIENT, 1), Some(A));
    set_q(&mut s, A, 0.2);
    until_provider(&mut s, B, ms(1000)).expect("never switched to B");
    let switched = s.now();
    set_q(&mut s, A, 0.8);
    until_provider(&mut s, A, ms(1000)).expect("never went back to A");
    assert!(s.now() - switched < ms(600), "{:?}", s.now() - switched);
}

#[test]
fn a_provider_that_comes_back_is_not_judged_by_its_last_contracts_evaluation() {
    let mut s = setup();
    // The client rates A badly once (its clients' feedback) and never rates B (a tracker that
    // sees nothing gets no evaluation).
    s.with(CLIENT, |a, _| {
        a.evaluate_provider(1, A, -1.0);
        Vec::new()
    });
    until_provider(&mut s, B, ms(2000)).expect("never switched to B");
    // A's penalty decays (tau 5 s) until its offer wins again.
    until_provider(&mut s, A, ms(30_000)).expect("never went back to A");
    // Nothing new was said about A: the old -1 must not be sent again, so A keeps the
    // contract (it lost it again right after the dwell time when the stale one was re-sent).
    let back = s.now();
    while s.now() < back + ms(3000) {
        s.run_for(ms(10));
        assert_eq!(
            s.provider_of(CLIENT, 1),
            Some(A),
            "A lost the contract again {:?} after it came back",
            s.now() - back
        );
    }
}

#[test]
fn one_judgement_counts_once_however_many_refreshes_follow() {
    let mut s = setup();
    // A mild judgement once a second (the reacher's judge on a biased tracker), for 3 s: each
    // is one E_n of eq. 3. Re-sent with every refresh (5 a second) they piled up to -1.5 and
    // A, still the better provider, lost to B.
    for _ in 0..3 {
        s.with(CLIENT, |a, _| {
            a.evaluate_provider(1, A, -0.1);
            Vec::new()
        });
        s.run_for(ms(1000));
        assert_eq!(s.provider_of(CLIENT, 1), Some(A));
    }
    let v = s.agent(A).expect("A").value(s.now()).expect("value");
    assert!(
        v > 0.5 && v < 0.75,
        "three judgements of -0.1, decayed: V_A {v}"
    );
}
