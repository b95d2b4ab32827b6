//! Teleoperation by hand with `hng topic pub`: finite commands on `hng/teleop` drive the
//! simulated robot through the Interface and the Robot (under their contract); NaN and
//! infinite ones never move it and are counted (the Interface's report, `msgs_dropped`).

use std::process::{Child, Command, Stdio};

use nix::sys::signal::Signal;

use crate::common::{Watch, dist};
use crate::signals::Run;

const HNG: &str = env!("CARGO_BIN_EXE_hng");

/// The Table 1 modules a teleoperated robot needs, the Manager with no goals; the simulator's
/// built-in world, or `world`.
fn launch(world: Option<&std::path::Path>) -> String {
    let mut sim =
        "speed = 2\nwait_for = [\"laser\", \"robot\", \"security\", \"interface\", \"manager\"]"
            .to_owned();
    if let Some(w) = world {
        sim.push_str(&format!("\nworld = {:?}", w.to_string_lossy()));
    }
    crate::common::launch_file(
        "teleop",
        3.0,
        10.0,
        &[
            ("simulator", "", &sim),
            ("laser", "", ""),
            ("robot", "", ""),
            ("security", "", ""),
            ("interface", "", ""),
            ("manager", "manager = true", "goals = []"),
        ],
    )
}

/// `hng topic pub hng/teleop JSON --rate 20`, running until it is stopped.
fn teleop(prefix: &str, json: &str, count: Option<u64>) -> Child {
    let mut c = Command::new(HNG);
    c.args(["topic", "pub", "hng/teleop", json, "--rate", "20"])
        .env("HNG_PREFIX", prefix)
        .env("HNG_LOG", "warn")
        .stdin(Stdio::null());
    if let Some(n) = count {
        c.args(["--count", &n.to_string()]);
    }
    c.spawn().expect("hng topic pub")
}

fn stop(mut c: Child) {
    let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(c.id() as i32), Signal::SIGTERM);
    let s = c.wait().expect("wait");
    assert!(s.success(), "hng topic pub ends cleanly on SIGTERM: {s:?}");
}

