//! Fault injection with real processes: `hng run FILE` supervises fixture modules that are
//! killed, crash, hang or crash-loop. Each test checks the recovery (or the deactivation)
//! through the supervisor's event and status channels, and that the restarted module resumed
//! from its checkpoint (the `faulty` fixture publishes the last count it saved, so the test
//! knows exactly which state must come back).

use std::path::PathBuf;
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

use hng_runtime::msg::Goal;
use hng_runtime::system::{EventKind, JsonInfo, ModuleEvent, SUPERVISOR_EVENTS, SUPERVISOR_STATUS};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, SliceSubscriber, Subscriber, shm};
use serde_json::Value;

use crate::signals::{is_alive, processes_of};

const HNG: &str = env!("CARGO_BIN_EXE_hng");
const TESTMOD: &str = env!("CARGO_BIN_EXE_hng-testmod");
const TIMEOUT: Duration = Duration::from_secs(20);

/// The test's view of the system: ports on its channels.
struct Observer {
    events: Subscriber<ModuleEvent>,
    status: SliceSubscriber<JsonInfo>,
    count: Subscriber<Goal>,
    waiter: Waiter,
    _node: Node,
}

/// One `hng run` under a unique prefix, with its launch file in a temporary folder.
struct RunningSystem {
    prefix: String,
    dir: PathBuf,
    child: Option<Child>,
    obs: Option<Observer>,
    /// Every module pid seen in a Started event.
    pids: Vec<u32>,
    /// Highest count and highest announced checkpoint read so far. Counts are read while
    /// waiting: a dead publisher's unread samples go with its shared memory when the
    /// supervisor cleans up before the restart.
    seen: (u32, u32),
}

/// A launch file around `modules` (TOML of `[[module]]` tables; `TESTMOD` is replaced by the
/// fixture's path).
fn launch_file(modules: &str) -> String {
    format!(
        "system = \"faults\"\n\n[defaults]\nstop_timeout_s = 5.0\nbackoff_initial_s = 0.01\n\n{}",
        modules.replace("TESTMOD", TESTMOD)
    )
}

fn temp_dir(prefix: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("{prefix}run"));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

impl RunningSystem {
    fn start(tag: &str, modules: &str) -> RunningSystem {
        RunningSystem::start_with(tag, |_| modules.to_owned())
    }

