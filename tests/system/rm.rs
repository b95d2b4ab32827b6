//! The resource manager as a process (`hng module rm`) with real fixture modules: CPU
//! measurement, limits ("over limit" through the supervisor), degraded mode, `hng top`.
//!
//! Each test runs under its own prefix; the RM and the fixtures are killed and the prefix's
//! files removed on drop, also when a test fails.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{Goal, ModuleReport, ModuleState};
use hng_runtime::system::{
    CommandOp, JsonInfo, RM_COSTS, RM_STATUS, ResourceCosts, SUPERVISOR_COMMAND, SUPERVISOR_STATUS,
    SupervisorCommand,
};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, SliceSubscriber, Subscriber, shm};
use serde_json::Value;

use crate::common::{Reaped, TestSystem};

const HNG: &str = env!("CARGO_BIN_EXE_hng");
const TESTMOD: &str = env!("CARGO_BIN_EXE_hng-testmod");
const TIMEOUT: Duration = Duration::from_secs(15);

/// Starts `hng module rm` under a test's prefix; killed on drop.
fn start_rm(prefix: &str, config: &str) -> Reaped {
    let child = Command::new(HNG)
        .args(["module", "rm"])
        .env("HNG_PREFIX", prefix)
        .env("HNG_MODULE_NAME", "rm")
        .env("HNG_MODULE_CONFIG", config)
        .env("HNG_LOG", "warn")
        .env_remove("HNG_CGROUP_RUN")
        .stdin(Stdio::null())
        .spawn()
        .expect("spawn hng module rm");
    Reaped(child)
}

/// The test's ports on the system channels.
struct Observer {
    status: SliceSubscriber<JsonInfo>,
    costs: Subscriber<ResourceCosts>,
    commands: Subscriber<SupervisorCommand>,
    reports: Subscriber<ModuleReport>,
    waiter: Waiter,
    node: Node,
}

impl Observer {
    /// Subscribes before anything starts, so no command or report is missed.
    fn new(prefix: &str) -> Observer {
        let node = Node::new(NodeOptions::new("rm-test").prefix(prefix)).expect("node");
        // Every status, not only the latest few (the CPU test weighs each figure by its
        // interval).
        let status = node
            .slice_tap_subscriber::<JsonInfo>(RM_STATUS)
            .expect("rm status");
        let costs = node.subscriber::<ResourceCosts>(RM_COSTS).expect("costs");
        let commands = node
            .subscriber::<SupervisorCommand>(SUPERVISOR_COMMAND)
            .expect("commands");
        let reports = node
            .subscriber::<ModuleReport>(REPORT_CHANNEL)
            .expect("reports");
        let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
        waiter.attach(&status).expect("attach");
        waiter.attach(&costs).expect("attach");
        waiter.attach(&commands).expect("attach");
        waiter.attach(&reports).expect("attach");
        Observer {
            status,
            costs,
            commands,
            reports,
            waiter,
            node,
        }
    }

    /// Blocks until something arrives or `deadline`; panics with `what` after it.
    fn wait(&mut self, deadline: Instant, what: &str) {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "timed out waiting for {what}");
        self.waiter.wait(Some(left)).expect("wait");
    }

    /// The next RM status document.
    fn next_status(&mut self, deadline: Instant) -> Value {
        self.next_stamped_status(deadline).1
    }

    /// The next RM status document with its stamp (`CLOCK_MONOTONIC` s, the RM's clock).
    fn next_stamped_status(&mut self, deadline: Instant) -> (f64, Value) {
        loop {
            if let Some(s) = self.status.receive().expect("receive status") {
                let doc = serde_json::from_slice(s.data()).expect("RM status is JSON");
                return (s.header().header.stamp_ns as f64 * 1e-9, doc);
            }
            self.wait(deadline, "an RM status");
        }
    }

    /// The first RM status satisfying `pred`.
    fn status_where(&mut self, what: &str, mut pred: impl FnMut(&Value) -> bool) -> Value {
        let deadline = Instant::now() + TIMEOUT;
        let mut last = Value::Null;
        loop {
            while let Some(s) = self.status.receive().expect("receive status") {
                let doc: Value = serde_json::from_slice(s.data()).expect("RM status is JSON");
                if pred(&doc) {
                    return doc;
                }
                last = doc;
            }
            if Instant::now() >= deadline {
                panic!("no RM status with {what} within {TIMEOUT:?}; last: {last:#}");
            }
            self.wait(deadline, what);
        }
    }
}

