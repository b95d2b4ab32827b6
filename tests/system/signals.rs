//! Every way of stopping `hng run` ends in the same orderly stop (modules in reverse start
//! order, every file of the prefix removed), with real processes: SIGTERM, SIGINT and SIGHUP
//! in the middle of the built-in mission, `hng stop`, a SIGKILLed supervisor (its modules go
//! with it, the next start cleans up), one system per prefix, fatal signals on the first
//! delivery, and a module that is not an hng module (a shell script) stopping on SIGTERM.

use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use hng_runtime::shm;
use hng_runtime::system::{EventKind, ModuleEvent, SUPERVISOR_EVENTS};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, Subscriber};
use nix::sys::signal::Signal;
use nix::unistd::Pid;

use crate::common::{heavy, poll_until, wait_until};

const HNG: &str = env!("CARGO_BIN_EXE_hng");
const TESTMOD: &str = env!("CARGO_BIN_EXE_hng-testmod");
/// Generous: a whole robot starting on two loaded cores.
const TIMEOUT: Duration = Duration::from_secs(120);

/// One `hng run` under its own prefix: its stdout lines as they come, its log in a file.
pub struct Run {
    pub prefix: String,
    pub dir: PathBuf,
    child: Option<Child>,
    lines: mpsc::Receiver<String>,
    pub stdout: Vec<String>,
    /// The pid of `hng run`.
    pub pid: u32,
}

impl Run {
    /// `hng run ARGS` with `HNG_PREFIX` set to a new prefix (so `hng run` itself is found by
    /// [`processes_of`]) and a run directory of its own.
    pub fn start(tag: &str, args: &[&str]) -> Run {
        let prefix = shm::unique_prefix(tag);
        Run::start_on(&prefix, args)
    }

    /// Like [`Run::start`] on a given prefix.
    pub fn start_on(prefix: &str, args: &[&str]) -> Run {
        Run::spawn(prefix, args, true)
    }

    /// Like [`Run::start`] with nobody reading its stdout (a closed terminal, `| head -1`
    /// done): the pipe's reading end is closed at once, so its every write fails.
    pub fn start_with_stdout_closed(tag: &str, args: &[&str]) -> Run {
        Run::spawn(&shm::unique_prefix(tag), args, false)
    }

    fn spawn(prefix: &str, args: &[&str], read_stdout: bool) -> Run {
        let dir = test_dir(prefix);
        std::fs::create_dir_all(&dir).expect("test dir");
        let n = std::fs::read_dir(&dir).map_or(0, Iterator::count);
        let log = std::fs::File::create(dir.join(format!("run{n}.log"))).expect("log file");
        // No operator page unless the test asks for one (`--gui ADDR`).
        let page = args.contains(&"--gui");
        let mut child = crate::common::hng_run(prefix, log)
            .args(if page { None } else { Some("--no-gui") })
            .arg("--run-dir")
            .arg(dir.join("run"))
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn hng run");
        let out = child.stdout.take().expect("stdout");
        let lines = if read_stdout {
            crate::common::stdout_lines(out)
        } else {
            drop(out);
            mpsc::channel().1
        };
        Run {
            prefix: prefix.to_owned(),
            pid: child.id(),
            dir,
            child: Some(child),
            lines,
            stdout: Vec::new(),
        }
    }

    /// Every log file of this test's runs, in order.
    pub fn log(&self) -> String {
        run_log(&self.dir)
    }

