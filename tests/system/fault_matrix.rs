//! The fault matrix of docs/fault-matrix.md, measured: each fatal or stopping signal is sent
//! once (`hng kill MODULE --signal SIG`) to a built-in module (the `hng` executable), an SDK
//! module (`hng-testmod`, `run_module`) and a program that is not an hng module (a shell
//! script), and what the supervisor records (exit cause, restarted or not) is compared with
//! what is expected. The table in the docs is this test's output: the test fails when the
//! docs say something else (`HNG_WRITE_FAULT_MATRIX=1` rewrites it).

use std::path::Path;
use std::time::{Duration, Instant};

use hng_runtime::shm;
use hng_runtime::system::{EventKind, JsonInfo, ModuleEvent, SUPERVISOR_EVENTS, SUPERVISOR_STATUS};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, SliceSubscriber, Subscriber};
use serde_json::Value;

use crate::signals::{Run, test_dir};

const TESTMOD: &str = env!("CARGO_BIN_EXE_hng-testmod");
const TIMEOUT: Duration = Duration::from_secs(60);

/// The modules of the matrix: name, kind (as the table says), launch-file lines.
const MODULES: [(&str, &str, &str); 3] = [
    (
        "builtin",
        "built-in module (`hng module heartbeat-probe`)",
        "command = [\"hng\", \"module\", \"heartbeat-probe\"]\nheartbeat_period_s = 0.05\nheartbeat_timeout_s = 0.25",
    ),
    (
        "sdk",
        "SDK module (`run_module`, hng-testmod counter)",
        "command = [\"TESTMOD\", \"counter\"]\nheartbeat_period_s = 0.05\nheartbeat_timeout_s = 0.25",
    ),
    (
        "script",
        "shell script (`/bin/sh -c`, no heartbeat)",
        "command = [\"/bin/sh\", \"-c\", \"while :; do sleep 0.05; done\"]",
    ),
];

const FAULTS: [&str; 8] = ["KILL", "SEGV", "BUS", "ABRT", "ILL", "FPE", "TERM", "STOP"];

/// What should happen.
fn expected(fault: &str, module: &str) -> Option<String> {
    Some(match (fault, module) {
        // Without a heartbeat a stopped process is not detected.
        ("STOP", "script") => return None,
        ("STOP", _) => "hang (no heartbeat), SIGKILLed; restarted once".to_owned(),
        // hng modules turn SIGTERM into a clean stop: exit 0, and on-failure does not restart.
        ("TERM", "builtin" | "sdk") => "exited with code 0 (clean stop); not restarted".to_owned(),
        (f, _) => format!("killed by SIG{f}; restarted once"),
    })
}

struct Observer {
    events: Subscriber<ModuleEvent>,
    status: SliceSubscriber<JsonInfo>,
    waiter: Waiter,
    last: Value,
    _node: Node,
}

impl Observer {
    fn new(prefix: &str) -> Observer {
        let node = Node::new(NodeOptions::new("matrix-test").prefix(prefix)).expect("node");
        let events = node.subscriber(SUPERVISOR_EVENTS).expect("events");
        let status = node.slice_subscriber(SUPERVISOR_STATUS).expect("status");
        let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
        waiter.attach(&events).expect("attach");
        waiter.attach(&status).expect("attach");
        Observer {
            events,
            status,
            waiter,
            last: Value::Null,
            _node: node,
        }
    }

    /// The next event about `module` of one of `kinds`.
    fn event(&mut self, module: &str, kinds: &[EventKind]) -> ModuleEvent {
        let deadline = Instant::now() + TIMEOUT;
        loop {
            while let Some(e) = self.events.receive().expect("event") {
                if e.module() == module && e.kind().is_some_and(|k| kinds.contains(&k)) {
                    return *e;
                }
            }
            self.drain_status();
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "no {kinds:?} of {module} within {TIMEOUT:?}"
            );
            self.waiter.wait(Some(left)).expect("wait");
        }
    }

    fn drain_status(&mut self) {
        while let Some(s) = self.status.receive().expect("status") {
            if let Ok(v) = serde_json::from_slice(s.data()) {
                self.last = v;
            }
        }
    }

    /// The module's row of a status document that satisfies `pred`.
    fn row_where(&mut self, module: &str, pred: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + TIMEOUT;
        loop {
            self.drain_status();
            let row = self.last["modules"]
                .as_array()
                .and_then(|ms| ms.iter().find(|m| m["name"] == module))
                .cloned()
                .unwrap_or(Value::Null);
            if pred(&row) {
                return row;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "{module}: no matching status; last {row:#}"
            );
            self.waiter.wait(Some(left)).expect("wait");
        }
    }
}

