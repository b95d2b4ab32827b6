//! Shared helpers: unique prefixes, spawned module processes that never outlive a test.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hng_runtime::shm;

/// Waits (blocking, with a deadline) for the first report of module `name` that satisfies
/// `pred`.
pub fn wait_for_report(
    node: &hng_runtime::Node,
    name: &str,
    timeout: Duration,
    mut pred: impl FnMut(&hng_runtime::msg::ModuleReport) -> bool,
) -> hng_runtime::msg::ModuleReport {
    use hng_runtime::module::REPORT_CHANNEL;
    use hng_runtime::wait::{WaitMode, Waiter};
    let sub = node
        .subscriber::<hng_runtime::msg::ModuleReport>(REPORT_CHANNEL)
        .expect("report subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&sub).expect("attach");
    let deadline = Instant::now() + timeout;
    loop {
        while let Some(r) = sub.receive().expect("receive report") {
            if r.name() == name && pred(&r) {
                return *r;
            }
        }
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(
            !left.is_zero(),
            "no matching report from {name} within {timeout:?}"
        );
        waiter.wait(Some(left)).expect("wait");
    }
}

/// A test's isolated system: its prefix, and the processes it started.
pub struct TestSystem {
    pub prefix: String,
    children: Vec<Child>,
}

impl TestSystem {
    pub fn new(tag: &str) -> TestSystem {
        TestSystem {
            prefix: shm::unique_prefix(tag),
            children: Vec::new(),
        }
    }

    /// Starts the fixture module `role` with `HNG_*` settings for this system.
    pub fn spawn_testmod(&mut self, role: &str, name: &str, config: &str) -> u32 {
        self.spawn_testmod_with(role, name, config, &[])
    }

    /// Like [`TestSystem::spawn_testmod`], with extra environment variables.
    pub fn spawn_testmod_with(
        &mut self,
        role: &str,
        name: &str,
        config: &str,
        env: &[(&str, &str)],
    ) -> u32 {
        let child = Command::new(env!("CARGO_BIN_EXE_hng-testmod"))
            .arg(role)
            .envs(env.iter().copied())
            .env("HNG_PREFIX", &self.prefix)
            .env("HNG_MODULE_NAME", name)
            .env("HNG_MODULE_CONFIG", config)
            .env("HNG_LOG", "warn")
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn hng-testmod");
        let pid = child.id();
        self.children.push(child);
        pid
    }

    /// Starts `cmd` with this system's prefix; it is stopped with the system.
    pub fn spawn(&mut self, cmd: &mut Command) -> u32 {
        let child = cmd
            .env("HNG_PREFIX", &self.prefix)
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn");
        let pid = child.id();
        self.children.push(child);
        pid
    }

    /// Sends SIGTERM to every child and waits for each; returns their exit statuses.
    pub fn stop_all(&mut self) -> Vec<std::process::ExitStatus> {
        let mut out = Vec::new();
        for mut c in self.children.drain(..) {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(c.id() as i32),
                nix::sys::signal::Signal::SIGTERM,
            );
            let deadline = Instant::now() + Duration::from_secs(10);
            let status = loop {
                match c.try_wait() {
                    Ok(Some(s)) => break s,
                    Ok(None) if Instant::now() < deadline => {
                        // Waiting for a process to exit: poll its status at 1 ms intervals.
                        std::thread::sleep(Duration::from_millis(1));
                    }
                    _ => {
                        let _ = c.kill();
                        break c.wait().expect("wait child");
                    }
                }
            };
            out.push(status);
        }
        out
    }
}

impl Drop for TestSystem {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
        shm::remove_prefix_files(&self.prefix);
    }
}

/// Tests that load the machine (a whole robot in accelerated simulation, CPU-share
/// measurements) hold this lock, so that they never run beside each other on a small machine:
/// what they measure is then the system under test, not the neighbouring test.
pub fn heavy() -> std::sync::MutexGuard<'static, ()> {
    static HEAVY: std::sync::Mutex<()> = std::sync::Mutex::new(());
    HEAVY
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Says that `test` skipped because `why` (a client it needs is missing), where the runner's
/// summary cannot hide it: straight to the process's stderr (cargo's test harness captures
/// only `eprintln!`), and as a line in `target/skipped-tests.txt`, which `.ci/run` prints
/// after the tests. A skip is never silent.
pub fn skip(test: &str, why: &str) {
    use std::io::Write as _;
    let line = format!("SKIPPED {test}: {why}\n");
    let _ = std::io::stderr().write_all(line.as_bytes());
    let list = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/skipped-tests.txt");
    if let Ok(mut file) = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&list)
    {
        let _ = file.write_all(line.as_bytes());
    }
}
