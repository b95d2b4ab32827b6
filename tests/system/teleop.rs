//! Teleoperation by hand with `hng topic pub`: finite commands on `hng/teleop` drive the
//! simulated robot through the Interface and the Robot (under their contract); NaN and
//! infinite ones never move it and are counted (the Interface's report, `msgs_dropped`).

use std::process::{Child, Command, Stdio};

use nix::sys::signal::Signal;

use crate::common::{Watch, dist};
use crate::signals::Run;

const HNG: &str = env!("CARGO_BIN_EXE_hng");

/// The Table 1 modules a teleoperated robot needs, the Manager with no goals.
fn launch() -> String {
    let sim =
        "speed = 2\nwait_for = [\"laser\", \"robot\", \"security\", \"interface\", \"manager\"]";
    crate::common::launch_file(
        "teleop",
        3.0,
        10.0,
        &[
            ("simulator", "", sim),
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
    std::fs::write(&file, launch()).expect("launch file");
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
