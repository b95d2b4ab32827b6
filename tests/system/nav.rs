//! Navigation end to end (`hng run` and `hng eval nav`, every module its own process, in
//! lockstep): a robot boxed in by a world script goes through every recovery behaviour and
//! fails with its reason; a robot starting inside the footprint margin of a wall, facing it,
//! first leaves it; a small sample of generated worlds is navigated; `hng eval nav` runs the
//! problems of one world on one system, each problem with figures of its own.

use std::path::Path;

use crate::common::poll_until;
use crate::mission::{MissionRun as Run, hng};
use crate::signals::is_alive;

/// A corridor 12 m long and 2 m wide (y 0..2) along x, closed at both ends; `extra` is
/// appended (events, ...). Start at `start`.
fn corridor(dir: &Path, start: (f64, f64, f64), extra: &str) -> std::path::PathBuf {
    let world = format!(
        r#"name = "nav-corridor"
seed = 5

[robot]
start = {{ x = {}, y = {}, theta = {} }}

{walls}{extra}"#,
        start.0,
        start.1,
        start.2,
        walls = crate::common::room_walls(12.0, 2.0)
    );
    let path = dir.join("corridor.toml");
    std::fs::write(&path, world).expect("world file");
    path
}

#[test]
fn a_robot_boxed_in_by_a_world_script_tries_every_recovery_and_fails_with_its_reason() {
    let _heavy = crate::common::heavy();
    let r = Run::new("nav_boxed_in");
    // At 1 s a box closes the corridor 2.5 m ahead of the robot: it is not on the known map
    // (Maps' grid is the drawn world), so Planning's path runs through it and Security
    // holds the robot in front of it.
    let world = corridor(
        &r.dir,
        (1.0, 1.0, 0.0),
        r#"
[[events]]
at_s = 1.0
add_box = { name = "closed", center = [3.5, 1.0], size = [0.3, 2.1] }
"#,
    );
    let w = world.to_string_lossy();
    let (out, s) = r.run(&[
        "--world",
        &w,
        "--goal",
        "10,1",
        "--speed",
        "max",
        "--duration",
        "150",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        !out.status.success(),
        "boxed in, yet succeeded: {s}\n{text}"
    );
    assert_eq!(s["success"], false, "{s}");
    assert_eq!(s["collisions"], 0, "{s}\n{text}");
    assert!(s["stalls"].as_u64().expect("stalls") >= 1, "{s}\n{text}");
    assert_eq!(s["recoveries"], 4, "{s}\n{text}");
    let goal = &s["goals"][0];
    assert_eq!(goal["state"], "refused", "{s}");
    let why = goal["reason"].as_str().expect("a reason");
    assert!(why.contains("stuck"), "{why}");
    let failure = s["failure"].as_str().expect("a failure");
    assert!(failure.contains("stuck"), "{failure}");
    // The progress lines name the stall, each behaviour and the failure, in order.
    let mut at = 0;
    for line in [
        "STALLED",
        "recovery 1: clear the costmap",
        "recovery 2: rotate in place",
        "recovery 3: back up",
        "recovery 4: re-plan",
        "FAILED: no progress",
        "goal REFUSED",
    ] {
        let i = text[at..]
            .find(line)
            .unwrap_or_else(|| panic!("no {line:?} after byte {at}:\n{text}"));
        at += i + line.len();
    }
    // The robot stood still most of the time after the box appeared.
    assert!(
        s["stuck_time_s"].as_f64().expect("stuck time") > 10.0,
        "{s}"
    );
}

#[test]
fn a_robot_starting_inside_the_margin_of_a_wall_facing_it_first_moves_away() {
    let _heavy = crate::common::heavy();
    let r = Run::new("nav_wall_start");
    // 0.25 m from the west wall's centre line (its surface at 0.025 m): a gap of 25 mm
    // (above the simulator's 5 mm contact margin), facing the wall; Security's 0.25 m disc
    // already overlaps it.
    let world = corridor(&r.dir, (0.25, 1.0, std::f64::consts::PI), "");
    let w = world.to_string_lossy();
    let (out, s) = r.run(&[
        "--world",
        &w,
        "--goal",
        "6,1",
        "--speed",
        "max",
        "--duration",
        "90",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{s}\n{text}");
    assert_eq!(s["success"], true, "{s}");
    assert_eq!(s["collisions"], 0, "{s}");
    assert_eq!(s["goals"][0]["state"], "reached", "{s}");
}

#[test]
fn a_sample_of_generated_worlds_is_navigated_and_every_failure_has_a_reason() {
    let _heavy = crate::common::heavy();
    let r = Run::new("nav_generated");
    let out = hng()
        .args(["eval", "nav", "--generate", "5", "--seed", "3", "--json"])
        .args(["--tolerance", "1.0", "--dir"])
        .arg(r.dir.join("eval"))
        .output()
        .expect("hng eval nav");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (problems, summary) = eval_lines(&text);
    assert_eq!(problems.len(), 5, "{text}");
    for p in problems {
        for k in [
            "success",
            "time_s",
            "path_length_m",
            "optimum_m",
            "min_clearance_m",
            "collisions",
            "stuck_time_s",
            "recoveries",
            "reason",
        ] {
            assert!(p.get(k).is_some(), "no {k} in {p}");
        }
        assert_eq!(p["collisions"], 0, "{p}");
        if p["success"] == true {
            let ratio = p["path_ratio"].as_f64().expect("ratio");
            assert!(ratio > 0.5 && ratio < 2.0, "{p}");
        } else {
            assert!(p["reason"].as_str().is_some_and(|r| !r.is_empty()), "{p}");
        }
    }
    let ok = summary["successes"].as_u64().expect("successes");
    assert!(ok >= 4, "{ok} of 5 generated problems: {text}");
}

/// `hng eval nav` on a map_server world runs its four problems on one system (one run
/// directory), and each problem's figures are its own: a success, a start inside a wall (the
/// teleport refused), a goal inside a crate (refused by Planning), then a success whose path
/// and time do not include the earlier problems'.
#[test]
fn an_eval_reuses_one_system_and_each_problem_has_figures_of_its_own() {
    let _heavy = crate::common::heavy();
    let r = Run::new("nav_eval_reuse");
    let yaml = r.dir.join("rooms.yaml");
    let st = hng()
        .args(["sim", "map", "--world"])
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("simulator/worlds/two_rooms.toml"))
        .arg(&yaml)
        .status()
        .expect("hng sim map");
    assert!(st.success());
    // The left room (x 0..4.5, y 0..5), its crate 2.2..2.8 x 3.2..3.8; the dividing wall at
    // x 4.5 above the doorway (y 3.3..5).
    let problems = r.dir.join("problems.txt");
    std::fs::write(
        &problems,
        "1.0 1.0 3.5 1.0\n4.5 4.2 3.5 4.2\n1.0 2.5 2.5 3.5\n1.0 4.3 3.8 4.3\n",
    )
    .expect("problems");
    let out = hng()
        .args(["eval", "nav", "--world"])
        .arg(&yaml)
        .arg("--problems")
        .arg(&problems)
        .args(["--tolerance", "0.5", "--json", "--keep", "--dir"])
        .arg(r.dir.join("eval"))
        .output()
        .expect("hng eval nav");
    let text = String::from_utf8_lossy(&out.stdout);
    let all = format!("{text}\n{}", String::from_utf8_lossy(&out.stderr));
    let (p, summary) = eval_lines(&text);
    assert_eq!(p.len(), 4, "{all}");
    // One system: one run directory.
    let runs: Vec<_> = std::fs::read_dir(r.dir.join("eval/runs"))
        .expect("runs")
        .flatten()
        .collect();
    assert_eq!(runs.len(), 1, "{all}");
    // Localization jumps to each start's estimate: the Servo, told of the estimate, does not
    // take it for a faulty provider (which switched both its clients to the GPS for 4-9 s
    // after every teleport).
    let run_out = std::fs::read_to_string(runs[0].path().join("stdout.txt")).expect("stdout");
    assert!(
        !run_out.contains("Localization: localization -> "),
        "{run_out}\n{all}"
    );
    let f = |i: usize, k: &str| p[i][k].as_f64().unwrap_or(f64::NAN);
    let reason = |i: usize| p[i]["reason"].as_str().unwrap_or("").to_owned();
    for q in &p {
        assert_eq!(q["collisions"], 0, "{all}");
    }
    assert_eq!(p[0]["success"], true, "{all}");
    let ratio = f(0, "path_ratio");
    assert!(ratio > 0.8 && ratio < 1.5, "{all}");
    assert_eq!(p[1]["success"], false, "{all}");
    // Seen from the simulator's count of refused teleports, not from a timeout.
    assert!(reason(1).contains("refused the teleport"), "{all}");
    assert_eq!(f(1, "path_length_m"), 0.0, "{all}");
    assert_eq!(p[2]["success"], false, "{all}");
    assert!(reason(2).contains("refused"), "{all}");
    // Refused (at once on the drawn map; after a short drive when Planning's map was SLAM's
    // for a while, see docs/navigation.md): less path and time than the first problem's
    // drive, which the counters of the run as a whole would include.
    assert!(f(2, "path_length_m") < f(0, "path_length_m"), "{all}");
    assert!(f(2, "time_s") < f(0, "time_s"), "{all}");
    assert_eq!(p[3]["success"], true, "{all}");
    let ratio = f(3, "path_ratio");
    assert!(ratio > 0.8 && ratio < 1.5, "{all}");
    assert!(f(3, "min_clearance_m") > 0.0, "{all}");
    assert_eq!(summary["successes"], 2, "{all}");
}

/// The JSON lines of `hng eval nav --json`: one per problem, then the summary (checked to be
/// one).
fn eval_lines(text: &str) -> (Vec<serde_json::Value>, serde_json::Value) {
    let mut lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    let summary = lines.pop().expect("lines");
    assert_eq!(summary["summary"], true, "{text}");
    (lines, summary)
}

/// The `hng run` child of process `parent` and its `--prefix`, from /proc.
fn eval_run_child(parent: u32) -> Option<(u32, String)> {
    for e in std::fs::read_dir("/proc").ok()?.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let stat = std::fs::read(format!("/proc/{pid}/stat")).unwrap_or_default();
        if hng_rm::sampler::parse_stat(&stat).map(|s| s.ppid) != Some(parent) {
            continue;
        }
        let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
        let args: Vec<String> = cmdline
            .split(|b| *b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        if !args.iter().any(|a| a == "run") {
            continue;
        }
        let prefix = args
            .iter()
            .position(|a| a == "--prefix")
            .and_then(|i| args.get(i + 1))
            .cloned()?;
        return Some((pid, prefix));
    }
    None
}

/// True when a problem's `hng run` under `runs` has printed its start lines.
fn run_has_started(runs: &Path) -> bool {
    std::fs::read_dir(runs)
        .into_iter()
        .flatten()
        .flatten()
        .any(|d| {
            std::fs::read_to_string(d.path().join("stdout.txt")).is_ok_and(|t| t.contains("logs:"))
        })
}

/// `hng eval nav` stopped by SIGTERM stops its current problem's `hng run` in order and exits
/// 128 + 15; killed by SIGKILL, the run gets its parent-death signal (SIGTERM) and stops in
/// order all the same. Either way no process and no file of the run's prefix is left.
#[test]
fn an_eval_stopped_by_sigterm_or_killed_leaves_no_run_and_no_files() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    use std::time::{Duration, Instant};
    let _heavy = crate::common::heavy();
    for sig in [Signal::SIGTERM, Signal::SIGKILL] {
        let r = Run::new("nav_eval_stop");
        let mut eval = hng()
            .args(["eval", "nav", "--generate", "3", "--seed", "3", "--json"])
            .args(["--speed", "1", "--dir"])
            .arg(r.dir.join("eval"))
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("hng eval nav");
        // Wait until the first problem's system is up.
        let deadline = Instant::now() + Duration::from_secs(180);
        let (run_pid, prefix) = loop {
            // Up: its shared-memory files exist and it has printed where its logs go.
            if let Some((pid, prefix)) = eval_run_child(eval.id())
                && !hng_runtime::shm::prefix_files(&prefix).is_empty()
                && run_has_started(&r.dir.join("eval/runs"))
            {
                break (pid, prefix);
            }
            assert!(
                eval.try_wait().expect("try_wait").is_none(),
                "eval ended early"
            );
            assert!(Instant::now() < deadline, "no run started");
            std::thread::sleep(Duration::from_millis(200));
        };
        kill(Pid::from_raw(eval.id() as i32), sig).expect("signal");
        let status = eval.wait().expect("wait");
        if sig == Signal::SIGTERM {
            assert_eq!(
                std::os::unix::process::ExitStatusExt::signal(&status),
                None,
                "{status}"
            );
            assert_eq!(status.code(), Some(128 + 15), "{status}");
        }
        // The run stops in order (a clean stop takes seconds on a loaded machine); after a
        // SIGKILL of the eval nobody but the run itself removes its files.
        poll_until(
            Duration::from_secs(60),
            Duration::from_millis(200),
            || !is_alive(run_pid as i32) && hng_runtime::shm::prefix_files(&prefix).is_empty(),
            || {
                format!(
                    "after {sig}: run {run_pid} alive {}, files left {:?}",
                    is_alive(run_pid as i32),
                    hng_runtime::shm::prefix_files(&prefix)
                )
            },
        );
    }
}