    /// Starts a system whose `[[module]]` tables `modules` writes, given the test's folder.
    fn start_with(tag: &str, modules: impl FnOnce(&std::path::Path) -> String) -> RunningSystem {
        let prefix = shm::unique_prefix(tag);
        let dir = temp_dir(&prefix);
        let file = dir.join("launch.toml");
        std::fs::write(&file, launch_file(&modules(&dir))).expect("write launch file");
        // Subscribe before anything starts, so no event is missed.
        let node = Node::new(NodeOptions::new("fault-test").prefix(&prefix)).expect("node");
        let events = node
            .subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)
            .expect("events");
        let status = node
            .slice_subscriber::<JsonInfo>(SUPERVISOR_STATUS)
            .expect("status");
        let count = node.subscriber::<Goal>("test/count").expect("count");
        let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
        waiter.attach(&events).expect("attach");
        waiter.attach(&status).expect("attach");
        waiter.attach(&count).expect("attach");
        let child = crate::common::spawn_hng_run(&prefix, &dir, &file, &["--no-rm"]);
        RunningSystem {
            prefix,
            dir,
            child: Some(child),
            obs: Some(Observer {
                events,
                status,
                count,
                waiter,
                _node: node,
            }),
            pids: Vec::new(),
            seen: (0, 0),
        }
    }

    fn obs(&mut self) -> &mut Observer {
        self.obs.as_mut().expect("observer")
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("run.log")).unwrap_or_default()
    }

    /// Polls `poll` until it gives a value, waiting for input in between; fails after
    /// [`TIMEOUT`] with what `poll` last said was missing, and the run's log.
    fn until<T>(&mut self, mut poll: impl FnMut(&mut Self) -> Result<T, String>) -> T {
        let deadline = Instant::now() + TIMEOUT;
        loop {
            let missing = match poll(self) {
                Ok(v) => return v,
                Err(missing) => missing,
            };
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "{missing} within {TIMEOUT:?}; log:\n{}",
                self.log()
            );
            self.obs().waiter.wait(Some(left)).expect("wait");
        }
    }

    /// Waits for an event of `kind` about `module`; other events are skipped (their
    /// Started pids recorded).
    fn wait_event(&mut self, module: &str, kind: EventKind) -> ModuleEvent {
        self.until(|f| {
            while let Some(e) = f.obs().events.receive().expect("receive event") {
                let e = *e;
                if e.kind() == Some(EventKind::Started) {
                    f.pids.push(e.pid);
                }
                if e.module() == module && e.kind() == Some(kind) {
                    return Ok(e);
                }
            }
            f.drain_counts();
            Err(format!("no {kind:?} event for {module}"))
        })
    }

    /// Waits for a status document that satisfies `pred`.
    fn status_where(&mut self, what: &str, mut pred: impl FnMut(&Value) -> bool) -> Value {
        let mut last = Value::Null;
        self.until(|f| {
            while let Some(s) = f.obs().status.receive().expect("receive status") {
                let doc: Value = serde_json::from_slice(s.data()).expect("status is JSON");
                if pred(&doc) {
                    return Ok(doc);
                }
                last = doc;
            }
            Err(format!("no status with {what} (last: {last:#})"))
        })
    }

    /// The next count message.
    fn next_count(&mut self) -> Goal {
        self.until(|f| {
            f.obs()
                .count
                .receive()
                .expect("receive count")
                .map(|g| *g)
                .ok_or_else(|| "the counter published nothing".to_owned())
        })
    }

    /// Reads counts until one reaches `n`; returns the last message and the largest
    /// checkpointed count it announced.
    fn count_until(&mut self, n: u32) -> (Goal, u32) {
        let mut saved = 0;
        let deadline = Instant::now() + TIMEOUT;
        loop {
            assert!(
                Instant::now() < deadline,
                "the counter did not reach {n} with a checkpoint within {TIMEOUT:?} (saved: {saved})"
            );
            let g = self.next_count();
            saved = saved.max(g.tolerance_m as u32);
            if g.id >= n && saved > 0 {
                return (g, saved);
            }
        }
    }

    /// The counts process `pid` wrote to the fixture's count log, in order.
    fn logged_counts(&self, pid: u32) -> Vec<u32> {
        std::fs::read_to_string(self.dir.join("counts"))
            .unwrap_or_default()
            .lines()
            .filter_map(|line| line.split_once(' '))
            .filter(|(p, _)| p.parse() == Ok(pid))
            .filter_map(|(_, count)| count.parse().ok())
            .collect()
    }

    /// The highest count process `pid` logged (0 if none).
    fn last_logged_count(&self, pid: u32) -> u32 {
        self.logged_counts(pid).into_iter().max().unwrap_or(0)
    }

    /// The first count process `pid` logged; it has published one, so it logged one.
    fn first_logged_count(&self, pid: u32) -> u32 {
        let counts = self.logged_counts(pid);
        *counts
            .first()
            .unwrap_or_else(|| panic!("process {pid} published a count but logged none"))
    }

    /// Drops every message already received (from a process that is dead now).
    fn drain_counts(&mut self) -> (u32, u32) {
        let (mut last, mut saved) = self.seen;
        while let Some(g) = self.obs().count.receive().expect("drain") {
            last = last.max(g.id);
            saved = saved.max(g.tolerance_m as u32);
        }
        self.seen = (last, saved);
        (last, saved)
    }

    fn hng(&self, args: &[&str]) -> Output {
        Command::new(HNG)
            .args(args)
            .env("HNG_PREFIX", &self.prefix)
            .env("HNG_LOG", "warn")
            .output()
            .expect("run hng")
    }

    /// `hng ps --json`, parsed.
    fn ps(&self) -> Value {
        let out = self.hng(&["ps", "--json"]);
        assert!(
            out.status.success(),
            "hng ps failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).expect("ps --json is JSON")
    }

    /// SIGTERM to `hng run`; checks a clean exit, that no process of the system is left and
    /// that the prefix left no file. Returns the supervisor's log.
    fn stop(mut self) -> String {
        // The test's own ports and node go first, so that every file left is the system's.
        self.obs = None;
        let mut child = self.child.take().expect("child");
        let pid = nix::unistd::Pid::from_raw(child.id() as i32);
        nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).expect("SIGTERM");
        let status = crate::common::wait_exit(&mut child, TIMEOUT)
            .unwrap_or_else(|| panic!("hng run did not stop within {TIMEOUT:?}"));
        assert!(
            status.success(),
            "hng run exit: {status:?}; log:\n{}",
            self.log()
        );
        let left = processes_of(&self.prefix);
        assert!(left.is_empty(), "processes left behind: {left:?}");
        for p in &self.pids {
            assert!(
                !is_alive(*p as i32),
                "module pid {p} still alive after hng run stopped"
            );
        }
        let files = shm::prefix_files(&self.prefix);
        assert!(files.is_empty(), "files left behind: {files:?}");
        self.log()
    }
}