    /// Waits for a stdout line that satisfies `pred`.
    pub fn wait_line(&mut self, what: &str, pred: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    self.stdout.push(l.clone());
                    if pred(&l) {
                        return l;
                    }
                }
                Err(_) => panic!(
                    "no {what} on hng run's stdout within {TIMEOUT:?}; stdout:\n{}\nlog tail:\n{}",
                    self.stdout.join("\n"),
                    tail(&self.log())
                ),
            }
        }
    }

    /// The exit status if `hng run` has ended (stdout lines read so far are kept).
    pub fn try_wait(&mut self) -> Option<ExitStatus> {
        let status = self.child.as_mut()?.try_wait().expect("try_wait")?;
        self.child = None;
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(5)) {
            self.stdout.push(l);
        }
        Some(status)
    }

    /// Collects stdout lines for up to `d` (the caller's pace); returns at once if stdout
    /// closed.
    pub fn read_for(&mut self, d: Duration) {
        let deadline = Instant::now() + d;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return;
            }
            match self.lines.recv_timeout(left) {
                Ok(l) => self.stdout.push(l),
                Err(mpsc::RecvTimeoutError::Timeout) => return,
                Err(mpsc::RecvTimeoutError::Disconnected) => return,
            }
        }
    }

    pub fn signal(&self, sig: Signal) {
        nix::sys::signal::kill(Pid::from_raw(self.pid as i32), sig).expect("signal hng run");
    }

    /// Waits for `hng run` to end; returns its status (stdout read to the end).
    pub fn wait(&mut self) -> ExitStatus {
        let mut child = self.child.take().expect("running");
        let status = crate::common::wait_exit(&mut child, TIMEOUT).unwrap_or_else(|| {
            panic!(
                "hng run did not end within {TIMEOUT:?}; log tail:\n{}",
                tail(&self.log())
            )
        });
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(5)) {
            self.stdout.push(l);
        }
        status
    }

    /// `hng ARGS` on this run's prefix.
    pub fn hng(&self, args: &[&str]) -> std::process::Output {
        Command::new(HNG)
            .args(args)
            .env("HNG_PREFIX", &self.prefix)
            .env("HNG_LOG", "warn")
            .stdin(Stdio::null())
            .output()
            .expect("run hng")
    }

    /// Stops `hng run` with SIGTERM: it must exit 0 and leave nothing behind
    /// ([`Run::assert_left_nothing`]). Returns the log.
    pub fn stop_ok(&mut self) -> String {
        self.signal(Signal::SIGTERM);
        let status = self.wait();
        let log = self.assert_left_nothing();
        assert_eq!(status.code(), Some(0), "log tail:\n{}", tail(&log));
        log
    }

    /// After `hng run` ended: no process of the prefix, no file of it, and the modules
    /// stopped in the reverse of their start order. Returns the log.
    pub fn assert_left_nothing(&self) -> String {
        let log = self.log();
        // Orphans being reaped by init.
        poll_until(
            Duration::from_secs(20),
            Duration::from_millis(10),
            || processes_of(&self.prefix).is_empty(),
            || {
                format!(
                    "processes left behind: {:?}\nlog tail:\n{}",
                    processes_of(&self.prefix),
                    tail(&log)
                )
            },
        );
        let files = shm::prefix_files(&self.prefix);
        assert!(files.is_empty(), "files left behind: {files:?}");
        log
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        for p in processes_of(&self.prefix) {
            let _ = nix::sys::signal::kill(Pid::from_raw(p), Signal::SIGKILL);
        }
        shm::remove_prefix_files(&self.prefix);
        if std::thread::panicking() || std::env::var_os("HNG_KEEP_TEST_LOGS").is_some() {
            // A failed test keeps its logs (run directory, module logs) for the diagnosis, and
            // so does every test with HNG_KEEP_TEST_LOGS set.
            eprintln!("the run's logs are kept in {}", self.dir.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// The folder of a test's runs on `prefix`: run directory, launch files, logs.
pub fn test_dir(prefix: &str) -> PathBuf {
    std::env::temp_dir().join(format!("hng-sig-{}", prefix.trim_end_matches('_')))
}

/// A new prefix for a test tagged `tag`, and its [`test_dir`], created (a [`Run`] on the
/// prefix removes it).
pub fn prefix_and_dir(tag: &str) -> (String, PathBuf) {
    let prefix = shm::unique_prefix(tag);
    let dir = test_dir(&prefix);
    std::fs::create_dir_all(&dir).expect("test dir");
    (prefix, dir)
}

fn tail(log: &str) -> String {
    let lines: Vec<&str> = log.lines().collect();
    lines[lines.len().saturating_sub(60)..].join("\n")
}

/// Module names in the order of their first start, and in the order they were stopped, from
/// the supervisor's log (`NAME: started, pid ...`, `NAME: stopped`).
pub fn start_and_stop_order(log: &str) -> (Vec<String>, Vec<String>) {
    let name_before = |line: &str, marker: &str| -> Option<String> {
        let i = line.find(marker)?;
        line[..i].rsplit(' ').next().map(str::to_owned)
    };
    let mut started = Vec::new();
    let mut stopped = Vec::new();
    for line in log.lines() {
        if let Some(n) = name_before(line, ": started, pid ")
            && !started.contains(&n)
        {
            started.push(n);
        } else if line.trim_end().ends_with(": stopped")
            && let Some(n) = name_before(line, ": stopped")
        {
            stopped.push(n);
        }
    }
    (started, stopped)
}

/// Live processes whose environment has `HNG_PREFIX=<prefix>`: `hng run` and its modules.
pub fn processes_of(prefix: &str) -> Vec<i32> {
    let needle = format!("HNG_PREFIX={prefix}\0");
    let me = std::process::id() as i32;
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return out;
    };
    for e in entries.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<i32>().ok()) else {
            continue;
        };
        if pid == me || !is_alive(pid) {
            continue;
        }
        if let Ok(env) = std::fs::read(e.path().join("environ"))
            && env
                .split_inclusive(|&b| b == 0)
                .any(|kv| kv == needle.as_bytes())
        {
            out.push(pid);
        }
    }
    out
}

