//! Client feedback (the E term of eq. 3) with real processes: a Localization source that
//! claims Q = 1 while wrong (the `liar` fixture: its pose moves 30 % as far as the robot, with
//! a claimed 2 cm uncertainty) wins the Servo's and Planning's "Localization" at first; once
//! the robot moves, the Servo rates it by consistency with odometry, and the feedback takes
//! the contract from it (to SLAM) within a bounded time.

use hng_runtime::msg::OrderKind;
use hng_runtime::shm;
use nix::sys::signal::Signal;

use crate::common::{Watch, dist, goal};
use crate::orders::{launch, write_map};
use crate::signals::Run;

const TESTMOD: &str = env!("CARGO_BIN_EXE_hng-testmod");

#[test]
fn a_lying_localization_loses_its_contract_through_the_servos_feedback() {
    let _heavy = crate::common::heavy();
    let prefix = shm::unique_prefix("feedback");
    let dir = crate::signals::test_dir(&prefix);
    std::fs::create_dir_all(&dir).expect("dir");
    let map = write_map(&dir, None);
    let mut plan = launch(&map, None, (2.0, 2.0, 0.0), &[]);
    plan.push_str(&format!(
        "\n[[module]]\nname = \"liar\"\ncommand = [{TESTMOD:?}, \"liar\"]\n[module.config]\nstart = {{ x = 2.0, y = 2.0, theta = 0.0 }}\n"
    ));
    let file = dir.join("feedback.toml");
    std::fs::write(&file, plan).expect("launch");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    watch.until("the liar selected by the Servo and Planning", |w| {
        w.sim_s() > 1.0
            && w.provider_of("servo", 2).as_deref() == Some("liar")
            && w.provider_of("planning", 3).as_deref() == Some("liar")
    });
    let s = watch.order(goal(OrderKind::Goal, &[(5.5, 3.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.until("the liar still selected (Planning and Servo active)", |w| {
        w.provider_of("servo", 2).as_deref() == Some("liar")
    });
    let start = watch.xy();
    watch.until("the robot moving", |w| dist(w.xy(), start) > 0.05);
    let t_move = watch.sim_s();
    watch.until("the Servo's Localization away from the liar", |w| {
        w.provider_of("servo", 2).as_deref() != Some("liar")
    });
    let t_switch = watch.sim_s();
    let to = watch.provider_of("servo", 2);
    watch.until("Planning's Localization away from the liar", |w| {
        w.provider_of("planning", 3).as_deref() != Some("liar")
    });
    let t_planning = watch.sim_s();
    eprintln!(
        "feedback: the liar lost the Servo's Localization {:.2} s (simulated) after the robot \
         started moving (to {to:?}), Planning's {:.2} s after",
        t_switch - t_move,
        t_planning - t_move
    );
    assert_eq!(to.as_deref(), Some("slam"));
    assert!(t_switch - t_move <= 3.0, "{:.2} s", t_switch - t_move);
    assert!(t_planning - t_move <= 3.5, "{:.2} s", t_planning - t_move);

    drop(watch);
    run.signal(Signal::SIGTERM);
    let status = run.wait();
    run.assert_left_nothing();
    assert_eq!(status.code(), Some(0));
}