impl Drop for RunningSystem {
    fn drop(&mut self) {
        self.obs = None;
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
            for p in processes_of(&self.prefix) {
                let _ = nix::sys::signal::kill(
                    nix::unistd::Pid::from_raw(p),
                    nix::sys::signal::Signal::SIGKILL,
                );
            }
        }
        shm::remove_prefix_files(&self.prefix);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn module(checkpoint_s: f64, extra: &str, config: &str) -> String {
    format!(
        "[[module]]\nname = \"counter\"\ncommand = [\"TESTMOD\", \"faulty\"]\ncheckpoint_period_s = {checkpoint_s}\n{extra}\n[module.config]\nperiod_s = 0.005\n{config}\n"
    )
}

fn module_row<'a>(doc: &'a Value, name: &str) -> &'a Value {
    doc["modules"]
        .as_array()
        .and_then(|ms| ms.iter().find(|m| m["name"] == name))
        .unwrap_or(&Value::Null)
}

/// Runs a counter, lets it checkpoint, injects a fault (`inject`, or the module's own
/// configured fault), and checks the restart, the exit cause and the restored count.
fn crash_and_recover(
    tag: &str,
    extra: &str,
    config: &str,
    inject: Option<&str>,
    expect_exit: impl Fn(&Value) -> bool,
) {
    let mut sys = RunningSystem::start_with(tag, |dir| {
        let log = dir.join("counts");
        module(
            0.02,
            extra,
            &format!("{config}\ncount_log = {:?}", log.display().to_string()),
        )
    });
    let first = sys.wait_event("counter", EventKind::Started);
    let (before, saved_seen) = sys.count_until(15);
    assert!(before.id >= 15);
    if let Some(sig) = inject {
        let out = sys.hng(&["kill", "counter", "--signal", sig]);
        assert!(
            out.status.success(),
            "hng kill failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let died = sys.wait_event("counter", EventKind::Died);
    assert_eq!(died.pid, first.pid, "the first process died");
    // Everything published before the death; the last checkpoint announced is the floor of
    // the state that must come back.
    let (last, saved) = sys.drain_counts();
    let saved = saved.max(saved_seen);
    // The first process's own record of what it counted: samples it published just before
    // dying can be gone with its shared memory before this test reads them.
    let last = last.max(before.id).max(sys.last_logged_count(first.pid));
    let second = sys.wait_event("counter", EventKind::Started);
    assert_ne!(second.pid, first.pid, "a new process");
    // The new process counts on: its first count (from its own record, since a slow reader
    // can lose the oldest samples) tells the state it restored.
    sys.next_count();
    let restored = sys.first_logged_count(second.pid) - 1;
    assert!(
        restored >= saved,
        "restored count {restored} is below the last checkpoint {saved} (last counted {last})"
    );
    assert!(
        restored <= last,
        "restored count {restored} is above the last count counted {last}"
    );
    let doc = sys.status_where("the counter running again", |d| {
        let m = module_row(d, "counter");
        m["state"] == "running" && m["pid"] == second.pid && m["restarts"] == 1
    });
    let m = module_row(&doc, "counter");
    assert!(
        expect_exit(&m["last_exit"]),
        "last exit: {:#}",
        m["last_exit"]
    );
    sys.stop();
}

fn signaled(name: &'static str) -> impl Fn(&Value) -> bool {
    move |e| e["kind"] == "signaled" && e["signal"] == name
}

#[test]
fn sigkill_is_detected_and_the_module_resumes_from_its_checkpoint() {
    crash_and_recover("fkill", "", "", Some("KILL"), signaled("SIGKILL"));
}

#[test]
fn a_segfault_is_recorded_and_the_module_resumes() {
    crash_and_recover(
        "fsegv",
        "",
        "fault = \"segv\"\nfault_after = 30\nfault_runs = 1",
        None,
        signaled("SIGSEGV"),
    );
}

#[test]
fn an_abort_is_recorded_and_the_module_resumes() {
    crash_and_recover(
        "fabrt",
        "",
        "fault = \"abort\"\nfault_after = 30\nfault_runs = 1",
        None,
        signaled("SIGABRT"),
    );
}

#[test]
fn exit_1_is_recorded_and_the_module_resumes() {
    crash_and_recover(
        "fexit",
        "",
        "fault = \"exit1\"\nfault_after = 30\nfault_runs = 1",
        None,
        |e| e["kind"] == "exited" && e["code"] == 1,
    );
}

#[test]
fn a_sigstopped_module_is_a_hang_killed_and_restarted() {
    crash_and_recover(
        "fstop",
        "heartbeat_period_s = 0.05",
        "",
        Some("STOP"),
        |e| e["kind"] == "hang" && e["silent_for_ms"].as_f64().is_some_and(|ms| ms >= 100.0),
    );
}

#[test]
fn a_busy_loop_that_stops_heartbeats_is_a_hang() {
    crash_and_recover(
        "fbusy",
        "heartbeat_period_s = 0.05",
        "fault = \"busy\"\nfault_after = 30\nfault_runs = 1",
        None,
        |e| e["kind"] == "hang",
    );
}

#[test]
fn a_crash_loop_reaches_the_give_up_rule_and_is_deactivated() {
    // Each process counts twice, then exits with 1; checkpoints after every wake-up.
    let mut sys = RunningSystem::start(
        "floop",
        &module(
            0.001,
            "give_up_failures = 3\ngive_up_window_s = 60.0",
            "fault = \"exit1\"\nfault_after = 3",
        ),
    );
    sys.wait_event("counter", EventKind::Deactivated);
    let doc = sys.status_where("the counter deactivated", |d| {
        module_row(d, "counter")["state"] == "deactivated"
    });
    let m = module_row(&doc, "counter");
    assert_eq!(m["pid"], Value::Null);
    assert_eq!(
        m["restarts"], 3,
        "3 restarts allowed, the 4th failure gives up"
    );
    assert_eq!(m["last_exit"]["kind"], "exited");
    // Four processes of two counts each: without restore the count would never pass 2.
    let (last, _) = sys.drain_counts();
    assert!(
        last > 2,
        "the count did not survive the crashes (max {last})"
    );
    // The command-line view agrees.
    let ps = sys.ps();
    assert_eq!(module_row(&ps, "counter")["state"], "deactivated");
    sys.stop();
}

#[test]
fn sigterm_stops_every_module_in_reverse_order_and_leaves_nothing() {
    let modules = "[[module]]\nname = \"first\"\ncommand = [\"TESTMOD\", \"faulty\"]\nconfig = { output = \"test/a\" }\n\n\
                   [[module]]\nname = \"second\"\ncommand = [\"TESTMOD\", \"faulty\"]\nconfig = { output = \"test/b\" }\n";
    let mut sys = RunningSystem::start("fterm", modules);
    sys.wait_event("first", EventKind::Started);
    sys.wait_event("second", EventKind::Started);
    sys.status_where("both running", |d| {
        module_row(d, "first")["state"] == "running"
            && module_row(d, "second")["state"] == "running"
    });
    // Command-line errors while it runs.
    let out = sys.hng(&["kill", "nosuch"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("nosuch") && err.contains("first, second"),
        "{err}"
    );
    let ps = sys.ps();
    assert_eq!(ps["modules"].as_array().map(Vec::len), Some(2));
    assert_eq!(ps["prefix"], sys.prefix.as_str());
    // `stop` drops the observer first: the order is checked from the supervisor's log.
    let pids = sys.pids.clone();
    let dir = sys.dir.clone();
    let log = sys.stop();
    let a = log.find("first: stopped");
    let b = log.find("second: stopped");
    assert!(
        matches!((a, b), (Some(a), Some(b)) if b < a),
        "second (started last) must stop first; log:\n{log}"
    );
    assert!(pids.iter().all(|p| !is_alive(*p as i32)));
    assert!(!dir.exists(), "the test's folder is removed");
}

#[test]
fn tools_fail_clearly_when_no_system_runs() {
    let prefix = shm::unique_prefix("fnone");
    let out = Command::new(HNG)
        .args(["ps", "--prefix", &prefix])
        .output()
        .expect("hng ps");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no hng system runs"), "{err}");
    let out = Command::new(HNG)
        .args(["kill", "x", "--prefix", &prefix])
        .output()
        .expect("hng kill");
    assert!(!out.status.success());
    assert!(
        shm::prefix_files(&prefix).is_empty(),
        "asking created files: {:?}",
        shm::prefix_files(&prefix)
    );
}

#[test]
fn a_bad_launch_file_is_reported_with_line_and_field_before_anything_starts() {
    let prefix = shm::unique_prefix("fbad");
    let dir = temp_dir(&prefix);
    let file = dir.join("bad.toml");
    let text = [
        "system = \"bad\"",
        "",
        "[[module]]",
        "name = \"a\"",
        "command = [\"/bin/sh\", \"-c\", \"sleep 100\"]",
        "colour = \"red\"",
        "",
        "[[module]]",
        "name = \"b\"",
        "command = [\"/bin/sh\", \"-c\", \"sleep 100\"]",
        "",
        "[[module]]",
        "name = \"b\"",
        "command = [\"/nonexistent/prog\"]",
    ];
    std::fs::write(&file, text.join("\n")).expect("write");
    let out = Command::new(HNG)
        .args(["run", "--no-rm", "--no-gui", "--prefix", &prefix])
        .arg(&file)
        .output()
        .expect("hng run");
    assert_eq!(
        out.status.code(),
        Some(2),
        "exit code 2 for a bad launch file"
    );
    let err = String::from_utf8_lossy(&out.stderr);
    let name = file.display().to_string();
    assert!(
        err.contains(&format!("{name}:6:")) && err.contains("colour"),
        "unknown field on line 6: {err}"
    );
    assert!(
        err.contains(&format!("{name}:13:")) && err.contains("duplicate module name"),
        "duplicate on line 13: {err}"
    );
    assert!(
        err.contains(&format!("{name}:14:")) && err.contains("/nonexistent/prog"),
        "missing binary on line 14: {err}"
    );
    assert!(shm::prefix_files(&prefix).is_empty(), "nothing started");
    let _ = std::fs::remove_dir_all(&dir);
}