/// Alive and not a zombie.
pub fn is_alive(pid: i32) -> bool {
    std::fs::read(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|stat| hng_rm::sampler::parse_stat(&stat))
        .is_some_and(|stat| stat.state != b'Z')
}

/// A `/proc/PID/status` field (e.g. `SigBlk`), as hex.
fn status_mask(pid: u32, field: &str) -> Option<u64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("{field}:")))
        .and_then(|v| u64::from_str_radix(v.trim(), 16).ok())
}

/// The built-in mission, stopped by `sig` once it runs (its first progress line: the robot
/// is being driven), ends in the orderly stop.
fn mission_stopped_by(tag: &str, sig: Signal) {
    let _heavy = heavy();
    let mut run = Run::start(tag, &["--speed", "5"]);
    run.wait_line("a progress line", |l| l.starts_with('['));
    stopped_in_order(&mut run, sig);
    assert!(
        run.stdout.iter().any(|l| l.starts_with("mission")),
        "the summary is printed: {}",
        run.stdout.join("\n")
    );
}

/// Sends `sig` to the running `hng run` and checks the orderly stop: exit 1 (the built-in
/// mission stopped before it ended), the signal named in the log, the whole robot stopped in
/// the reverse of its start order, nothing left. Returns the log.
fn stopped_in_order(run: &mut Run, sig: Signal) -> String {
    run.signal(sig);
    let status = run.wait();
    let log = run.assert_left_nothing();
    // Documented (docs/supervision.md): an orderly stop is not a death by signal; the built-in
    // mission exits with its result, 1 when it was stopped before it ended.
    assert_eq!(
        status.code(),
        Some(1),
        "{sig:?}: exit {status:?}; stdout:\n{}\nlog tail:\n{}",
        run.stdout.join("\n"),
        tail(&log)
    );
    assert!(
        log.contains(&format!("signal={}", sig as i32)) && log.contains("stopping the system"),
        "{sig:?} did not start the orderly stop; log tail:\n{}",
        tail(&log)
    );
    let (started, stopped) = start_and_stop_order(&log);
    assert!(started.len() >= 10, "the whole robot started: {started:?}");
    let mut reverse = started.clone();
    reverse.reverse();
    assert_eq!(
        stopped, reverse,
        "{sig:?}: modules stop in the reverse of their start order"
    );
    log
}

#[test]
fn sigterm_mid_mission_stops_in_order_and_leaves_nothing() {
    mission_stopped_by("sigterm", Signal::SIGTERM);
}