#[test]
fn non_finite_teleop_commands_never_move_the_robot_and_are_counted() {
    let _heavy = crate::common::heavy();
    let (prefix, dir) = crate::signals::prefix_and_dir("teleop");
    let file = dir.join("teleop.toml");
    std::fs::write(&file, launch(None)).expect("launch file");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    watch.until("simulated time running", |w| {
        w.sim_s() > 0.5 && w.pose.is_some()
    });

    // Finite commands drive the robot: the path from `hng topic pub` to the base works.
    let start = watch.xy();
    let go = teleop(&prefix, r#"{"linear_x": 0.3}"#, None);
    watch.until("the robot moving under teleoperation", |w| {
        dist(w.xy(), start) > 0.1
    });
    stop(go);
    // Stopped: the Robot sends a stop when the operator's commands stop coming.
    watch.until_still("the robot at rest", 1.0);
    let rest = watch.xy();
    let rejected_before = watch.sim.map_or(0, |s| s.rejected_commands);
    let dropped_before = watch.interface_dropped;

    // NaN and infinite velocities, 40 of each kind: never forwarded, counted.
    let n = 40;
    for json in [
        r#"{"linear_x": NaN}"#,
        r#"{"linear_x": "inf"}"#,
        r#"{"angular_z": -Infinity, "linear_x": 0.3}"#,
    ] {
        let mut c = teleop(&prefix, json, Some(n));
        let s = c.wait().expect("wait");
        assert!(s.success(), "hng topic pub {json}: {s:?}");
    }
    watch.until("the Interface counting the non-finite commands", |w| {
        w.interface_dropped >= dropped_before + 3 * n
    });
    let t0 = watch.sim_s();
    watch.until("one more simulated second", |w| w.sim_s() > t0 + 1.0);
    let moved = dist(watch.xy(), rest);
    assert!(
        moved < 0.01,
        "non-finite commands moved the robot by {moved:.3} m"
    );
    assert_eq!(
        watch.sim.map_or(0, |s| s.rejected_commands),
        rejected_before,
        "no non-finite command reached the simulator"
    );

    drop(watch);
    run.stop_ok();
}

/// Security SIGKILLed under `hng run` is started again by the supervisor, contracted again
/// by the Robot, and guards the wheels again: an operator pushing full speed at a wall is held
/// short of it, still pushing (docs/fault-matrix.md, "Security dead, restarting or blind").
/// The robot stands still while Security is down (no teleop yet): what the Robot does in the
/// outage itself is the Robot's unit test (`guard_of`).
#[test]
fn a_killed_security_is_restarted_and_holds_a_teleoperated_robot_short_of_a_wall_again() {
    use crate::modules::{RADIUS, WALL_FACE_X, world_file};
    use hng_modules::security::ROBOT_CONTROL_NEED;
    use hng_runtime::system::{EventKind, ModuleEvent, SUPERVISOR_EVENTS};
    use hng_runtime::{Node, NodeOptions};

    let _heavy = crate::common::heavy();
    let (prefix, dir) = crate::signals::prefix_and_dir("secrestart");
    let world = dir.join("wall.toml");
    std::fs::write(&world, world_file()).expect("world file");
    let file = dir.join("secrestart.toml");
    std::fs::write(&file, launch(Some(&world))).expect("launch file");
    let node = Node::new(NodeOptions::new("secrestart-events").prefix(&prefix)).expect("node");
    let events = node
        .subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)
        .expect("events");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    let guarded =
        |w: &Watch| w.provider_of("security", ROBOT_CONTROL_NEED).as_deref() == Some("robot");
    watch.until("Security contracted by the Robot", |w| {
        w.sim_s() > 0.5 && w.pose.is_some() && guarded(w)
    });
    while events.receive().expect("events").is_some() {}

    let out = run.hng(&["kill", "security"]);
    assert!(out.status.success(), "hng kill security: {out:?}");
    // The supervisor's `Started` event of the new process; from then the tables named
    // "security" are the new process's.
    let mut restarted_at = None;
    watch.until("the supervisor starting Security again", |w| {
        while let Some(e) = events.receive().expect("events") {
            if e.module() == "security" && matches!(e.kind(), Some(EventKind::Started)) {
                restarted_at = Some(w.pose_t());
            }
        }
        restarted_at.is_some()
    });
    let restarted_at = restarted_at.expect("restart");
    watch.until("the restarted Security contracted by the Robot", |w| {
        w.contracts
            .get("security")
            .is_some_and(|t| t.header.stamp_ns as f64 * 1e-9 > restarted_at)
            && guarded(w)
    });

    // Full speed at the wall, 3.3 m ahead, until the robot has stood still for a simulated
    // second while the Interface still forwarded the pushes: held by Security, not idle
    // because a push came late (the test is no lockstep participant; the Interface's deadman
    // stops the robot when pushes lapse).
    let start_x = watch.xy().0;
    watch.drive = Some(hng_runtime::msg::Twist {
        linear_x: 1.0,
        ..Default::default()
    });
    watch.until("the robot driving at the wall", |w| {
        w.xy().0 > start_x + 1.0
    });
    let mut held_since = None;
    for _ in 0..30 {
        let since = watch.until_still("the robot held", 1.0);
        if watch.last_forwarded.is_some_and(|f| f > since + 0.5) {
            held_since = Some(since);
            break;
        }
    }
    let held_since = held_since.expect("held while the Interface forwarded the pushes");
    let x = watch.xy().0;
    let gap = WALL_FACE_X - x - RADIUS;
    let sim = watch.sim.expect("status");
    watch.drive = None;
    drop(events);
    drop(node);
    drop(watch);
    run.stop_ok();
    assert!(
        gap > 0.0,
        "stopped before contact: gap {gap:.3} m at x {x:.3}"
    );
    assert!(
        gap < 0.6,
        "held by Security near the wall, not elsewhere: gap {gap:.3} m (still since {held_since:.2} s)"
    );
    assert_eq!(sim.collisions, 0, "no collision: {sim:?}");
}