fn module<'a>(doc: &'a Value, name: &str) -> &'a Value {
    doc["modules"]
        .as_array()
        .and_then(|ms| ms.iter().find(|m| m["name"] == name))
        .unwrap_or(&Value::Null)
}

/// utime + stime of a process, seconds (kernel accounting: the ground truth).
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("read stat");
    let rest = stat.rsplit_once(") ").expect("stat format").1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    // After ')': index 0 is field 3; utime is field 14, stime field 15.
    let ticks: u64 = f[11].parse::<u64>().expect("utime") + f[12].parse::<u64>().expect("stime");
    ticks as f64 / clock_ticks_per_second()
}

/// USER_HZ, the unit of utime and stime (`getconf CLK_TCK`; 100 on Linux).
fn clock_ticks_per_second() -> f64 {
    Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.trim().parse::<f64>().ok())
        .filter(|t| *t > 0.0)
        .unwrap_or(100.0)
}

/// The RM's CPU % of a module burning (up to) 30 % of a core is what the kernel accounts for
/// that process (utime + stime, read by the test) over the same window, within 2 points.
///
/// How much the burner gets is the kernel's choice (under load far less than 30 %), not the
/// RM's: the test compares the RM with the kernel only. The window is the RM's own: from the
/// stamp of one status to that of a later one, each figure weighed by its interval (the RM's
/// figures are over 100 ms, shorter or longer when it runs late, and a figure over 20 ms is
/// 0 or 50 % by the kernel's 10 ms ticks: an unweighted mean of such figures was 11.9 % for
/// the kernel's 6.2 % at load 17). The test reads the kernel's figure as each of the two
/// statuses arrives. Measured: |RM - kernel| at most 1.15 points in 44 runs at load 14-27
/// (the kernel gave the burner 0.8-23 %), 2 points with a margin.
#[test]
fn rm_measures_a_burning_module_as_the_kernel_accounts_it() {
    let _heavy = crate::common::heavy();
    let mut sys = TestSystem::new("rmcpu");
    let mut obs = Observer::new(&sys.prefix);
    let pid = sys.spawn_testmod("burn", "burner", "fraction = 0.3");
    let _rm = start_rm(&sys.prefix, "rate_hz = 10");
    // Warm up: the burner has caught up and the RM has two samples.
    obs.status_where("burner's cpu_percent", |d| {
        module(d, "burner")["cpu_percent"].is_number()
    });
    // Start at the next status (the ones before were read late).
    while obs.status.receive().expect("receive status").is_some() {}
    let (s0, _) = obs.next_stamped_status(Instant::now() + TIMEOUT);
    let (m0, c0) = (Instant::now(), cpu_seconds(pid));
    let mut figures = Vec::new();
    let mut last = s0;
    // 3 s and 20 figures at least (a starved RM published 7 in 3 s at load 16).
    while m0.elapsed() < Duration::from_secs(3) || figures.len() < 20 {
        let (stamp, doc) = obs.next_stamped_status(Instant::now() + TIMEOUT);
        let c = module(&doc, "burner")["cpu_percent"].as_f64();
        figures.push((stamp - last, c.expect("a figure in every status")));
        last = stamp;
    }
    let (m1, c1) = (Instant::now(), cpu_seconds(pid));
    let kernel = 100.0 * (c1 - c0) / (m1 - m0).as_secs_f64();
    assert_eq!(obs.status.stats().dropped, 0, "the test lost RM statuses");
    let span: f64 = figures.iter().map(|f| f.0).sum();
    let rm = figures.iter().map(|(dt, c)| dt * c).sum::<f64>() / span;
    let unweighted = figures.iter().map(|f| f.1).sum::<f64>() / figures.len() as f64;
    println!(
        "burner (nominal 30 %): RM {rm:.2} % over {span:.2} s ({} figures, unweighted mean \
         {unweighted:.2} %), kernel {kernel:.2} %",
        figures.len()
    );
    assert!(
        kernel > 0.5,
        "the burner burned nothing: kernel {kernel:.2} %"
    );
    assert!(
        (rm - kernel).abs() < 2.0,
        "RM says {rm:.2} %, the kernel {kernel:.2} %"
    );
    // The RM samples itself too (it is a module).
    let doc = obs.next_status(Instant::now() + TIMEOUT);
    assert!(module(&doc, "rm")["pid"].is_number(), "{doc:#}");
}