/// The exit cause of a status row, as the table says it.
fn cause_text(e: &Value) -> String {
    match e["kind"].as_str() {
        Some("signaled") => format!("killed by {}", e["signal"].as_str().unwrap_or("?")),
        Some("exited") => format!(
            "exited with code {}{}",
            e["code"],
            if e["code"] == 0 { " (clean stop)" } else { "" }
        ),
        Some("hang") => "hang (no heartbeat), SIGKILLed".to_owned(),
        other => format!("{other:?}"),
    }
}

#[test]
fn fault_matrix_every_signal_to_every_kind_of_module() {
    let prefix = shm::unique_prefix("matrix");
    let dir = test_dir(&prefix);
    std::fs::create_dir_all(&dir).expect("dir");
    let mut launch = String::from(
        "system = \"matrix\"\n\n[defaults]\nrestart = \"on-failure\"\nbackoff_initial_s = 0.01\nstop_timeout_s = 5.0\ngive_up_failures = 100\n",
    );
    for (name, _, lines) in MODULES {
        launch.push_str(&format!(
            "\n[[module]]\nname = \"{name}\"\n{}\n",
            lines.replace("TESTMOD", TESTMOD)
        ));
    }
    let file = dir.join("matrix.toml");
    std::fs::write(&file, launch).expect("launch file");
    let mut obs = Observer::new(&prefix);
    let mut run = Run::start_on(
        &prefix,
        &[
            "--no-rm",
            "--status-period",
            "0.1",
            file.to_str().expect("path"),
        ],
    );
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    for (name, kind, _) in MODULES {
        for fault in FAULTS {
            let Some(want) = expected(fault, name) else {
                continue;
            };
            let before = obs.row_where(name, |r| r["state"] == "running" && r["pid"].is_number());
            let restarts = before["restarts"].as_u64().unwrap_or(0);
            let out = run.hng(&["kill", name, "--signal", fault]);
            assert!(
                out.status.success(),
                "hng kill {name} {fault}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            let died = obs.event(name, &[EventKind::Died]);
            assert_eq!(Some(died.pid), before["pid"].as_u64().map(|p| p as u32));
            let next = obs.event(name, &[EventKind::Started, EventKind::Stopped]);
            let restarted = next.kind() == Some(EventKind::Started);
            let row = obs.row_where(name, |r| {
                r["last_exit"].is_object()
                    && (r["state"] == "stopped" || r["restarts"].as_u64() > Some(restarts))
            });
            let got = format!(
                "{}; {}",
                cause_text(&row["last_exit"]),
                match (restarted, row["restarts"].as_u64().unwrap_or(0) - restarts) {
                    (true, 1) => "restarted once".to_owned(),
                    (true, n) => format!("restarted {n} times"),
                    (false, _) => "not restarted".to_owned(),
                }
            );
            if got != want {
                failures.push(format!(
                    "{fault} to {name}: expected {want:?}, observed {got:?}"
                ));
            }
            rows.push(format!("| SIG{fault} | {kind} | {want} | {got} |"));
            if !restarted {
                let out = run.hng(&["start", name]);
                assert!(out.status.success(), "hng start {name}");
            }
        }
    }
    drop(obs);
    run.stop_ok();
    assert!(
        failures.is_empty(),
        "fault matrix:\n{}",
        failures.join("\n")
    );

    let table = format!(
        "| fault | module | expected | observed |\n|---|---|---|---|\n{}\n",
        rows.join("\n")
    );
    let doc = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/fault-matrix.md");
    let text = std::fs::read_to_string(&doc).unwrap_or_default();
    let (head, rest) = text
        .split_once(BEGIN)
        .map_or((text.as_str(), ""), |(h, r)| (h, r));
    let tail = rest.split_once(END).map_or("", |(_, t)| t);
    let fresh = format!("{head}{BEGIN}\n{table}{END}{tail}");
    if std::env::var_os("HNG_WRITE_FAULT_MATRIX").is_some() {
        std::fs::write(&doc, fresh).expect("write docs/fault-matrix.md");
    } else {
        assert_eq!(
            text, fresh,
            "docs/fault-matrix.md is not what this test measured: rerun with HNG_WRITE_FAULT_MATRIX=1"
        );
    }
}

const BEGIN: &str = "<!-- fault-matrix: generated by tests/system/fault_matrix.rs -->";
const END: &str = "<!-- end of fault-matrix -->";
