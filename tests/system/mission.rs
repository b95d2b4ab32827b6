//! The built-in mission end to end (`hng run` without a launch file): every module of HNG v1.0
//! as its own process under the supervisor, in accelerated simulated time, checked through the
//! summary JSON that `hng run --summary` writes.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use hng_runtime::shm;
use hng_runtime::system::{EventKind, ModuleEvent, SUPERVISOR_EVENTS};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};
use hng_simulator::module::SimStatus;

use crate::common::Reaped;

/// Simulation speed of the tests: high enough to be quick, low enough that the closed loop
/// keeps up on two loaded cores.
const SPEED: &str = "10";

pub(crate) fn hng() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hng"));
    // No operator page: tests do not fight for its port (tests/system/gui.rs tests it).
    c.env("HNG_LOG", "warn")
        .env("HNG_NO_GUI", "true")
        .stdin(Stdio::null());
    c
}

/// A mission run under its own prefix and run directory; removes both on drop.
pub(crate) struct MissionRun {
    pub(crate) prefix: String,
    pub(crate) dir: PathBuf,
}

impl MissionRun {
    pub(crate) fn new(tag: &str) -> MissionRun {
        let prefix = shm::unique_prefix(tag);
        let dir = std::env::temp_dir().join(format!("hng-test-{}", prefix.trim_end_matches('_')));
        std::fs::create_dir_all(&dir).expect("test dir");
        MissionRun { prefix, dir }
    }

    fn summary_path(&self) -> PathBuf {
        self.dir.join("summary.json")
    }

    /// `hng run` for this prefix and run directory, writing its summary; `args` follow.
    pub(crate) fn command(&self, args: &[&str]) -> Command {
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

    /// Starts `hng run` ([`MissionRun::command`]) with its stdout piped, for
    /// [`Reaped::finish`], and its stderr to `stderr`.
    pub(crate) fn start(&self, args: &[&str], stderr: Stdio) -> Reaped {
        Reaped(
            self.command(args)
                .stdout(Stdio::piped())
                .stderr(stderr)
                .spawn()
                .expect("hng run"),
        )
    }

    /// The summary JSON the run wrote; `output` (the run's output) goes into the panic
    /// message when there is none.
    pub(crate) fn summary(&self, output: &str) -> serde_json::Value {
        let text = std::fs::read_to_string(self.summary_path())
            .unwrap_or_else(|e| panic!("no summary ({e}); output:\n{output}"));
        serde_json::from_str(&text).expect("summary JSON")
    }

    /// Runs `hng run` to its end: its output and summary.
    pub(crate) fn run(&self, args: &[&str]) -> (Output, serde_json::Value) {
        let out = self.command(args).output().expect("hng run");
        let s = self.summary(&format!(
            "stdout:\n{}\nstderr:\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ));
        (out, s)
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
            "failure",
            "goals",
            "goals_reached",
            "goals_total",
            "min_obstacle_distance_m",
            "path_length_m",
            "recoveries",
            "restarts",
            "sim_time_s",
            "stalls",
            "stuck_time_s",
            "success",
            "true_poses_lost",
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
    // The end of the mission stops the system in order: nothing of it is left in /dev/shm,
    // its iceoryx2 root folder included.
    let left = shm::prefix_files(&m.prefix);
    assert!(left.is_empty(), "left after the mission's end: {left:?}");
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
    // Without the fused localization (`--no-fusion`), which would serve throughout
    // (tests/system/localization.rs); the raw GPS (σ 0.3 m) needs the tolerance of 1 m the
    // mission had before the fusion.
    let (out, s) = m.run(&[
        "--no-rm",
        "--no-fusion",
        "--tolerance",
        "1.0",
        "--speed",
        "5",
    ]);
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
fn the_mission_succeeds_while_slam_planning_and_servo_are_killed() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("mission_faults");
    let mut run = m.start(&["--speed", "5"], Stdio::inherit());
    // SIGKILL SLAM, Planning and Servo in turn, each 6 s of simulated time (the simulator's
    // clock) after the previous victim was started again, as long as the mission runs. A
    // restart costs wall time (the supervisor's clean-up of the dead process's shared-memory
    // resources: up to 1.5 s on a loaded 2-core machine, 7.5 s simulated at 5x): a schedule in
    // simulated time alone would, on a slow machine, kill the next module while the previous
    // one is still down. A kill refused because the victim is not running is retried 6 s later.
    let node =
        Node::new(NodeOptions::new("mission-fault-injector").prefix(&m.prefix)).expect("node");
    let status = node.subscriber::<SimStatus>("sim/status").expect("sub");
    let events = node
        .subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)
        .expect("events");
    let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
    waiter.attach(&status).expect("attach");
    waiter.attach(&events).expect("attach");
    let victims = ["slam", "planning", "servo"];
    let mut kills = [0usize; 3];
    let mut attempts = 0usize;
    let mut sim_s = 0.0;
    let mut next_kill_s = Some(6.0);
    // The victim killed last, until the supervisor starts it again.
    let mut down: Option<&str> = None;
    while run.running() {
        waiter.wait(Some(Duration::from_millis(200))).expect("wait");
        while let Some(st) = status.receive().expect("receive") {
            sim_s = st.sim_time_ns as f64 * 1e-9;
        }
        while let Some(e) = events.receive().expect("receive") {
            if matches!(e.kind(), Some(EventKind::Started)) && down.is_some_and(|v| v == e.module())
            {
                down = None;
                next_kill_s = Some(sim_s + 6.0);
            }
        }
        if let Some(at) = next_kill_s
            && sim_s >= at
        {
            let v = attempts % victims.len();
            let ok = hng()
                .args(["--prefix", &m.prefix, "kill", victims[v]])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .expect("hng kill");
            if ok.success() {
                kills[v] += 1;
                attempts += 1;
                down = Some(victims[v]);
                next_kill_s = None;
            } else {
                next_kill_s = Some(sim_s + 6.0);
            }
        }
    }
    drop(events);
    drop(status);
    drop(node);
    let (exit, text, _) = run.finish();
    let s = m.summary(&text);
    for (v, n) in victims.iter().zip(kills) {
        assert!(n >= 1, "{v} was never killed ({kills:?}): {s}\n{text}");
    }
    assert_success(
        &Output {
            status: exit,
            stdout: text.clone().into_bytes(),
            stderr: Vec::new(),
        },
        &s,
    );
    // Every kill but possibly the last (the mission may end before its restart) is followed
    // by a restart, and the mission still succeeded without a collision.
    let restarts = s["restarts"].as_u64().expect("restarts");
    let total: usize = kills.iter().sum();
    assert!(
        restarts > 0 && restarts + 1 >= total as u64,
        "{restarts} restarts for {total} kills: {s}\n{text}"
    );
    assert!(text.contains("module slam restarted"), "{text}");
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