/// A memory hog over the RM's software limit is reported: an OverLimit command for it
/// arrives on the supervisor's command channel, with the measured figure in its reason.
#[test]
fn memory_hog_over_its_limit_is_sent_over_limit() {
    let _heavy = crate::common::heavy();
    let mut sys = TestSystem::new("rmhog");
    let mut obs = Observer::new(&sys.prefix);
    sys.spawn_testmod("hog", "hog", "step_mb = 8\nperiod_s = 0.05\nmax_mb = 160");
    sys.spawn_testmod("counter", "calm", "");
    let _rm = start_rm(
        &sys.prefix,
        "rate_hz = 10\ncgroups = false\n[limits.hog]\nmemory_max = \"48MiB\"\n[limits.calm]\nmemory_max = \"48MiB\"\n",
    );
    let deadline = Instant::now() + TIMEOUT;
    let cmd = loop {
        if let Some(c) = obs.commands.receive().expect("receive command") {
            break *c;
        }
        obs.wait(deadline, "an OverLimit command");
    };
    assert_eq!(cmd.op(), Some(CommandOp::OverLimit));
    assert_eq!(cmd.module(), "hog", "only the hog is over its limit");
    assert!(
        cmd.reason().starts_with("memory ") && cmd.reason().ends_with("> 48.0 MiB"),
        "{}",
        cmd.reason()
    );
    let doc = obs.status_where("the hog marked over limit", |d| {
        module(d, "hog")["over_limit"].is_string()
    });
    let hog = module(&doc, "hog");
    assert_eq!(hog["caps"]["memory_bytes"]["enforced"], "software");
    assert!(module(&doc, "calm")["over_limit"].is_null());
}

/// Induced scarcity: three providers (priorities 1, 2, 3) report waiting for resources
/// while they work. The RM raises C_R to its maximum, enters degraded mode and publishes a
/// minimum priority that stops the least important first (3, then 2) while 1 keeps running;
/// when the scarcity ends, work resumes in reverse order and degraded mode ends.
#[test]
fn degraded_mode_stops_least_important_first_and_recovers() {
    let _heavy = crate::common::heavy();
    let mut sys = TestSystem::new("rmdeg");
    let mut obs = Observer::new(&sys.prefix);
    let scarce = obs
        .node
        .publisher::<Goal>("test/scarce")
        .expect("scarce publisher");
    scarce
        .publish(Goal {
            id: 1,
            ..Default::default()
        })
        .expect("publish scarce");
    for (name, prio) in [("p1", "[1]"), ("p2", "[2]"), ("p3", "[3]")] {
        sys.spawn_testmod("needy", name, &format!("priority = {prio}"));
    }
    // Only the wait-for-resources reports make resources scarce here (the machine running
    // the tests may be busy or not).
    let _rm = start_rm(
        &sys.prefix,
        "rate_hz = 20\ncpu_free_threshold = 0.0\nmemory_free_threshold = 0.0\ncomm_delay_threshold_s = 5.0\ndegraded_enter_after = 2\ndegraded_step_after = 4\ndegraded_recover_after = 4\n",
    );
    let deadline = Instant::now() + TIMEOUT;
    // Sequence of published bars (None = normal mode), without repeats.
    let mut bars: Vec<Option<Vec<u16>>> = vec![None];
    let mut states: [Option<ModuleState>; 3] = [None; 3];
    let mut p1_stopped = false;
    let mut idle_seen = [false; 3];
    let mut calm_sent = false;
    loop {
        // The flag was published before the modules subscribed: deliver the latest sample
        // (history) to those that joined since.
        scarce.update_connections();
        while let Some(c) = obs.costs.receive().expect("receive costs") {
            let bar = (c.degraded != 0).then(|| c.min_priority().unwrap_or(&[]).to_vec());
            if bars.last() != Some(&bar) {
                bars.push(bar);
            }
        }
        while let Some(r) = obs.reports.receive().expect("receive report") {
            let i = match r.name() {
                "p1" => 0,
                "p2" => 1,
                "p3" => 2,
                _ => continue,
            };
            states[i] = ModuleState::from_repr(r.state);
            if states[i] == Some(ModuleState::Idle) {
                idle_seen[i] = true;
                if i == 0 {
                    p1_stopped = true;
                }
            }
            // p2 stopped while p3 still works would be the wrong order.
            if idle_seen[1] && !idle_seen[2] {
                panic!("p2 stopped before p3; bars {bars:?}");
            }
        }
        // Deepest cut reached (2 stopped) and seen by the modules: end the scarcity.
        if !calm_sent
            && bars.last() == Some(&Some(vec![1]))
            && states[1] == Some(ModuleState::Idle)
            && states[2] == Some(ModuleState::Idle)
        {
            scarce
                .publish(Goal {
                    id: 0,
                    ..Default::default()
                })
                .expect("publish calm");
            calm_sent = true;
        }
        if calm_sent
            && bars.last() == Some(&None)
            && states.iter().all(|s| *s == Some(ModuleState::Running))
        {
            break;
        }
        obs.wait(
            deadline,
            &format!("degraded mode and recovery; bars so far {bars:?}, states {states:?}"),
        );
    }
    assert_eq!(
        bars,
        vec![None, Some(vec![2]), Some(vec![1]), Some(vec![2]), None],
        "cut 3, then 2; restore 2, then everything"
    );
    assert!(!p1_stopped, "the most important provider never stopped");
}

