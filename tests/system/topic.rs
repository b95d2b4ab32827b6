//! `hng topic list | echo | hz` against a running module.

use std::process::Command;
use std::time::Duration;

use hng_runtime::msg::Goal;
use hng_runtime::wait::{WaitMode, Waiter};

use crate::common::{TestSystem, json_lines};

fn hng(prefix: &str, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_hng"))
        .args(args)
        .env("HNG_PREFIX", prefix)
        .env("HNG_LOG", "warn")
        .output()
        .expect("run hng")
}

/// Starts the counter fixture and waits until its first message is out.
fn running_counter(sys: &mut TestSystem) {
    let node = sys.node("topic-test");
    let sub = node.subscriber::<Goal>("test/count").expect("subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&sub).expect("attach");
    sys.spawn_testmod("counter", "counter", "period_s = 0.01");
    while sub.receive().expect("receive").is_none() {
        waiter.wait(Some(Duration::from_secs(10))).expect("wait");
        assert!(waiter.any_ready(), "the counter never published");
    }
}

#[test]
fn topic_list_echo_and_hz_see_a_running_channel() {
    let mut sys = TestSystem::new("topic");
    running_counter(&mut sys);

    let list = json_lines(&hng(&sys.prefix, &["topic", "list", "--json"]));
    let count = list
        .iter()
        .find(|v| v["name"] == "test/count")
        .expect("test/count is listed");
    assert_eq!(count["type"], "hng/Goal/v1");
    assert!(
        list.iter().any(|v| v["name"] == "hng/report"),
        "the report channel is listed too"
    );

    let echoed = json_lines(&hng(
        &sys.prefix,
        &["topic", "echo", "test/count", "--count", "3", "--json"],
    ));
    let ids: Vec<u64> = echoed
        .iter()
        .map(|v| v["id"].as_u64().expect("id"))
        .collect();
    assert!(ids.len() >= 3, "{ids:?}");
    assert!(
        ids.windows(2).all(|w| w[1] > w[0]),
        "counts increase: {ids:?}"
    );

    let out = hng(
        &sys.prefix,
        &[
            "topic",
            "hz",
            "test/count",
            "--window",
            "0.3",
            "--count",
            "1",
            "--json",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).expect("json");
    assert_eq!(v["channel"], "test/count");
    assert!(v["messages"].as_u64().expect("messages") > 0);
    assert!(v["rate_hz"].as_f64().expect("rate") > 0.0);

    let out = hng(
        &sys.prefix,
        &["topic", "echo", "no/such/channel", "--count", "1"],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no/such/channel"));
    sys.stop_cleanly();
}
