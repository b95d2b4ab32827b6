//! The built-in mission end to end (`hng run` without a launch file): every module of HNG v1.0
//! as its own process under the supervisor, in accelerated simulated time, checked through the
//! summary JSON that `hng run --summary` writes.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use hng_runtime::shm;
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};
use hng_simulator::module::SimStatus;

/// Simulation speed of the tests: high enough to be quick, low enough that the closed loop
/// keeps up on two loaded cores.
const SPEED: &str = "10";

fn hng() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hng"));
    c.env("HNG_LOG", "warn").stdin(Stdio::null());
    c
}

/// A mission run under its own prefix and run directory; removes both on drop.
struct MissionRun {
    prefix: String,
    dir: PathBuf,
}

impl MissionRun {
    fn new(tag: &str) -> MissionRun {
        let prefix = shm::unique_prefix(tag);
        let dir = std::env::temp_dir().join(format!("hng-test-{}", prefix.trim_end_matches('_')));
        std::fs::create_dir_all(&dir).expect("test dir");
        MissionRun { prefix, dir }
    }

    fn summary_path(&self) -> PathBuf {
        self.dir.join("summary.json")
    }

    fn command(&self, args: &[&str]) -> Command {
        let mut c = hng();
        c.arg("--prefix")
            .arg(&self.prefix)
            .arg("run")
            .arg("--run-dir")
            .arg(self.dir.join("run"))
            .arg("--summary")
            .arg(self.summary_path())
            .args(args);
        c
    }

    fn run(&self, args: &[&str]) -> (Output, serde_json::Value) {
        let out = self.command(args).output().expect("hng run");
        let summary = std::fs::read_to_string(self.summary_path()).unwrap_or_else(|e| {
            panic!(
                "no summary ({e}); stdout:\n{}\nstderr:\n{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            )
        });
        let json: serde_json::Value = serde_json::from_str(&summary).expect("summary JSON");
        (out, json)
    }
}

impl Drop for MissionRun {
    fn drop(&mut self) {
        shm::remove_prefix_files(&self.prefix);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn assert_success(out: &Output, s: &serde_json::Value) {
    let text = stdout(out);
    assert!(out.status.success(), "hng run failed: {s}\n{text}");
    assert_eq!(s["success"], true, "{s}\n{text}");
    assert_eq!(s["goals_reached"], s["goals_total"], "{s}");
    assert_eq!(s["collisions"], 0, "{s}");
    let min = s["min_obstacle_distance_m"].as_f64().expect("min distance");
    assert!(min > 0.0, "{s}");
    assert!(s["path_length_m"].as_f64().expect("path") > 1.0, "{s}");
}

fn summary_fields_are_exactly_the_documented_ones(s: &serde_json::Value) {
    let mut keys: Vec<&str> = s
        .as_object()
        .expect("object")
        .keys()
        .map(String::as_str)
        .collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "collisions",
            "contract_switches",
            "goals_reached",
            "goals_total",
            "min_obstacle_distance_m",
            "path_length_m",
            "restarts",
            "sim_time_s",
            "success",
            "wall_time_s"
        ]
    );
}

fn worlds() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("simulator/worlds")
}

#[test]
fn the_default_mission_reaches_every_goal_without_collision() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("mission_default");
    let (out, s) = m.run(&["--speed", SPEED]);
    assert_success(&out, &s);
    summary_fields_are_exactly_the_documented_ones(&s);
    assert_eq!(s["goals_total"], 3, "{s}");
    assert_eq!(s["restarts"], 0, "{s}");
    let text = stdout(&out);
    assert_eq!(text.matches("goal reached").count(), 3, "{text}");
    assert!(text.contains("mission SUCCEEDED"), "{text}");
}

#[test]
fn localization_moves_to_slam_in_a_gps_degraded_zone_and_back_after() {
    let _heavy = crate::common::heavy();
    // Without the RM, V = Q: a nominal GPS fix (Q about 0.56) beats SLAM (at most 0.4), the
    // degraded zone around the tree at (3, 9), which the way to the second goal crosses, drops
    // the GPS to about -0.8, so SLAM takes over, and the GPS wins back by better offer after.
    let m = MissionRun::new("mission_localization");
    // At 5x the modules keep up with the simulation even with another test running beside:
    // a module that lags sees stale poses, and localization then flaps between providers.
    let (out, s) = m.run(&["--no-rm", "--speed", "5"]);
    assert_success(&out, &s);
    let text = stdout(&out);
    assert!(
        s["contract_switches"].as_u64().expect("switches") >= 2,
        "{s}\n{text}"
    );
    for client in ["servo", "planning"] {
        let to_slam = format!("contract switch: {client} Localization: gps -> slam");
        let to_gps = format!("contract switch: {client} Localization: slam -> gps");
        let at_slam = text
            .find(&to_slam)
            .unwrap_or_else(|| panic!("{to_slam}\n{text}"));
        assert!(
            text[at_slam..].contains(&to_gps),
            "{client}: no switch back to the GPS\n{text}"
        );
    }
}