/// Full path through `hng run`: the RM (configured in the launch file with a software
/// memory limit for `hog`) asks the supervisor to stop the hog, which is killed, recorded
/// with exit cause "over limit" and restarted. With writable cgroups, a burner with a 20 %
/// CPU quota measures 15-25 % (from its cgroup) and its cap shows as kernel-enforced.
/// `hng top --once --json` shows the figures.
#[test]
fn over_limit_through_hng_run_is_killed_recorded_and_restarted() {
    let _heavy = crate::common::heavy();
    let prefix = shm::unique_prefix("rmrun");
    let dir: PathBuf = std::env::temp_dir().join(format!("{prefix}run"));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let launch = format!(
        r#"system = "rmrun"

[defaults]
stop_timeout_s = 5.0
backoff_initial_s = 0.01
restart = "always"

[[module]]
name = "rm"
command = ["hng", "module", "rm"]

[module.config]
rate_hz = 10
[module.config.limits.hog]
memory_max = "48MiB"

[[module]]
name = "hog"
command = ["{TESTMOD}", "hog"]

[module.config]
step_mb = 8
period_s = 0.05
max_mb = 160

[[module]]
name = "capped"
command = ["{TESTMOD}", "burn"]
cpu_quota = 0.2

[module.config]
fraction = 0.6
"#
    );
    let file = dir.join("launch.toml");
    std::fs::write(&file, launch).expect("write launch file");
    let node = Node::new(NodeOptions::new("rm-run-test").prefix(&prefix)).expect("node");
    let sup = node
        .slice_subscriber::<JsonInfo>(SUPERVISOR_STATUS)
        .expect("supervisor status");
    let mut obs = Observer::new(&prefix);
    let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
    waiter.attach(&sup).expect("attach");
    let child = crate::common::spawn_hng_run(&prefix, &dir, &file, &[]);
    struct Guard(Option<Child>, String, PathBuf);
    impl Drop for Guard {
        fn drop(&mut self) {
            if let Some(mut c) = self.0.take() {
                let _ = crate::common::terminate(&mut c, Duration::from_secs(10));
                let _ = c.kill();
                let _ = c.wait();
            }
            shm::remove_prefix_files(&self.1);
            let _ = std::fs::remove_dir_all(&self.2);
        }
    }
    let guard = Guard(Some(child), prefix.clone(), dir.clone());
    let run_log = || std::fs::read_to_string(dir.join("run.log")).unwrap_or_default();

    // The supervisor records the kill as "over limit" and restarts the hog.
    let deadline = Instant::now() + Duration::from_secs(25);
    let mut last = Value::Null;
    let row = 'found: loop {
        while let Some(s) = sup.receive().expect("receive status") {
            let doc: Value = serde_json::from_slice(s.data()).expect("status is JSON");
            let hog = module(&doc, "hog").clone();
            let over = hog["last_exit_text"]
                .as_str()
                .is_some_and(|t| t.contains("over limit"));
            if over && hog["restarts"].as_u64().unwrap_or(0) >= 1 {
                break 'found hog;
            }
            last = doc;
        }
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(
            !left.is_zero(),
            "no over-limit restart of hog; last status {last:#}\nlog:\n{}",
            run_log()
        );
        waiter.wait(Some(left)).expect("wait");
    };
    println!("hog: {}", row["last_exit_text"]);
    assert!(
        row["last_exit_text"]
            .as_str()
            .is_some_and(|t| t.contains("memory")),
        "{row:#}"
    );
    // The OverLimit command the RM sent is on the command channel too.
    let mut seen = false;
    while let Some(c) = obs.commands.receive().expect("receive command") {
        seen |= c.op() == Some(CommandOp::OverLimit) && c.module() == "hog";
    }
    assert!(seen, "the RM's OverLimit command for hog");

    // CPU quota measured through the module's cgroup.
    let doc = obs.status_where("capped's cpu figure", |d| {
        module(d, "capped")["cpu_percent"].is_number()
    });
    let cgroups = doc["cgroups"].as_str().unwrap_or_default().to_owned();
    if module(&doc, "capped")["cgroup"] == true {
        assert_eq!(
            module(&doc, "capped")["caps"]["cpu_percent"]["kernel"].as_f64(),
            Some(20.0),
            "{doc:#}"
        );
        let t0 = Instant::now();
        let mut figures = Vec::new();
        while t0.elapsed() < Duration::from_secs(3) {
            let d = obs.next_status(Instant::now() + TIMEOUT);
            if let Some(c) = module(&d, "capped")["cpu_percent"].as_f64() {
                figures.push(c);
            }
        }
        let avg = figures.iter().sum::<f64>() / figures.len().max(1) as f64;
        println!("capped (20% quota, burning 60%): {avg:.1}% over 3 s ({cgroups})");
        assert!((15.0..=25.0).contains(&avg), "{avg:.1}% for a 20% quota");
        assert_eq!(module(&doc, "capped")["cpu_source"], "cgroup");
    } else {
        crate::common::skip(
            "over_limit_through_hng_run_is_killed_recorded_and_restarted (its CPU quota part)",
            &format!("the RM has no cgroup for the module ({cgroups})"),
        );
    }

    // hng top --once --json sees the same system.
    let out = Command::new(HNG)
        .args(["top", "--once", "--json"])
        .env("HNG_PREFIX", &prefix)
        .env("HNG_LOG", "warn")
        .output()
        .expect("run hng top");
    assert!(
        out.status.success(),
        "hng top: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let top: Value = serde_json::from_slice(&out.stdout).expect("hng top --json is JSON");
    for name in ["rm", "hog", "capped"] {
        let m = module(&top, name);
        assert!(m["pid"].is_number(), "{name} in hng top: {top:#}");
    }
    assert!(top["costs"]["cpu"].is_number(), "{top:#}");
    assert!(module(&top, "capped")["cpu_percent"].is_number(), "{top:#}");

    // hng ps --json carries the RM's figures beside the supervisor's.
    let out = Command::new(HNG)
        .args(["ps", "--json"])
        .env("HNG_PREFIX", &prefix)
        .env("HNG_LOG", "warn")
        .output()
        .expect("run hng ps");
    assert!(
        out.status.success(),
        "hng ps: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ps: Value = serde_json::from_slice(&out.stdout).expect("hng ps --json is JSON");
    let capped = ps["modules"]
        .as_array()
        .and_then(|ms| ms.iter().find(|m| m["name"] == "capped"))
        .expect("capped in hng ps");
    assert!(capped["resources"]["cpu_percent"].is_number(), "{ps:#}");
    assert!(capped["resources"]["rss_bytes"].is_number(), "{ps:#}");
    // ... and the supervisor's caps: who enforces the 20% quota (kernel cgroup, or the
    // RM's software check naming why the kernel does not).
    assert_eq!(capped["caps"]["cpu_quota"].as_f64(), Some(0.2), "{ps:#}");
    match capped["caps"]["cpu"].as_str() {
        Some("kernel") => {}
        Some("software") => assert!(
            capped["caps"]["fallback"][0]
                .as_str()
                .is_some_and(|f| f.contains("resource manager")),
            "{ps:#}"
        ),
        other => panic!("cpu cap enforced by {other:?}: {ps:#}"),
    }
    assert!(module(&ps, "hog")["caps"].is_null(), "{ps:#}");
    drop(obs);
    drop(sup);
    drop(node);
    drop(guard);
}
