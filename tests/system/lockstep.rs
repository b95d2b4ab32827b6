//! Lockstep simulation and the truth of mission results, end to end with `hng run` (every
//! module its own process): two runs of the default mission at `--speed max` with one seed
//! (each must succeed, and both give the same summary), a corrupted simulator checkpoint, and
//! goals added outside the map.

use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

use hng_runtime::clock::CLOCK_CHANNEL;
use hng_runtime::msg;
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};
use hng_simulator::module::SimStatus;

use crate::mission::{MissionRun as Run, hng};

fn goals(s: &serde_json::Value) -> &Vec<serde_json::Value> {
    s["goals"].as_array().expect("goals list")
}

/// Every goal reached by the true pose, with its true error within its tolerance.
fn assert_truly_successful(out: &Output, s: &serde_json::Value) {
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "hng run failed: {s}\n{text}");
    assert_eq!(s["success"], true, "{s}\n{text}");
    assert_eq!(s["goals_reached"], s["goals_total"], "{s}");
    assert_eq!(s["collisions"], 0, "{s}");
    for g in goals(s) {
        assert_eq!(g["state"], "reached", "{g}\n{s}");
        let err = g["true_error_m"].as_f64().expect("true error");
        let tol = g["tolerance_m"].as_f64().expect("tolerance");
        assert!(err <= tol, "{g}");
    }
}

#[test]
fn two_runs_with_one_seed_give_the_same_summary() {
    let _heavy = crate::common::heavy();
    let mut summaries = Vec::new();
    for i in 0..2 {
        let r = Run::new(&format!("lockstep_seed{i}"));
        let (out, s) = r.run(&["--speed", "max", "--seed", "7", "--no-rm"]);
        assert_truly_successful(&out, &s);
        assert_eq!(s["goals_total"], 3, "{s}");
        assert!(s["path_length_m"].as_f64().expect("path") > 10.0, "{s}");
        println!(
            "speed max: {} s simulated in {} s wall",
            s["sim_time_s"], s["wall_time_s"]
        );
        summaries.push(s);
    }
    let (a, b) = (&summaries[0], &summaries[1]);
    let states = |s: &serde_json::Value| -> Vec<(String, String)> {
        goals(s)
            .iter()
            .map(|g| (g["id"].to_string(), g["state"].to_string()))
            .collect()
    };
    assert_eq!(states(a), states(b), "same goals, same outcomes:\n{a}\n{b}");
    // The end is the stamp of the Manager's last document and the path is counted up to it,
    // whenever the monitor (no lockstep participant) read them.
    let (pa, pb) = (
        a["path_length_m"].as_f64().expect("path"),
        b["path_length_m"].as_f64().expect("path"),
    );
    assert!(
        (pa - pb).abs() <= 1e-9,
        "path lengths {pa} and {pb} differ:\n{a}\n{b}"
    );
    assert_eq!(a["sim_time_s"], b["sim_time_s"], "same end:\n{a}\n{b}");
    assert_eq!(
        a["stuck_time_s"], b["stuck_time_s"],
        "same time standing still:\n{a}\n{b}"
    );
    assert_eq!(
        a["contract_switches"], b["contract_switches"],
        "same contract switches:\n{a}\n{b}"
    );
    // Up to the last goal the two runs are the same to the last digit: a handler runs in a
    // round only for what it may handle in it (docs/simulator.md, "Determinism").
    let errors = |s: &serde_json::Value| -> Vec<String> {
        goals(s)
            .iter()
            .map(|g| g["true_error_m"].to_string())
            .collect()
    };
    assert_eq!(errors(a), errors(b), "same true errors:\n{a}\n{b}");
    assert_eq!(
        a["min_obstacle_distance_m"], b["min_obstacle_distance_m"],
        "same least obstacle distance:\n{a}\n{b}"
    );
}

/// The pid of a module of the running system (`hng ps --json`).
fn pid_of(prefix: &str, module: &str) -> Option<i32> {
    let out = hng()
        .args(["--prefix", prefix, "ps", "--json"])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let doc: serde_json::Value = serde_json::from_str(text.trim()).ok()?;
    let list = doc
        .as_array()
        .or_else(|| doc["modules"].as_array())?
        .clone();
    list.iter()
        .find(|m| m["name"] == module)
        .and_then(|m| m["pid"].as_i64())
        .and_then(|p| i32::try_from(p).ok())
        .filter(|p| *p > 0)
}

