//! The module SDK across processes: clean stop on SIGTERM, checkpoint and restore. (A missed
//! receive deadline, counted once in the module's report, is a module unit test on the
//! in-process harness: `security::tests::the_module_publishes_an_envelope_per_scan_and_the_stop_envelope_without_scans`.)

use std::time::Duration;

use hng_runtime::checkpoint::CheckpointStore;
use hng_runtime::msg::Goal;
use hng_runtime::wait::{WaitMode, Waiter};

use crate::common::TestSystem;

fn next_count(sub: &hng_runtime::Subscriber<Goal>, waiter: &mut Waiter) -> u32 {
    loop {
        if let Some(g) = sub.receive().expect("receive") {
            return g.id;
        }
        waiter.wait(Some(Duration::from_secs(10))).expect("wait");
        assert!(waiter.any_ready(), "the counter stopped publishing");
    }
}

#[test]
fn sigterm_stops_cleanly_and_the_restarted_module_restores_its_checkpoint() {
    let mut sys = TestSystem::new("ckpt");
    let dir = std::env::temp_dir().join(format!("{}ckpt", sys.prefix));
    let dir_s = dir.to_string_lossy().into_owned();
    let env = [
        ("HNG_CHECKPOINT_DIR", dir_s.as_str()),
        ("HNG_CHECKPOINT_PERIOD_MS", "50"),
    ];
    let node = sys.node("observer");
    let sub = node.subscriber::<Goal>("test/count").expect("subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&sub).expect("attach");

    sys.spawn_testmod_with("counter", "counter", "period_s = 0.005", &env);
    let mut last = 0;
    while last < 20 {
        last = next_count(&sub, &mut waiter);
    }
    let statuses = sys.stop_all();
    assert!(
        statuses[0].success(),
        "SIGTERM must be a clean stop: {:?}",
        statuses[0]
    );
    while let Some(g) = sub.receive().expect("drain") {
        last = g.id;
    }

    // The final checkpoint was written on stop: the new process counts on from there.
    sys.spawn_testmod_with("counter", "counter", "period_s = 0.005", &env);
    let first = next_count(&sub, &mut waiter);
    assert_eq!(first, last + 1, "restored count");
    sys.stop_all();

    // Checkpoints whose files are sound (checksums good) but whose payload is not the module's
    // state: both refused as a whole, and the module starts clean, counting from 1 again.
    while sub.receive().expect("drain").is_some() {}
    let store = |name: &str| CheckpointStore::new(&dir, name).expect("checkpoint store");
    store("counter").save(1, &[0xff; 9]).expect("write"); // a u32 that never ends
    store("counter.prev").save(1, &[5, 0, 0]).expect("write"); // a u32 and 2 bytes more
    sys.spawn_testmod_with("counter", "counter", "period_s = 0.005", &env);
    assert_eq!(
        next_count(&sub, &mut waiter),
        1,
        "a clean start after two undecodable checkpoints"
    );
    sys.stop_all();
    let _ = std::fs::remove_dir_all(&dir);
}