#[test]
fn sigint_mid_mission_stops_in_order_and_leaves_nothing() {
    mission_stopped_by("sigint", Signal::SIGINT);
}

/// SIGHUP is what a closed terminal sends, and with the terminal gone nobody reads stdout any
/// more: the run must neither die of its progress lines (a write to a closed pipe) nor leave
/// its files. Its stdout is closed from the start; it is stopped once every module runs.
#[test]
fn sighup_with_its_stdout_closed_stops_in_order_and_leaves_nothing() {
    let _heavy = heavy();
    let mut run = Run::start_with_stdout_closed("sighup", &["--speed", "5"]);
    let deadline = Instant::now() + TIMEOUT;
    loop {
        let log = run.log();
        let (started, _) = start_and_stop_order(&log);
        let running = log.matches("running (first heartbeat)").count();
        if started.len() >= 10 && running >= started.len() {
            break;
        }
        assert!(
            run.try_wait().is_none(),
            "hng run ended with its stdout closed; log tail:\n{}",
            tail(&log)
        );
        assert!(
            Instant::now() < deadline,
            "not up; log tail:\n{}",
            tail(&log)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let log = stopped_in_order(&mut run, Signal::SIGHUP);
    assert!(
        log.contains("stdout is closed"),
        "the dropped lines are said; log tail:\n{}",
        tail(&log)
    );
}

/// Writes `text` as a launch file in `dir`; returns its path.
pub(crate) fn launch_file(dir: &std::path::Path, text: &str) -> PathBuf {
    std::fs::create_dir_all(dir).expect("dir");
    let f = dir.join("launch.toml");
    std::fs::write(&f, text.replace("TESTMOD", TESTMOD)).expect("launch file");
    f
}

/// Subscribes to the supervisor's events of `prefix` (before anything starts).
pub(crate) struct Events {
    sub: Subscriber<ModuleEvent>,
    waiter: Waiter,
    _node: Node,
}

impl Events {
    pub(crate) fn new(prefix: &str) -> Events {
        let node = Node::new(NodeOptions::new("sig-test").prefix(prefix)).expect("node");
        let sub = node
            .subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)
            .expect("events");
        let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
        waiter.attach(&sub).expect("attach");
        Events {
            sub,
            waiter,
            _node: node,
        }
    }

    /// The next event of `kind` about `module`; the others are skipped.
    pub(crate) fn wait(
        &mut self,
        module: &str,
        kind: EventKind,
        log: &dyn Fn() -> String,
    ) -> ModuleEvent {
        wait_until(
            &mut self.waiter,
            TIMEOUT,
            || {
                std::iter::from_fn(|| self.sub.receive().expect("receive"))
                    .find(|e| e.module() == module && e.kind() == Some(kind))
                    .map(|e| *e)
            },
            || {
                format!(
                    "no {kind:?} event for {module}; log tail:\n{}",
                    tail(&log())
                )
            },
        )
    }
}

#[test]
fn a_shell_script_module_gets_sigterm_with_a_clean_signal_state_and_exits_on_it() {
    let prefix = shm::unique_prefix("sigsh");
    let dir = test_dir(&prefix);
    let marker = dir.join("got-term");
    let script = format!(
        "trap 'echo term > {}; exit 0' TERM; while :; do sleep 0.05; done",
        marker.display()
    );
    let file = launch_file(
        &dir.join("launch"),
        &format!(
            "system = \"shell\"\n[defaults]\nstop_timeout_s = 60.0\n\n\
             [[module]]\nname = \"sleeper\"\ncommand = [\"/bin/sleep\", \"1000\"]\n\n\
             [[module]]\nname = \"script\"\ncommand = [\"/bin/sh\", \"-c\", {script:?}]\n"
        ),
    );
    let mut events = Events::new(&prefix);
    let mut run = Run::start_on(&prefix, &["--no-rm", file.to_str().expect("path")]);
    let log = || run_log(&dir);
    let sleeper = events.wait("sleeper", EventKind::Started, &log);
    let script_started = events.wait("script", EventKind::Started, &log);
    // A module starts like a program started from a shell: nothing blocked, nothing ignored.
    assert_eq!(
        status_mask(sleeper.pid, "SigBlk"),
        Some(0),
        "blocked signals of a module"
    );
    assert_eq!(
        status_mask(sleeper.pid, "SigIgn"),
        Some(0),
        "ignored signals of a module"
    );
    drop(events);
    let out = run.hng(&["stop"]);
    assert!(
        out.status.success(),
        "hng stop: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let status = run.wait();
    let log = run.assert_left_nothing();
    assert_eq!(
        status.code(),
        Some(0),
        "hng stop ends hng run with 0; log:\n{log}"
    );
    assert!(
        marker.exists(),
        "the script's TERM trap ran (pid {}); log:\n{log}",
        script_started.pid
    );
    assert!(
        log.contains(&format!(
            "script: pid {} exited with code 0",
            script_started.pid
        )),
        "the script exited on SIGTERM, not SIGKILLed after its stop timeout; log:\n{log}"
    );
    assert!(
        log.contains(&format!("sleeper: pid {} killed by SIGTERM", sleeper.pid)),
        "sleep died of SIGTERM; log:\n{log}"
    );
    assert!(!log.contains("ignored SIGTERM"), "{log}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The log files written by [`Run`]s in `dir`.
pub(crate) fn run_log(dir: &std::path::Path) -> String {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "log"))
        .collect();
    files.sort();
    let text = files
        .iter()
        .map(|f| std::fs::read_to_string(f).unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n");
    hng_recorder::internal::strip_ansi(&text)
}

#[test]
fn a_sigkilled_supervisor_leaves_no_module_and_the_next_start_cleans_up() {
    let prefix = shm::unique_prefix("sigkill");
    let dir = test_dir(&prefix);
    let file = launch_file(
        &dir.join("launch"),
        "system = \"orphans\"\n\n[[module]]\nname = \"sleeper\"\ncommand = [\"/bin/sleep\", \"1000\"]\n\n\
         [[module]]\nname = \"counter\"\ncommand = [\"TESTMOD\", \"faulty\"]\n[module.config]\nperiod_s = 0.02\n",
    );
    let path = file.to_str().expect("path").to_owned();
    let mut events = Events::new(&prefix);
    let mut run = Run::start_on(&prefix, &["--no-rm", &path]);
    let log = || run_log(&dir);
    let a = events.wait("sleeper", EventKind::Started, &log);
    let b = events.wait("counter", EventKind::Started, &log);
    drop(events);
    run.signal(Signal::SIGKILL);
    let status = run.wait();
    assert_eq!(status.code(), None, "hng run died of SIGKILL");
    // PR_SET_PDEATHSIG: the modules go with their supervisor.
    poll_until(
        Duration::from_secs(20),
        Duration::from_millis(10),
        || !is_alive(a.pid as i32) && !is_alive(b.pid as i32),
        || {
            format!(
                "modules {} and {} outlived their SIGKILLed supervisor",
                a.pid, b.pid
            )
        },
    );
    let stale = shm::prefix_files(&prefix);
    assert!(
        stale
            .iter()
            .any(|p| p.to_string_lossy().ends_with("supervisor.lock")),
        "a SIGKILLed supervisor leaves its (unlocked) lock file: {stale:?}"
    );
    // ... and its iceoryx2 root with its dead nodes' files in it.
    let root = shm::iox_root(&prefix);
    assert!(
        stale
            .iter()
            .any(|p| p.starts_with(root.join("nodes")) && p.is_file()),
        "a dead node's files in the root {}: {stale:?}",
        root.display()
    );
    // A node of another system lives on meanwhile: nothing of it is touched below.
    let other = shm::unique_prefix("sigkillother");
    let other_node = Node::new(NodeOptions::new("other").prefix(&other)).expect("other node");
    let other_pub = other_node
        .publisher::<hng_runtime::msg::Twist>("other/cmd")
        .expect("other publisher");
    let other_sub = other_node
        .subscriber::<hng_runtime::msg::Twist>("other/cmd")
        .expect("other subscriber");
    let other_files = shm::prefix_files(&other);
    // The next start on the prefix removes what the dead system left, runs, and stops clean.
    let mut events = Events::new(&prefix);
    let mut again = Run::start_on(&prefix, &["--no-rm", &path]);
    events.wait("counter", EventKind::Started, &log);
    drop(events);
    let log = again.stop_ok();
    assert!(
        log.contains("ended without an orderly stop"),
        "the second start says it cleaned up; log:\n{log}"
    );
    assert!(!root.exists(), "the stale root {} is gone", root.display());
    assert_eq!(
        shm::prefix_files(&other),
        other_files,
        "the other system's files"
    );
    other_pub
        .publish(hng_runtime::msg::Twist::default())
        .expect("the other system still publishes");
    assert!(other_sub.receive().expect("receive").is_some());
    drop((other_sub, other_pub, other_node));
    shm::remove_prefix_files(&other);
    drop(run);
}

/// The operator page's process (`hng gui --listen-fd`, a child of `hng run`) goes with a
/// SIGKILLed supervisor (parent-death signal) and frees its port; the next start cleans up.
#[test]
fn a_sigkilled_supervisor_takes_its_operator_page_with_it() {
    let prefix = shm::unique_prefix("sigkillpage");
    let dir = test_dir(&prefix);
    let file = launch_file(
        &dir.join("launch"),
        "system = \"page\"\n\n[[module]]\nname = \"sleeper\"\ncommand = [\"/bin/sleep\", \"1000\"]\n",
    );
    let path = file.to_str().expect("path").to_owned();
    let mut events = Events::new(&prefix);
    let mut run = Run::start_on(&prefix, &["--gui", "127.0.0.1:0", "--no-rm", &path]);
    let log = || run_log(&dir);
    let line = run.wait_line("the page's address", |l| {
        l.starts_with("operator page: http://")
    });
    let addr: std::net::SocketAddr = line
        .trim_start_matches("operator page: http://")
        .split('/')
        .next()
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("no address in {line:?}"));
    let sleeper = events.wait("sleeper", EventKind::Started, &log);
    drop(events);
    let page = processes_of(&prefix)
        .into_iter()
        .find(|pid| {
            std::fs::read(format!("/proc/{pid}/cmdline"))
                .is_ok_and(|c| c.split(|b| *b == 0).any(|arg| arg == b"--listen-fd"))
        })
        .unwrap_or_else(|| panic!("no page process among {:?}", processes_of(&prefix)));
    assert!(
        std::net::TcpStream::connect(addr).is_ok(),
        "the page serves on {addr}"
    );
    run.signal(Signal::SIGKILL);
    assert_eq!(run.wait().code(), None, "hng run died of SIGKILL");
    // The kernel's parent-death signal.
    poll_until(
        Duration::from_secs(20),
        Duration::from_millis(10),
        || !is_alive(page) && !is_alive(sleeper.pid as i32),
        || {
            format!(
                "the page ({page}) or the module ({}) outlived the SIGKILLed supervisor",
                sleeper.pid
            )
        },
    );
    assert!(
        std::net::TcpStream::connect(addr).is_err(),
        "nothing listens on {addr} any more"
    );
    // The next start on the prefix removes what the dead system left and stops clean.
    let mut events = Events::new(&prefix);
    let mut again = Run::start_on(&prefix, &["--no-rm", &path]);
    events.wait("sleeper", EventKind::Started, &log);
    drop(events);
    again.stop_ok();
    drop(run);
}

#[test]
fn a_second_run_on_a_live_prefix_is_refused_and_the_first_mission_succeeds() {
    let _heavy = heavy();
    let mut first = Run::start("sigtwo", &["--speed", "10"]);
    first.wait_line("a progress line", |l| l.starts_with('['));
    // Another mission, and a launch file, on the same prefix: both refused before starting.
    let file = launch_file(
        &first.dir.join("launch"),
        "system = \"intruder\"\n\n[[module]]\nname = \"sleeper\"\ncommand = [\"/bin/sleep\", \"1000\"]\n",
    );
    for args in [
        vec!["run", "--no-gui", "--speed", "10"],
        vec!["run", "--no-gui", "--no-rm", file.to_str().expect("path")],
    ] {
        let out = first.hng(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?} refused: {err}");
        assert!(
            err.contains(&first.prefix) && err.contains(&format!("supervisor pid {}", first.pid)),
            "the refusal names the prefix and the running supervisor: {err}"
        );
        assert!(
            String::from_utf8_lossy(&out.stdout).trim().is_empty() || !err.contains("starting"),
            "nothing started"
        );
    }
    let status = first.wait();
    let log = first.assert_left_nothing();
    assert!(
        status.success(),
        "the first mission still succeeds: {status:?}\n{}\nlog tail:\n{}",
        first.stdout.join("\n"),
        tail(&log)
    );
    assert!(
        first.stdout.iter().any(|l| l.contains("mission SUCCEEDED")),
        "{}",
        first.stdout.join("\n")
    );
}

#[test]
fn a_sent_sigsegv_kills_a_module_on_the_first_delivery() {
    let prefix = shm::unique_prefix("sigsegv");
    let dir = test_dir(&prefix);
    // A built-in module (the hng executable) and an SDK module (run_module).
    let file = launch_file(
        &dir.join("launch"),
        "system = \"segv\"\n[defaults]\nheartbeat_period_s = 0.1\nheartbeat_timeout_s = 30.0\n\n\
         [[module]]\nname = \"probe\"\ncommand = [\"hng\", \"module\", \"heartbeat-probe\"]\n\n\
         [[module]]\nname = \"counter\"\ncommand = [\"TESTMOD\", \"faulty\"]\n[module.config]\nperiod_s = 0.02\n",
    );
    let mut events = Events::new(&prefix);
    let mut run = Run::start_on(&prefix, &["--no-rm", file.to_str().expect("path")]);
    let log = || run_log(&dir);
    // Started in file order: both first starts before any fault.
    let firsts = [
        events.wait("probe", EventKind::Started, &log),
        events.wait("counter", EventKind::Started, &log),
    ];
    for (module, first) in ["probe", "counter"].into_iter().zip(firsts) {
        let out = run.hng(&["kill", module, "--signal", "SEGV"]);
        assert!(
            out.status.success(),
            "hng kill: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // One SIGSEGV: the process dies of it (before, the first one was swallowed by the
        // standard library's handler and only a second one killed it) and is restarted.
        let died = events.wait(module, EventKind::Died, &log);
        assert_eq!(
            died.pid, first.pid,
            "{module}: the process that got SIGSEGV died"
        );
        let second = events.wait(module, EventKind::Started, &log);
        assert_ne!(second.pid, first.pid);
    }
    let ps = run.hng(&["ps", "--json"]);
    let doc: serde_json::Value = serde_json::from_slice(&ps.stdout).expect("ps --json");
    for module in ["probe", "counter"] {
        let m = doc["modules"]
            .as_array()
            .and_then(|ms| ms.iter().find(|m| m["name"] == module))
            .cloned()
            .unwrap_or_default();
        assert_eq!(m["restarts"], 1, "{module}: exactly one restart: {m:#}");
        assert_eq!(m["last_exit"]["kind"], "signaled", "{m:#}");
        assert_eq!(m["last_exit"]["signal"], "SIGSEGV", "{m:#}");
    }
    // `hng top` writes JSON when its stdout is not a terminal (here a pipe).
    let top = run.hng(&["top", "--once"]);
    assert!(
        top.status.success(),
        "{}",
        String::from_utf8_lossy(&top.stderr)
    );
    let snap: serde_json::Value =
        serde_json::from_slice(&top.stdout).expect("hng top into a pipe prints JSON");
    assert_eq!(snap["supervisor"]["system"], "segv", "{snap:#}");
    drop(events);
    run.stop_ok();
    assert!(
        run_log(&dir).contains("fatal signal SIGSEGV sent by pid"),
        "the crash handler says what happened"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
