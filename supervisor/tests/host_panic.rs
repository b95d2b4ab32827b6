//! A panic inside the supervisor host (here a companion's) leaves nothing behind: the modules
//! are killed, the prefix's files and its lock are removed, and `supervise` returns the panic
//! as its error.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use hng_runtime::shm;
use hng_supervisor::lock::SystemLock;
use hng_supervisor::{Companion, HostOptions, supervise};
use hng_watchdog::{LaunchPlan, ModuleSpec};

/// Panics at a status check once the module's process runs (or, failing the test, after 10 s
/// without it).
struct Panicking {
    mark: String,
    since: Instant,
}

impl Companion for Panicking {
    fn check(&mut self) {
        if !processes_with(&self.mark).is_empty() {
            panic!("a companion's bug");
        }
        if self.since.elapsed() > Duration::from_secs(10) {
            panic!("the module never ran");
        }
    }
}

/// The pids of the processes whose command line holds `mark`.
fn processes_with(mark: &str) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Some(pid) = entry.file_name().to_str().and_then(|s| s.parse().ok()) else {
            continue;
        };
        let cmdline = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
        if String::from_utf8_lossy(&cmdline).contains(mark) {
            found.push(pid);
        }
    }
    found
}

#[test]
fn a_panic_in_the_host_kills_the_modules_and_removes_the_files_and_the_lock() {
    let prefix = shm::unique_prefix("hostpanic");
    // A duration nobody else uses marks the module's process.
    let mark = format!("3600.{}", std::process::id());
    let plan = LaunchPlan {
        file: PathBuf::from("test"),
        system: "hostpanic".to_owned(),
        modules: vec![ModuleSpec::new("sleeper", "/bin/sleep", &[&mark])],
        sim_clock: false,
        checkpoint_dir: None,
        warnings: Vec::new(),
    };
    let run_dir = std::env::temp_dir().join(format!("hng-test-{prefix}"));
    let opts = HostOptions {
        run_dir: run_dir.clone(),
        status_period: Duration::from_millis(50),
    };
    let lock = SystemLock::acquire(&prefix).expect("lock").lock;
    let (result, outcome) = supervise(
        &prefix,
        &opts,
        plan,
        None,
        lock,
        Box::new(|_plan, _paths| {
            Ok(vec![Box::new(Panicking {
                mark: mark.clone(),
                since: Instant::now(),
            }) as Box<dyn Companion>])
        }),
    );
    let e = result.expect_err("the panic is the run's error");
    assert!(
        e.to_string().contains("panicked (a companion's bug)"),
        "{e}"
    );
    assert!(outcome.is_none());
    // The module ran (the companion panicked only then) and is gone (SIGKILLed and reaped by the supervisor's drop).
    let deadline = Instant::now() + Duration::from_secs(5);
    while !processes_with(&mark).is_empty() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(
        processes_with(&mark),
        Vec::<u32>::new(),
        "the module is gone"
    );
    assert_eq!(
        shm::leftovers(&prefix),
        Vec::<PathBuf>::new(),
        "no file left"
    );
    // The lock is free: a second system may start on the prefix.
    SystemLock::acquire(&prefix)
        .expect("the lock was released")
        .lock
        .release();
    let _ = std::fs::remove_dir_all(&run_dir);
}