#[test]
fn a_corrupted_simulator_checkpoint_never_makes_simulated_time_go_back() {
    let _heavy = crate::common::heavy();
    let r = Run::new("lockstep_ckpt");
    let mut run = r.start(&["--speed", "5", "--no-rm"], Stdio::piped());
    let node = Node::new(NodeOptions::new("ckpt-watch").prefix(&r.prefix)).expect("node");
    let clock = node.subscriber::<msg::Clock>(CLOCK_CHANNEL).expect("clock");
    let status = node.subscriber::<SimStatus>("sim/status").expect("status");
    let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
    waiter.attach(&clock).expect("attach");
    let ckpt = r.dir.join("run/checkpoints/simulator.ckpt");
    let mut max_ns = 0u64;
    // Each channel is checked against itself (a status may be read after a newer clock).
    let mut status_max_ns = 0u64;
    let mut went_back: Option<(u64, u64)> = None;
    let mut killed_at: Option<u64> = None;
    let mut after_kill_max = 0u64;
    let start = Instant::now();
    while run.running() && start.elapsed() < Duration::from_secs(120) {
        waiter.wait(Some(Duration::from_millis(50))).expect("wait");
        while let Some(c) = clock.receive().expect("receive") {
            if c.sim_time_ns < max_ns && went_back.is_none() {
                went_back = Some((max_ns, c.sim_time_ns));
            }
            max_ns = max_ns.max(c.sim_time_ns);
            if killed_at.is_some() {
                after_kill_max = after_kill_max.max(c.sim_time_ns);
            }
        }
        while let Some(st) = status.receive().expect("receive") {
            if st.sim_time_ns < status_max_ns && went_back.is_none() {
                went_back = Some((status_max_ns, st.sim_time_ns));
            }
            status_max_ns = status_max_ns.max(st.sim_time_ns);
        }
        // After 8 s simulated (two checkpoints at least): freeze the simulator, corrupt its
        // latest checkpoint, and kill it: the supervisor restarts it.
        if killed_at.is_none() && max_ns > 8_000_000_000 {
            let Some(pid) = pid_of(&r.prefix, "simulator") else {
                continue;
            };
            let pid = nix::unistd::Pid::from_raw(pid);
            nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGSTOP).expect("SIGSTOP");
            // A save moves the latest checkpoint aside before writing the new one: caught in
            // between, let it finish and try again.
            let Ok(mut bytes) = std::fs::read(&ckpt) else {
                nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGCONT).expect("SIGCONT");
                continue;
            };
            let mid = bytes.len() / 2;
            for b in &mut bytes[mid..mid + 8] {
                *b ^= 0xA5;
            }
            std::fs::write(&ckpt, &bytes).expect("corrupt checkpoint");
            nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGKILL).expect("SIGKILL");
            killed_at = Some(max_ns);
        }
    }
    drop(status);
    drop(clock);
    drop(node);
    let (exit, out, err) = run.finish();
    let killed_at = killed_at.unwrap_or_else(|| panic!("the simulator was never killed\n{out}"));
    assert!(
        went_back.is_none(),
        "simulated time went back {went_back:?}\n{out}\n{err}"
    );
    assert!(
        after_kill_max > killed_at,
        "the clock never moved on after the restart\n{out}\n{err}"
    );
    assert!(
        err.contains("state restored from the one before it"),
        "the previous checkpoint was not used:\n{err}"
    );
    let s = r.summary(&out);
    assert!(exit.success(), "{s}\n{out}\n{err}");
    assert_eq!(s["success"], true, "{s}");
    assert!(s["restarts"].as_u64().expect("restarts") >= 1, "{s}");
}

#[test]
fn an_added_goal_outside_the_map_fails_the_run_and_is_listed() {
    let _heavy = crate::common::heavy();
    let r = Run::new("lockstep_added");
    let mut run = r.start(&["--speed", "5", "--no-rm"], Stdio::null());
    // Wait for the Manager, then add goals: one beyond any map (refused at once, with the
    // reason), one outside this map (accepted, then refused by Planning).
    let start = Instant::now();
    let added = loop {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the Manager never answered"
        );
        assert!(run.running(), "hng run ended early");
        let far = hng()
            .args(["--prefix", &r.prefix, "mission", "add", "1e300,1e300"])
            .output()
            .expect("hng mission");
        let far_err = String::from_utf8_lossy(&far.stderr).into_owned();
        assert!(!far.status.success(), "1e300,1e300 accepted");
        if !far_err.contains("within") {
            // No Manager yet ("start a system ..."): try again.
            std::thread::sleep(Duration::from_millis(200));
            continue;
        }
        let out = hng()
            .args(["--prefix", &r.prefix, "mission", "add", "25,25"])
            .output()
            .expect("hng mission");
        if out.status.success() {
            break String::from_utf8_lossy(&out.stdout).into_owned();
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(added.contains("25.00"), "{added}");
    let (exit, out, _) = run.finish();
    let s = r.summary(&out);
    assert!(
        !exit.success(),
        "the run succeeded with a goal outside the map:\n{out}"
    );
    assert_eq!(s["success"], false, "{s}");
    assert_eq!(s["goals_total"], 4, "{s}");
    let g = goals(&s)
        .iter()
        .find(|g| g["x"] == 25.0 && g["y"] == 25.0)
        .unwrap_or_else(|| panic!("the added goal is not listed: {s}"));
    assert_eq!(g["state"], "refused", "{g}");
    assert_eq!(g["reason"], "outside the map", "{g}");
    assert!(out.contains("REFUSED (25.00, 25.00)"), "{out}");
    assert!(out.contains("mission FAILED"), "{out}");
}
