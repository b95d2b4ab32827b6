//! Supervisor tests with real processes (`/bin/sh`, `/bin/sleep`).
//!
//! Synchronisation is always on an observable condition with a deadline:
//! supervisor events (the event loop blocks on pidfds), or the state of a
//! process in /proc (signal dispositions, process-group members). Nothing
//! sleeps for a fixed time hoping something has happened.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use hng_watchdog::{
    Event, EventKind, ExitCause, HeartbeatSpec, ModuleSpec, ModuleState, NoHooks, RestartPolicy,
    Signal, Supervisor, SupervisorHooks, SupervisorOptions,
};

const T: Duration = Duration::from_secs(10);

fn spec(name: &str, program: &str, args: &[&str]) -> ModuleSpec {
    let mut s = ModuleSpec::new(name, program, args);
    s.stop_timeout = Duration::from_secs(3);
    s
}

fn sh(name: &str, script: &str) -> ModuleSpec {
    spec(name, "/bin/sh", &["-c", script])
}

/// `/bin/sleep 1000` as module `name`, expected to beat every 20 ms: hung after `timeout`
/// of silence, or `start_timeout` without a first beat.
fn sleeper_with_heartbeat(name: &str, timeout: Duration, start_timeout: Duration) -> ModuleSpec {
    let mut m = spec(name, "/bin/sleep", &["1000"]);
    m.heartbeat = Some(HeartbeatSpec {
        period: Duration::from_millis(20),
        timeout,
    });
    m.start_timeout = start_timeout;
    m
}

/// Drives a supervisor and keeps every event it returned.
struct Harness<H: SupervisorHooks> {
    sup: Supervisor<H>,
    log: Vec<Event>,
    queue: VecDeque<Event>,
    /// Every pid seen in a Started event, to check /proc at the end.
    pids: Vec<u32>,
}

impl Harness<NoHooks> {
    /// Starts `modules` under a supervisor with the default options.
    fn start(modules: Vec<ModuleSpec>) -> Self {
        Harness::start_with(Supervisor::new(modules, SupervisorOptions::default()).expect("new"))
    }
}

impl<H: SupervisorHooks> Harness<H> {
    /// Starts every module of `sup`.
    fn start_with(mut sup: Supervisor<H>) -> Self {
        sup.start_all();
        Self {
            sup,
            log: Vec::new(),
            queue: VecDeque::new(),
            pids: Vec::new(),
        }
    }

    fn take(&mut self, events: Vec<Event>) {
        for e in events {
            if let EventKind::Started { pid, .. } = e.kind {
                self.pids.push(pid);
            }
            self.log.push(e.clone());
            self.queue.push_back(e);
        }
    }

    /// Next event (in order) for which `pred` holds; events before it are
    /// skipped (they stay in `log`). `tick` runs between polls, at least every 20 ms.
    fn wait_with(
        &mut self,
        what: &str,
        timeout: Duration,
        mut pred: impl FnMut(&Event) -> bool,
        mut tick: impl FnMut(&mut Supervisor<H>),
    ) -> Event {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(e) = self.queue.pop_front() {
                if pred(&e) {
                    return e;
                }
            }
            let now = Instant::now();
            assert!(
                now < deadline,
                "timed out waiting for {what}; events so far:\n{}",
                self.log
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join("\n")
            );
            tick(&mut self.sup);
            let wait = (deadline - now).min(Duration::from_millis(20));
            let events = self.sup.poll(wait).expect("poll failed");
            self.take(events);
        }
    }

    fn wait(&mut self, what: &str, pred: impl FnMut(&Event) -> bool) -> Event {
        self.wait_with(what, T, pred, |_| {})
    }

    fn shutdown(&mut self) {
        let events = self.sup.shutdown().expect("shutdown failed");
        self.take(events);
    }

    /// After shutdown: no process we started, nor any member of their
    /// process groups, is alive.
    fn assert_no_leftovers(&self) {
        for &pid in &self.pids {
            wait_until(&format!("process group {pid} to be empty"), || {
                alive_in_group(pid).is_empty() && !alive(pid)
            });
        }
    }
}

fn module_of(e: &Event) -> &str {
    &e.module
}

// ---------------------------------------------------------------------------
// /proc helpers
// ---------------------------------------------------------------------------

