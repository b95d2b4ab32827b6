//! The data plane across processes: ping-pong, content, clean-up, type errors.

use std::time::Duration;

use hng_runtime::channel::Node;
use hng_runtime::msg::{BytesInfo, Goal, Twist};
use hng_runtime::shm;
use hng_runtime::wait::{WaitMode, Waiter, Wake};

use crate::common::TestSystem;

fn pattern(round: u64, i: usize) -> u8 {
    (i as u64)
        .wrapping_mul(31)
        .wrapping_add(round.wrapping_mul(7)) as u8
}

/// Size of the pings that wait for the echo process to answer, bytes.
const WARM_UP_LEN: usize = 8;

/// Sends `rounds` payloads of `size` bytes to the echo process and checks every byte back.
fn ping_pong(node: &Node, size: usize, rounds: u64) {
    let ping = node
        .slice_publisher::<BytesInfo>("test/ping", size)
        .expect("ping publisher");
    let pong = node
        .slice_subscriber::<BytesInfo>("test/pong")
        .expect("pong subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&pong).expect("attach");

    // The echo process may not be subscribed yet: resend the first ping until it answers.
    let mut answered = false;
    for _ in 0..500 {
        ping.publish_copy(BytesInfo::default(), &[0u8; WARM_UP_LEN])
            .expect("send");
        if waiter.wait(Some(Duration::from_millis(20))).expect("wait") == Wake::Data {
            answered = true;
            break;
        }
    }
    assert!(answered, "echo process never answered");
    while pong.receive().expect("drain").is_some() {}

    for round in 1..=rounds {
        let loan = ping.loan_uninit(size).expect("loan");
        loan.write_from_fn(|i| pattern(round, i))
            .publish()
            .expect("publish");
        // An echo of a warm-up ping (8 bytes) may still come in after the drain above when
        // the echo process answered late (a loaded machine): it is not this round's.
        let sample = loop {
            let s = pong
                .receive_timeout(&mut waiter, Duration::from_secs(5))
                .expect("receive")
                .unwrap_or_else(|| panic!("no echo for round {round} of {size} bytes"));
            if s.data().len() != WARM_UP_LEN || size == WARM_UP_LEN {
                break s;
            }
        };
        let data = sample.data();
        assert_eq!(data.len(), size, "echoed length, round {round}");
        let bad = data
            .iter()
            .enumerate()
            .find(|(i, b)| **b != pattern(round, *i));
        assert!(
            bad.is_none(),
            "byte {:?} differs in round {round} ({size} bytes)",
            bad
        );
    }
}

#[test]
fn two_processes_ping_pong_64_bytes_and_1_mib_with_content_verified() {
    let mut sys = TestSystem::new("pp");
    sys.spawn_testmod("echo", "echo", "");
    {
        let node = sys.node("pinger");
        ping_pong(&node, 64, 200);
        ping_pong(&node, 1 << 20, 20);
    }
    sys.stop_cleanly();

    // After a clean stop only the system's own files remain (the prefix's management file,
    // hng's wake segments and CPU register); the system's final clean-up removes them.
    let unexpected = shm::leftovers(&sys.prefix);
    assert!(
        unexpected.is_empty(),
        "left behind after a clean stop: {unexpected:?}"
    );
    shm::remove_prefix_files(&sys.prefix);
    assert_eq!(
        shm::prefix_files(&sys.prefix),
        Vec::<std::path::PathBuf>::new()
    );
}

#[test]
fn subscriber_with_another_type_gets_an_error_naming_channel_and_both_types() {
    let sys = TestSystem::new("ty");
    let node = sys.node("typed");
    let _p = node.publisher::<Twist>("robot/cmd_vel").expect("publisher");
    let err = node
        .subscriber::<Goal>("robot/cmd_vel")
        .expect_err("a Goal subscriber on a Twist channel must fail");
    let msg = err.to_string();
    assert!(msg.contains("robot/cmd_vel"), "{msg}");
    assert!(msg.contains("hng/Twist/v1"), "{msg}");
    assert!(msg.contains("hng/Goal/v1"), "{msg}");
}

#[test]
fn state_channels_give_late_joiners_the_latest_sample() {
    let sys = TestSystem::new("late");
    let node = sys.node("early");
    let p = node.publisher::<Goal>("mission/goal").expect("publisher");
    for id in 1..=3 {
        p.publish(Goal {
            id,
            ..Default::default()
        })
        .expect("publish");
    }
    let late = sys.node("late");
    let s = late.subscriber::<Goal>("mission/goal").expect("subscriber");
    assert!(
        s.latest().expect("receive").is_none(),
        "history arrives when the publisher updates"
    );
    // What a module's executor does at every wake-up:
    node.update_connections();
    let got = s
        .latest()
        .expect("receive")
        .expect("the latest goal is delivered");
    assert_eq!(got.id, 3);
    assert_eq!(got.header.seq, 3);
}

#[test]
fn overflow_drops_are_counted_and_the_publisher_never_blocks() {
    let sys = TestSystem::new("ovf");
    let node = sys.node("fast");
    let p = node.publisher::<Twist>("robot/cmd_vel").expect("publisher");
    let s = node
        .subscriber::<Twist>("robot/cmd_vel")
        .expect("subscriber");
    // Drops are counted from the first message seen from a publisher.
    p.publish(Twist::default()).expect("publish");
    assert!(s.receive().expect("receive").is_some());
    // The subscriber reads nothing while 100 commands go out: the buffer (4) overflows.
    for i in 1..=100 {
        p.publish(Twist {
            linear_x: f64::from(i),
            ..Default::default()
        })
        .expect("publish never blocks");
    }
    let mut got = Vec::new();
    while let Some(m) = s.receive().expect("receive") {
        got.push(m.linear_x);
    }
    assert_eq!(got.last(), Some(&100.0), "the newest command survives");
    let stats = s.stats();
    assert_eq!(stats.received as usize, got.len() + 1);
    assert_eq!(stats.dropped + stats.received, 101, "{stats:?}");
    assert!(stats.dropped > 0);
}

#[test]
fn a_sample_the_waiter_saw_is_received_once_in_order() {
    let sys = TestSystem::new("ahead");
    let node = sys.node("ahead");
    let p = node.publisher::<Twist>("robot/cmd_vel").expect("publisher");
    let s = node
        .subscriber::<Twist>("robot/cmd_vel")
        .expect("subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&s).expect("attach");
    assert!(!s.has_samples());
    for i in 1..=3 {
        p.publish(Twist {
            linear_x: f64::from(i),
            ..Default::default()
        })
        .expect("publish");
    }
    // Looking for data (the waiter, then the subscriber itself) is not receiving it.
    assert_eq!(
        waiter.wait(Some(Duration::from_secs(5))).expect("wait"),
        Wake::Data
    );
    assert_eq!(waiter.ready().collect::<Vec<_>>(), vec![s.id()]);
    assert!(s.has_samples());
    assert_eq!(s.stats().received, 0, "a look is not a receipt");
    let mut got = Vec::new();
    while let Some(m) = s.receive().expect("receive") {
        got.push((m.linear_x, m.header.seq));
    }
    assert_eq!(got, vec![(1.0, 1), (2.0, 2), (3.0, 3)]);
    assert_eq!(s.stats().received, 3);
    assert_eq!(s.stats().dropped, 0);
    assert!(!s.has_samples());
}

#[test]
fn a_slice_publisher_grows_to_any_size_and_every_subscriber_gets_every_sample_in_order() {
    let sys = TestSystem::new("grow");
    let node = sys.node("grower");
    // The subscriber exists before the publisher and does not look at its port until the
    // segment has grown (as a module descheduled on a loaded machine): what was sent before
    // the growth must still arrive. (With a publisher replaced by a larger one, as hng grew
    // before, the first sample was lost here, uncounted.)
    let s = node
        .slice_subscriber::<BytesInfo>("test/grow")
        .expect("subscriber");
    let p = node
        .slice_publisher::<BytesInfo>("test/grow", 8)
        .expect("publisher");
    let send = |len: usize| {
        p.loan_uninit(len)
            .expect("loan")
            .write_from_fn(|i| pattern(len as u64, i))
            .publish()
            .expect("publish");
    };
    let receive_all = || {
        let mut got = Vec::new();
        while let Some(m) = s.receive().expect("receive") {
            let len = m.data().len();
            assert!(
                m.data()
                    .iter()
                    .enumerate()
                    .all(|(i, b)| *b == pattern(len as u64, i)),
                "content of the {len}-byte sample"
            );
            got.push((m.header().header.seq, len));
        }
        got
    };
    // The second send does not fit: the segment grows while the first sample is unread
    // (two samples: a bulk channel's subscriber buffer).
    send(8);
    send(100);
    assert_eq!(receive_all(), vec![(1, 8), (2, 100)]);
    send(1 << 20);
    send(10);
    assert_eq!(receive_all(), vec![(3, 1 << 20), (4, 10)]);
    let stats = s.stats();
    assert_eq!((stats.received, stats.dropped, stats.restarts), (4, 0, 0));
}

#[test]
fn the_spare_sample_a_publisher_loans_ahead_costs_no_loan_and_fits_any_length() {
    let sys = TestSystem::new("spare");
    let node = sys.node("spare");
    let p = node.publisher::<Twist>("robot/cmd_vel").expect("publisher");
    let s = node
        .subscriber::<Twist>("robot/cmd_vel")
        .expect("subscriber");
    let twist = |x: f64| Twist {
        linear_x: x,
        ..Twist::default()
    };
    let received = || {
        let mut got = Vec::new();
        while let Some(m) = s.receive().expect("receive") {
            got.push((m.header.seq, m.linear_x));
        }
        got
    };
    // After a publish the publisher holds a spare; a module may still hold iceoryx2's two
    // loans at once, because the spare is the first one handed out.
    p.publish(twist(1.0)).expect("publish");
    let mut a = p.loan().expect("first loan");
    let mut b = p.loan().expect("second loan, beside the spare");
    assert_eq!(a.linear_x, 0.0, "a loan starts from the default");
    a.linear_x = 2.0;
    b.linear_x = 3.0;
    b.publish().expect("publish b");
    a.publish().expect("publish a");
    p.publish(twist(4.0)).expect("publish");
    assert_eq!(
        received(),
        vec![(1, 1.0), (2, 3.0), (3, 2.0), (4, 4.0)],
        "sequence numbers follow the publish order"
    );

    // Slices: the spare is loaned for a steady length and dropped for any other.
    let p = node
        .slice_publisher::<BytesInfo>("test/spare", 64)
        .expect("slice publisher");
    let s = node
        .slice_subscriber::<BytesInfo>("test/spare")
        .expect("slice subscriber");
    for (round, len) in [16, 16, 16, 32, 32, 8, 8, 500, 500, 0, 0, 16]
        .into_iter()
        .enumerate()
    {
        let round = round as u64 + 1;
        p.loan_uninit(len)
            .expect("loan")
            .write_from_fn(|i| pattern(round, i))
            .publish()
            .expect("publish");
        let m = s.receive().expect("receive").expect("a sample");
        assert_eq!(m.header().header.seq, round);
        assert_eq!(m.data().len(), len, "length of sample {round}");
        assert!(
            m.data()
                .iter()
                .enumerate()
                .all(|(i, b)| *b == pattern(round, i)),
            "content of sample {round}"
        );
    }
    assert_eq!(s.stats().dropped, 0);
}

#[test]
fn receive_timeout_gives_the_next_message_or_none_when_the_time_is_up_in_both_modes() {
    let sys = TestSystem::new("rto");
    let node = sys.node("rto");
    let p = node.publisher::<Twist>("robot/cmd_vel").expect("publisher");
    let s = node
        .subscriber::<Twist>("robot/cmd_vel")
        .expect("subscriber");
    for mode in [WaitMode::default(), WaitMode::Spin] {
        let mut waiter = Waiter::new(mode).expect("waiter");
        waiter.attach(&s).expect("attach");
        let none = s
            .receive_timeout(&mut waiter, Duration::from_millis(5))
            .expect("receive");
        assert!(none.is_none(), "{mode:?}: nothing was published");
        for x in [1.0, 2.0] {
            p.publish(Twist {
                linear_x: x,
                ..Default::default()
            })
            .expect("publish");
        }
        for x in [1.0, 2.0] {
            let m = s
                .receive_timeout(&mut waiter, Duration::from_secs(5))
                .expect("receive")
                .expect("a message");
            assert_eq!(m.linear_x, x, "{mode:?}: in order");
        }
    }
}