#[test]
fn a_goal_in_a_second_toml_world_is_reached() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("mission_rooms");
    let world = worlds().join("two_rooms.toml");
    let (out, s) = m.run(&[
        "--world",
        world.to_str().expect("path"),
        "--goal",
        "7.5,3.5",
        "--speed",
        SPEED,
    ]);
    assert_success(&out, &s);
    assert_eq!(s["goals_total"], 1, "{s}");
}

#[test]
fn a_goal_in_a_map_server_world_is_reached() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("mission_pgm");
    let yaml = m.dir.join("rooms_map.yaml");
    let st = hng()
        .args(["sim", "map", "--world"])
        .arg(worlds().join("two_rooms.toml"))
        .arg(&yaml)
        .status()
        .expect("hng sim map");
    assert!(st.success());
    let (out, s) = m.run(&[
        "--world",
        yaml.to_str().expect("path"),
        "--start",
        "1,1,0",
        "--goal",
        "7.5,3.5",
        "--speed",
        SPEED,
    ]);
    assert_success(&out, &s);
}

#[test]
#[ignore = "passes alone (about 9 s) but under the whole suite's load the robot can stall \
            short of the last goal after SLAM restarts; run with --ignored (see docs/modules.md)"]
fn the_mission_succeeds_while_slam_planning_and_servo_are_killed() {
    let m = MissionRun::new("mission_faults");
    let mut child = m
        .command(&["--speed", "5"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("hng run");
    // Kill SLAM, Planning and Servo in turn every 6 s of simulated time, as long as the
    // mission runs.
    let node =
        Node::new(NodeOptions::new("mission-fault-injector").prefix(&m.prefix)).expect("node");
    let status = node.subscriber::<SimStatus>("sim/status").expect("sub");
    let mut waiter = Waiter::new(WaitMode::Blocking {
        max_spin: Duration::ZERO,
    })
    .expect("waiter");
    waiter.attach(&status).expect("attach");
    let victims = ["slam", "planning", "servo"];
    let mut kills = 0usize;
    let mut next_kill_s = 6.0;
    while child.try_wait().expect("try_wait").is_none() {
        waiter.wait(Some(Duration::from_millis(200))).expect("wait");
        let mut sim_s = None;
        while let Some(st) = status.receive().expect("receive") {
            sim_s = Some(st.sim_time_ns as f64 * 1e-9);
        }
        if let Some(t) = sim_s
            && t >= next_kill_s
        {
            let victim = victims[kills % victims.len()];
            let ok = hng()
                .args(["--prefix", &m.prefix, "kill", victim])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .expect("hng kill");
            if ok.success() {
                kills += 1;
            }
            next_kill_s = t + 6.0;
        }
    }
    drop(status);
    drop(node);
    let out = child.wait_with_output().expect("wait");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(m.summary_path()).expect("summary"))
            .expect("json");
    assert!(kills >= 3, "only {kills} kills: {s}");
    assert_success(&out, &s);
    assert!(s["restarts"].as_u64().expect("restarts") >= 3, "{s}");
}

#[test]
fn an_unreachable_or_out_of_map_goal_is_refused_and_the_robot_stays() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("mission_refused");
    let (out, s) = m.run(&["--start", "2,2", "--goal", "30,40", "--speed", SPEED]);
    let text = stdout(&out);
    assert!(!out.status.success(), "{text}");
    assert_eq!(s["success"], false, "{s}");
    assert_eq!(s["goals_reached"], 0, "{s}");
    assert_eq!(s["collisions"], 0, "{s}");
    assert!(s["path_length_m"].as_f64().expect("path") < 0.2, "{s}");
    assert!(text.contains("REFUSED"), "{text}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("outside the map"), "{stderr}");
}

#[test]
fn a_world_file_error_names_the_line() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("mission_badworld");
    let bad = m.dir.join("bad.toml");
    std::fs::write(
        &bad,
        "name = \"bad\"\n[robot]\nstart = { x = 1.0, y = \"a\" }\n",
    )
    .expect("write");
    let out = m
        .command(&["--world", bad.to_str().expect("path"), "--goal", "2,2"])
        .output()
        .expect("hng run");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.toml:3:"), "{err}");
    assert!(err.contains("robot.start.y"), "{err}");
}