/// (state, ppid, pgrp) from /proc/PID/stat.
fn stat(pid: u32) -> Option<(char, u32, u32)> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let mut it = rest.split_whitespace();
    let state = it.next()?.chars().next()?;
    let ppid = it.next()?.parse().ok()?;
    let pgrp = it.next()?.parse().ok()?;
    Some((state, ppid, pgrp))
}

/// Alive = exists and is not a zombie (zombies of reparented orphans may
/// linger if PID 1 does not reap; they hold no resources but a pid).
fn alive(pid: u32) -> bool {
    stat(pid).is_some_and(|(state, _, _)| state != 'Z' && state != 'X')
}

fn alive_in_group(pgid: u32) -> Vec<u32> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|&pid| stat(pid).is_some_and(|(st, _, pg)| pg == pgid && st != 'Z' && st != 'X'))
        .collect()
}

fn ignores_sigterm(pid: u32) -> bool {
    let Ok(s) = std::fs::read_to_string(format!("/proc/{pid}/status")) else {
        return false;
    };
    s.lines()
        .find_map(|l| l.strip_prefix("SigIgn:"))
        .and_then(|hex| u64::from_str_radix(hex.trim(), 16).ok())
        .is_some_and(|mask| mask & (1 << (libc::SIGTERM - 1)) != 0)
}

/// Wait for a condition observable in /proc (e.g. a signal disposition),
/// re-checking every 2 ms, failing after 10 s.
fn wait_until(what: &str, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + T;
    while !cond() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn started_pid(e: &Event) -> u32 {
    match e.kind {
        EventKind::Started { pid, .. } => pid,
        _ => panic!("not a Started event: {e}"),
    }
}

fn exit_cause(e: &Event) -> ExitCause {
    match &e.kind {
        EventKind::Exited { cause, .. } => cause.clone(),
        _ => panic!("not an Exited event: {e}"),
    }
}

fn is_exit(name: &'static str) -> impl FnMut(&Event) -> bool {
    move |e| e.module == name && matches!(e.kind, EventKind::Exited { .. })
}

fn is_started(name: &'static str) -> impl FnMut(&Event) -> bool {
    move |e| e.module == name && matches!(e.kind, EventKind::Started { .. })
}

// ---------------------------------------------------------------------------
// Tests
// ---------------------------------------------------------------------------

#[test]
fn crash_causes_are_classified() {
    let mut mods = vec![
        sh("selfkill", "kill -KILL $$"),
        sh("segv", "kill -SEGV $$"),
        sh("abort", "kill -ABRT $$"),
        sh("exit1", "exit 1"),
        sh("exit0", "exit 0"),
        spec("injected", "/bin/sleep", &["1000"]),
    ];
    for m in &mut mods {
        m.restart = RestartPolicy::OnFailure;
        m.give_up_failures = 0; // first failure deactivates: one exit each
    }
    let mut h = Harness::start(mods);
    let started = h.wait("injected started", is_started("injected"));
    assert!(started_pid(&started) > 0);
    h.sup.kill("injected", Signal::SIGKILL).expect("kill");

    let mut causes = std::collections::BTreeMap::new();
    for _ in 0..6 {
        let e = h.wait("an exit", |e| matches!(e.kind, EventKind::Exited { .. }));
        causes.insert(module_of(&e).to_owned(), exit_cause(&e));
    }
    let sig = |c: &ExitCause| match c {
        ExitCause::Signaled { signal, .. } => signal.clone(),
        other => format!("{other:?}"),
    };
    assert_eq!(sig(&causes["selfkill"]), "SIGKILL");
    assert_eq!(sig(&causes["segv"]), "SIGSEGV");
    assert_eq!(sig(&causes["abort"]), "SIGABRT");
    assert_eq!(sig(&causes["injected"]), "SIGKILL");
    assert_eq!(causes["exit1"], ExitCause::Exited { code: 1 });
    assert_eq!(causes["exit0"], ExitCause::Exited { code: 0 });
    // exit 0 under on-failure: Stopped; a failure with 0 allowed: Deactivated.
    // (Decided in the same poll as the exit, so already in the log.)
    assert!(
        h.log
            .iter()
            .any(|e| e.module == "exit0" && e.kind == EventKind::Stopped)
    );
    assert!(h.log.iter().any(|e| {
        e.module == "exit1" && matches!(e.kind, EventKind::Deactivated { failures: 1, .. })
    }));
    assert_eq!(h.sup.state("exit0").expect("state"), ModuleState::Stopped);
    assert_eq!(
        h.sup.state("exit1").expect("state"),
        ModuleState::Deactivated
    );
    h.shutdown();
    h.assert_no_leftovers();
}

#[test]
fn hang_by_sigstop_is_detected_killed_and_restarted() {
    // Generous timeout: the machine is shared, a starved test thread must not
    // look like a hang.
    let m = sleeper_with_heartbeat("stuck", Duration::from_millis(400), Duration::from_secs(5));
    let mut h = Harness::start(vec![m]);
    let pid = started_pid(&h.wait("start", is_started("stuck")));

    // The test is the module's heartbeat source: it sends one per tick while
    // the process exists and is not stopped ('T') in /proc.
    let feed = |sup: &mut Supervisor<_>| {
        if let Ok(Some(pid)) = sup.pid("stuck")
            && stat(pid).is_some_and(|(st, _, _)| st != 'T' && st != 'Z')
        {
            sup.heartbeat("stuck", Instant::now()).expect("heartbeat");
        }
    };
    h.wait_with(
        "running",
        T,
        |e| matches!(e.kind, EventKind::Running { .. }),
        feed,
    );
    let stopped_at = Instant::now();
    h.sup.kill("stuck", Signal::SIGSTOP).expect("SIGSTOP");
    let hang = h.wait_with(
        "hang",
        T,
        |e| matches!(e.kind, EventKind::HangDetected { .. }),
        feed,
    );
    match hang.kind {
        EventKind::HangDetected { pid: p, silent_for } => {
            assert_eq!(p, pid);
            assert!(silent_for >= Duration::from_millis(400), "{silent_for:?}");
        }
        _ => unreachable!(),
    }
    println!(
        "SIGSTOP -> hang detected: {:.1} ms (timeout 400 ms, heartbeat every 20 ms)",
        (hang.at - stopped_at).as_secs_f64() * 1e3
    );
    let exit = h.wait_with("exit", T, is_exit("stuck"), feed);
    assert!(
        matches!(exit_cause(&exit), ExitCause::Hang { .. }),
        "{exit}"
    );
    let r = h.wait_with(
        "restart",
        T,
        |e| matches!(e.kind, EventKind::Restarting { .. }),
        feed,
    );
    assert!(
        matches!(r.kind, EventKind::Restarting { delay, attempt: 1 } if delay.is_zero()),
        "first restart is immediate: {r}"
    );
    let new_pid = started_pid(&h.wait_with("restarted", T, is_started("stuck"), feed));
    assert_ne!(new_pid, pid);
    h.wait_with(
        "running again",
        T,
        |e| matches!(e.kind, EventKind::Running { .. }),
        feed,
    );
    let st = &h.sup.status(Instant::now())[0];
    assert_eq!(st.restarts, 1);
    assert!(matches!(st.last_exit, Some(ExitCause::Hang { .. })));
    h.shutdown();
    h.assert_no_leftovers();
}

#[test]
fn a_heartbeat_that_announces_a_longer_period_moves_the_hang_deadline() {
    // An idle module stretches its heartbeat and says so in each report; the supervisor then
    // waits the announced period plus the configured slack (timeout - period), not the
    // configured timeout alone.
    let m = sleeper_with_heartbeat("idle", Duration::from_millis(200), Duration::from_secs(5));
    let (period, timeout) = (Duration::from_millis(20), Duration::from_millis(200));
    let mut h = Harness::start(vec![m]);
    h.wait("start", is_started("idle"));
    let promised = Duration::from_millis(800);
    h.sup
        .heartbeat_promising("idle", Instant::now(), Some(promised))
        .expect("heartbeat");
    let hang = h.wait("hang", |e| matches!(e.kind, EventKind::HangDetected { .. }));
    match hang.kind {
        EventKind::HangDetected { silent_for, .. } => {
            let deadline = timeout + promised - period;
            assert!(silent_for >= deadline, "{silent_for:?} < {deadline:?}");
        }
        _ => unreachable!(),
    }
    h.wait("exit", is_exit("idle"));
    h.shutdown();
    h.assert_no_leftovers();
}

#[test]
fn silent_start_is_a_hang_too() {
    let mut m = sleeper_with_heartbeat(
        "mute",
        Duration::from_millis(60),
        Duration::from_millis(100),
    );
    m.restart = RestartPolicy::Never;
    let mut h = Harness::start(vec![m]);
    let exit = h.wait("exit", is_exit("mute"));
    assert!(
        matches!(exit_cause(&exit), ExitCause::Hang { silent_for } if silent_for >= Duration::from_millis(100)),
        "{exit}"
    );
    h.wait("stopped", |e| e.kind == EventKind::Stopped);
    h.shutdown();
    h.assert_no_leftovers();
}

#[test]
fn crash_loop_backs_off_doubling_then_deactivates() {
    let mut m = sh("crashy", "exit 3");
    m.restart = RestartPolicy::OnFailure;
    m.backoff_initial = Duration::from_millis(20);
    m.backoff_max = Duration::from_millis(80);
    m.give_up_failures = 5;
    m.give_up_window = Duration::from_secs(60);
    let mut h = Harness::start(vec![m]);
    let deact = h.wait("deactivated", |e| {
        matches!(e.kind, EventKind::Deactivated { .. })
    });
    assert!(
        matches!(deact.kind, EventKind::Deactivated { failures: 6, .. }),
        "more than 5 failures: {deact}"
    );
    let delays: Vec<u128> = h
        .log
        .iter()
        .filter_map(|e| match e.kind {
            EventKind::Restarting { delay, .. } => Some(delay.as_millis()),
            _ => None,
        })
        .collect();
    assert_eq!(delays, [0, 20, 40, 80, 80]);
    // The actual gaps between an exit and the next start respect the delays.
    let mut exit_at = None;
    let mut gaps = Vec::new();
    for e in &h.log {
        match e.kind {
            EventKind::Exited { .. } => exit_at = Some(e.at),
            EventKind::Started { .. } => {
                if let Some(t) = exit_at.take() {
                    gaps.push(e.at - t);
                }
            }
            _ => {}
        }
    }
    assert_eq!(gaps.len(), 5);
    for (gap, want) in gaps.iter().zip(&delays) {
        assert!(gap.as_millis() >= *want, "gap {gap:?} < delay {want} ms");
    }
    println!(
        "crash loop gaps (ms): {:?}",
        gaps.iter()
            .map(|g| g.as_secs_f64() * 1e3)
            .collect::<Vec<_>>()
    );
    assert_eq!(
        h.sup.state("crashy").expect("state"),
        ModuleState::Deactivated
    );
    assert_eq!(h.sup.pid("crashy").expect("pid"), None);
    // Manual revival after deactivation starts a fresh series.
    h.sup.start("crashy").expect("start");
    h.wait("restarted by hand", is_started("crashy"));
    h.wait(
        "first delay of the new series",
        |e| matches!(e.kind, EventKind::Restarting { delay, .. } if delay.is_zero()),
    );
    h.shutdown();
    h.assert_no_leftovers();
}

#[test]
fn spawn_failure_goes_through_the_policy() {
    let mut m = spec("ghost", "/nonexistent/hng-module", &[]);
    m.backoff_initial = Duration::from_millis(1);
    m.give_up_failures = 2;
    let mut h = Harness::start(vec![m]);
    h.wait("deactivated", |e| {
        matches!(e.kind, EventKind::Deactivated { .. })
    });
    let fails = h
        .log
        .iter()
        .filter(|e| matches!(e.kind, EventKind::SpawnFailed { .. }))
        .count();
    assert_eq!(fails, 3);
    let st = &h.sup.status(Instant::now())[0];
    assert!(matches!(st.last_exit, Some(ExitCause::SpawnFailed { .. })));
    h.shutdown();
}

#[test]
fn orderly_shutdown_reverse_order_escalates_and_leaves_nothing() {
    let a = spec("a", "/bin/sleep", &["1000"]);
    // Forks two grandchildren into its process group.
    let b = sh("b", "sleep 1000 & sleep 1000 & wait");
    // Ignores SIGTERM (inherited by the exec'd sleep): needs SIGKILL.
    let mut c = sh("c", "trap '' TERM; exec sleep 1000");
    c.stop_timeout = Duration::from_millis(200);
    let mut h = Harness::start(vec![a, b, c]);
    for name in ["a", "b", "c"] {
        h.wait("start", move |e| {
            e.module == name && matches!(e.kind, EventKind::Started { .. })
        });
    }
    let pid_b = h.sup.pid("b").expect("pid").expect("b running");
    let pid_c = h.sup.pid("c").expect("pid").expect("c running");
    wait_until("b's grandchildren", || alive_in_group(pid_b).len() == 3);
    wait_until("c to ignore SIGTERM", || ignores_sigterm(pid_c));

    h.shutdown();
    let order: Vec<&str> = h
        .log
        .iter()
        .filter(|e| matches!(e.kind, EventKind::StopRequested { .. }))
        .map(module_of)
        .collect();
    assert_eq!(order, ["c", "b", "a"], "reverse start order");
    let escalated: Vec<&str> = h
        .log
        .iter()
        .filter(|e| matches!(e.kind, EventKind::StopTimedOut { .. }))
        .map(module_of)
        .collect();
    assert_eq!(escalated, ["c"]);
    let causes: Vec<(String, ExitCause)> = h
        .log
        .iter()
        .filter(|e| matches!(e.kind, EventKind::Exited { .. }))
        .map(|e| (e.module.clone(), exit_cause(e)))
        .collect();
    assert_eq!(causes[0], ("c".into(), ExitCause::StopTimeout));
    for (name, cause) in &causes[1..] {
        assert!(
            matches!(cause, ExitCause::Signaled { signal, .. } if signal == "SIGTERM"),
            "{name}: {cause}"
        );
    }
    assert!(h.sup.is_shut_down());
    for st in h.sup.status(Instant::now()) {
        assert_eq!(st.state, ModuleState::Stopped, "{}", st.name);
        assert_eq!(st.pid, None);
    }
    h.assert_no_leftovers();
}

#[derive(Default)]
struct Recorder {
    before_restart: Vec<(String, u32)>,
    spawns: u32,
    oom: bool,
}

impl SupervisorHooks for Recorder {
    fn before_spawn(
        &mut self,
        _m: &ModuleSpec,
        cmd: &mut std::process::Command,
    ) -> std::io::Result<()> {
        self.spawns += 1;
        cmd.env("HOOK_SPAWNS", self.spawns.to_string());
        Ok(())
    }
    fn before_restart(&mut self, m: &ModuleSpec, dead_pid: u32) {
        // The dead process has been reaped: its pid is gone.
        assert!(
            !alive(dead_pid),
            "before_restart called while {dead_pid} lives"
        );
        self.before_restart.push((m.name.clone(), dead_pid));
    }
    fn oom_killed(&mut self, _m: &ModuleSpec, _pid: u32) -> bool {
        self.oom
    }
}

#[test]
fn maintenance_restart_env_and_hooks() {
    let dir = std::env::temp_dir().join(format!("hng-sup-env-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    let out: PathBuf = dir.join("env.txt");
    let mut m = sh(
        "envy",
        "echo \"$HNG_MODULE_NAME $HNG_PREFIX $HNG_RESTART_COUNT $HOOK_SPAWNS\" > \"$OUT.tmp\" && mv \"$OUT.tmp\" \"$OUT\"; exec sleep 1000",
    );
    m.env.insert("OUT".into(), out.display().to_string());
    let mut opts = SupervisorOptions::default();
    opts.env.insert("HNG_PREFIX".into(), "hng_test_".into());
    let sup = Supervisor::with_hooks(vec![m], opts, Recorder::default()).expect("new");
    let mut h = Harness::start_with(sup);
    let pid1 = started_pid(&h.wait("start", is_started("envy")));
    let read = || std::fs::read_to_string(&out).unwrap_or_default();
    wait_until("env file", || !read().is_empty());
    assert_eq!(read().trim(), "envy hng_test_ 0 1");
    std::fs::remove_file(&out).expect("rm");

    h.sup.restart("envy").expect("restart");
    let exit = h.wait("exit", is_exit("envy"));
    assert!(
        matches!(exit_cause(&exit), ExitCause::Signaled { ref signal, .. } if signal == "SIGTERM")
    );
    let pid2 = started_pid(&h.wait("restart", is_started("envy")));
    assert_ne!(pid1, pid2);
    assert_eq!(
        h.sup.hooks_mut().before_restart,
        [("envy".to_owned(), pid1)]
    );
    wait_until("env file after restart", || !read().is_empty());
    assert_eq!(read().trim(), "envy hng_test_ 1 2");

    // A SIGKILL we did not send, with the RM hook saying "OOM".
    h.sup.hooks_mut().oom = true;
    // SAFETY: plain kill(2) of our own child.
    let r = unsafe { libc::kill(pid2 as i32, libc::SIGKILL) };
    assert_eq!(r, 0);
    let exit = h.wait("oom exit", is_exit("envy"));
    assert_eq!(exit_cause(&exit), ExitCause::OomKilled);
    let pid3 = started_pid(&h.wait("restart after oom", is_started("envy")));

    // Over a limit: the caller kills it with a reason.
    h.sup
        .kill_over_limit("envy", "cpu 180% > 50%")
        .expect("kill");
    let exit = h.wait("over-limit exit", is_exit("envy"));
    assert_eq!(
        exit_cause(&exit),
        ExitCause::OverLimit {
            reason: "cpu 180% > 50%".into()
        }
    );
    assert_eq!(h.sup.hooks_mut().before_restart.len(), 2);
    assert_eq!(h.sup.hooks_mut().before_restart[1].1, pid2);
    assert_ne!(pid3, pid2);
    h.shutdown();
    h.assert_no_leftovers();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn stop_one_module_and_status_json() {
    let mut h = Harness::start(vec![
        spec("x", "/bin/sleep", &["1000"]),
        spec("y", "/bin/sleep", &["1000"]),
    ]);
    h.wait("x", is_started("x"));
    h.wait("y", is_started("y"));
    h.sup.stop("x").expect("stop");
    h.wait("x stopped", |e| {
        e.module == "x" && e.kind == EventKind::Stopped
    });
    let status = h.sup.status(Instant::now());
    let json = serde_json::to_value(&status).expect("json");
    assert_eq!(json[0]["name"], "x");
    assert_eq!(json[0]["state"], "stopped");
    assert_eq!(json[0]["last_exit"]["kind"], "signaled");
    assert_eq!(json[0]["last_exit"]["signal"], "SIGTERM");
    assert_eq!(json[1]["state"], "running");
    assert!(json[1]["pid"].as_u64().is_some());
    assert!(json[1]["uptime_ms"].as_f64().is_some());
    let ev = serde_json::to_value(&h.log[0]).expect("json");
    assert_eq!(ev["event"], "started");
    h.shutdown();
    h.assert_no_leftovers();
}

#[test]
fn waker_interrupts_poll() {
    let mut sup = Supervisor::new(vec![], SupervisorOptions::default()).expect("new");
    let waker = sup.waker();
    let t0 = Instant::now();
    let th = std::thread::spawn(move || waker.wake());
    let events = sup.poll(Duration::from_secs(30)).expect("poll");
    assert!(events.is_empty());
    assert!(t0.elapsed() < Duration::from_secs(10));
    th.join().expect("join").expect("wake");
}

/// kill -> detection latency through pidfd + epoll. Prints the numbers; no
/// timing assertion (the machine is shared).
#[test]
fn measure_kill_to_detect_latency() {
    let mut m = spec("victim", "/bin/sleep", &["1000"]);
    m.restart = RestartPolicy::Always;
    m.backoff_initial = Duration::ZERO;
    m.give_up_failures = u32::MAX;
    let mut h = Harness::start(vec![m]);
    let mut lat = Vec::new();
    for _ in 0..100 {
        h.wait("start", is_started("victim"));
        let t0 = Instant::now();
        h.sup.kill("victim", Signal::SIGKILL).expect("kill");
        let e = h.wait("exit", is_exit("victim"));
        lat.push(e.at - t0);
    }
    lat.sort();
    let p = |q: f64| lat[((lat.len() - 1) as f64 * q) as usize].as_secs_f64() * 1e6;
    println!(
        "kill->detect latency over {} kills (pidfd+epoll): p50 {:.0} us, p90 {:.0} us, p99 {:.0} us, max {:.0} us",
        lat.len(),
        p(0.5),
        p(0.9),
        p(0.99),
        p(1.0)
    );
    h.shutdown();
    h.assert_no_leftovers();
}
