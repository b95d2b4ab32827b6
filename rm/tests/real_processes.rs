//! Tests with real processes and real cgroups. Each test creates its own cgroup run
//! (`hng/test-<name>-<pid>-<ns>`), and kills, reaps and removes everything it created,
//! also when an assertion fails (drop guards). Tests that need a writable cgroup
//! controller say that they skipped and why (`skip`, visible in the runner and listed by
//! `.ci/run`) and return when there is none.

use std::io::{BufRead, BufReader};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use hng_rm::cgroup::{CgroupRun, CgroupSupport, Controller, ModuleCgroup, unique_run_id};
use hng_rm::limits::{Cap, LimitedResource, ResourceLimits, SoftwareEnforcer};
use hng_rm::sampler::{CpuSource, Liveness, ModuleTarget, Sampler, SamplerConfig};

/// Kills and reaps the child on drop.
struct Proc(Child);

impl Proc {
    fn pid(&self) -> i32 {
        i32::try_from(self.0.id()).expect("pid fits i32")
    }

    /// Blocks until the child printed a line (it says it is ready).
    fn wait_ready(&mut self) -> String {
        let out: &mut ChildStdout = self.0.stdout.as_mut().expect("stdout piped");
        let mut line = String::new();
        BufReader::new(out)
            .read_line(&mut line)
            .expect("read ready line");
        line
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Spawns `cmd` placed in `cg` from the pre-exec hook.
fn spawn_in(cg: Option<&ModuleCgroup>, cmd: &mut Command) -> Proc {
    if let Some(cg) = cg {
        let placement = cg.placement().expect("open cgroup.procs");
        // SAFETY: place_self only calls getpid and write (async-signal-safe).
        unsafe {
            cmd.pre_exec(move || placement.place_self());
        }
    }
    Proc(cmd.stdout(Stdio::piped()).spawn().expect("spawn"))
}

/// A cgroup run of the test's own (`hng/SYSTEM-<pid>-<ns>`) with the cgroup of `module` in
/// it.
fn module_cgroup(support: &CgroupSupport, system: &str, module: &str) -> (CgroupRun, ModuleCgroup) {
    let run = CgroupRun::create(support, system, &unique_run_id()).expect("run");
    let cg = run.module(module).expect("module cgroup");
    (run, cg)
}

/// Removes the module's cgroup, then its run.
fn remove(run: CgroupRun, cg: ModuleCgroup) {
    cg.remove().expect("remove module cgroup");
    run.remove().expect("remove run");
}

fn support_with(controllers: &[Controller]) -> Option<CgroupSupport> {
    let s = CgroupSupport::detect();
    let missing: Vec<&str> = controllers
        .iter()
        .filter(|c| !s.has(**c))
        .map(|c| c.name())
        .collect();
    if missing.is_empty() {
        Some(s)
    } else {
        skip(&format!(
            "no writable cgroup controller {missing:?} ({})",
            s.describe()
        ));
        None
    }
}

fn python3() -> Option<&'static str> {
    let ok = Command::new("python3")
        .arg("-c")
        .arg("pass")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if ok {
        Some("python3")
    } else {
        skip("python3 not available");
        None
    }
}

/// Says that a test (or part of one) skipped and why, where cargo's runner cannot hide it:
/// straight to stderr and into the workspace's `target/skipped-tests.txt` (`.ci/run` prints it).
fn skip(why: &str) {
    use std::io::Write as _;
    let line = format!("SKIPPED hng-rm real_processes: {why}\n");
    let _ = std::io::stderr().write_all(line.as_bytes());
    let list = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/skipped-tests.txt");
    if let Ok(mut file) = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(list)
    {
        let _ = file.write_all(line.as_bytes());
    }
}

/// Measures the CPU % of one target over `wall` of wall time.
fn measure(sampler: &mut Sampler, name: &str, wall: Duration) -> (f64, CpuSource) {
    sampler.sample(Instant::now());
    std::thread::sleep(wall);
    sampler.sample(Instant::now());
    let s = sampler.get(name).expect("sampled");
    assert_eq!(s.liveness, Liveness::Alive, "{s:?}");
    (
        s.cpu_percent.expect("two samples give a CPU %"),
        s.cpu_source,
    )
}

/// (a) A CPU hog with a 20% quota measures between 15 and 25% over a few seconds.
#[test]
fn cpu_hog_with_20_percent_quota_measures_15_to_25() {
    let Some(support) = support_with(&[Controller::Cpu]) else {
        return;
    };
    let (run, cg) = module_cgroup(&support, "test-cpuquota", "hog");
    let applied = cg.apply_limits(&ResourceLimits {
        cpu_percent: Some(20.0),
        ..Default::default()
    });
    assert_eq!(applied.cpu, Cap::Kernel, "{applied:?}");
    let mut hog = spawn_in(
        Some(&cg),
        Command::new("sh").args(["-c", "echo ready; while :; do :; done"]),
    );
    hog.wait_ready();
    assert!(cg.pids().expect("pids").contains(&hog.pid()));

    let mut sampler = Sampler::new(SamplerConfig::default()).expect("sampler");
    sampler
        .add(ModuleTarget::new("hog", hog.pid()).with_cgroup_cpu(cg.cpu_counter()))
        .expect("add");
    let (cpu, source) = measure(&mut sampler, "hog", Duration::from_secs(3));
    println!("20% quota: measured {cpu:.1}% ({source:?})");
    assert!((15.0..=25.0).contains(&cpu), "measured {cpu:.1}%");
    if support.has(Controller::Cpuacct) {
        assert_eq!(source, CpuSource::Cgroup);
    }

    cg.kill_all().expect("kill group");
    let status = hog.0.wait().expect("wait hog");
    assert_eq!(status.signal(), Some(libc::SIGKILL));
    // stat is read every `cgroup_stat_every` passes for a cgroup module: the exit shows
    // within that many passes.
    let every = sampler.config().cgroup_stat_every;
    let exited_after = (1..=every).find(|_| {
        sampler.sample(Instant::now());
        sampler
            .get("hog")
            .is_some_and(|s| s.liveness == Liveness::Exited)
    });
    assert!(
        exited_after.is_some(),
        "exit not seen within {every} passes"
    );
    remove(run, cg);
}

/// Burns `FRACTION` of one core: whenever its CPU time (CLOCK_PROCESS_CPUTIME_ID) is
/// behind `FRACTION` × wall time since start it burns in ~1 ms slices, else it sleeps
/// 5 ms. Catching up keeps the average right even when the machine is busy, as long as
/// the process gets `FRACTION` of a core (the machine this runs on has 2 cores shared
/// by several compilers, hence 30% rather than 50%).
const DUTY_CYCLE: &str = r#"
import sys, time
frac = float(sys.argv[1])
print("ready", flush=True)
w0 = time.monotonic()
c0 = time.process_time()
while True:
    if time.process_time() - c0 >= frac * (time.monotonic() - w0):
        time.sleep(0.005)
    else:
        c = time.process_time()
        while time.process_time() - c < 0.001:
            pass
"#;
const FRACTION: f64 = 0.30;

/// (b) The CPU % of a process burning a known fraction of a core is right within 5
/// points, from /proc/PID/stat and, when available, from its cgroup.
#[test]
fn duty_cycle_is_measured_within_5_points() {
    let Some(py) = python3() else {
        return;
    };
    let support = CgroupSupport::detect();
    let (run, cg) = module_cgroup(&support, "test-duty", "duty");
    let mut p = spawn_in(
        cg.is_real().then_some(&cg),
        Command::new(py).args(["-c", DUTY_CYCLE, &FRACTION.to_string()]),
    );
    p.wait_ready();
    let mut sampler = Sampler::new(SamplerConfig::default()).expect("sampler");
    sampler
        .add(ModuleTarget::new("proc", p.pid()))
        .expect("add proc");
    let counter = cg.cpu_counter();
    let has_cg = counter.is_some();
    if has_cg {
        sampler
            .add(ModuleTarget::new("cg", p.pid()).with_cgroup_cpu(counter))
            .expect("add cgroup");
    } else {
        println!(
            "note: no cgroup CPU counter ({}), /proc only",
            support.describe()
        );
    }
    let (proc_cpu, _) = measure(&mut sampler, "proc", Duration::from_secs(4));
    let want = FRACTION * 100.0;
    println!("{want}% duty cycle: /proc/PID/stat {proc_cpu:.1}%");
    assert!(
        (proc_cpu - want).abs() <= 5.0,
        "measured {proc_cpu:.1}%, want {want}%"
    );
    if has_cg {
        let s = sampler.get("cg").expect("cg sample");
        assert_eq!(s.cpu_source, CpuSource::Cgroup);
        let cg_cpu = s.cpu_percent.expect("cpu from cgroup");
        println!("{want}% duty cycle: cgroup {cg_cpu:.1}%");
        assert!(
            (cg_cpu - want).abs() <= 5.0,
            "measured {cg_cpu:.1}%, want {want}%"
        );
    }
    drop(p);
    remove(run, cg);
}

/// (c) A memory hog over its cgroup memory limit is OOM-killed and the kill is read back.
#[test]
fn memory_hog_over_limit_is_oom_killed_and_read_back() {
    let Some(support) = support_with(&[Controller::Memory]) else {
        return;
    };
    let Some(py) = python3() else {
        return;
    };
    let (run, cg) = module_cgroup(&support, "test-oom", "hog");
    let applied = cg.apply_limits(&ResourceLimits {
        memory_bytes: Some(64 << 20),
        pids: Some(16),
        ..Default::default()
    });
    assert_eq!(applied.memory, Cap::Kernel, "{applied:?}");
    assert_eq!(applied.pids, Cap::Kernel, "{applied:?}");
    assert_eq!(cg.oom_kills().expect("read oom counter"), Some(0));
    // Writes every byte of 256 MiB; exits 0 if it is not killed.
    let mut hog = spawn_in(
        Some(&cg),
        Command::new(py).args(["-c", "b = b'x' * (256 << 20); print(len(b))"]),
    );
    let status = hog.0.wait().expect("wait for the hog");
    assert_eq!(
        status.signal(),
        Some(libc::SIGKILL),
        "hog was not OOM-killed: {status:?}"
    );
    let kills = cg.oom_kills().expect("read oom counter");
    println!("OOM kills read back: {kills:?}");
    assert!(kills.is_some_and(|k| k >= 1), "{kills:?}");
    remove(run, cg);
}

/// Placement from the pre-exec hook puts the child (and what it forks) in the group;
/// `kill_all` kills them all; the cgroups are removed afterwards.
#[test]
fn placement_kill_all_and_teardown() {
    let Some(support) = support_with(&[Controller::Pids]) else {
        return;
    };
    let (run, cg) = module_cgroup(&support, "test-kill", "family");
    let mut sh = spawn_in(
        Some(&cg),
        Command::new("sh").args(["-c", "sleep 100 & sleep 100 & echo ready; wait"]),
    );
    sh.wait_ready();
    let pids = cg.pids().expect("pids");
    assert!(pids.contains(&sh.pid()), "{pids:?}");
    assert_eq!(pids.len(), 3, "sh and two sleeps: {pids:?}");
    // The module cgroup is the one in /proc/PID/cgroup for every placed controller.
    let own = std::fs::read_to_string(format!("/proc/{}/cgroup", sh.pid())).expect("cgroup");
    assert!(own.contains(&format!("{}/family", run.name())), "{own}");

    // Busy: cannot be removed while it holds processes.
    let busy = run.module("family").expect("same cgroup again");
    let err = busy.remove().expect_err("must refuse a populated cgroup");
    assert!(err.to_string().contains("still holds processes"), "{err}");

    cg.kill_all().expect("kill all");
    let status = sh.0.wait().expect("wait sh");
    assert_eq!(status.signal(), Some(libc::SIGKILL));
    // The sleeps were SIGKILLed too; they are not our children, so wait for the group
    // to empty (bounded) before removing it.
    let deadline = Instant::now() + Duration::from_secs(5);
    while !cg.pids().expect("pids").is_empty() {
        assert!(
            Instant::now() < deadline,
            "group not empty: {:?}",
            cg.pids()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let dirs: Vec<_> = cg.dirs().map(std::path::Path::to_path_buf).collect();
    remove(run, cg);
    for d in dirs {
        assert!(!d.exists(), "{} left behind", d.display());
    }
}

/// A cap the kernel cannot take is a software cap with a reason, never a panic.
#[test]
fn refused_cap_falls_back_to_software() {
    let Some(support) = support_with(&[Controller::Cpu]) else {
        return;
    };
    let (run, cg) = module_cgroup(&support, "test-refuse", "tiny");
    let req = ResourceLimits {
        cpu_percent: Some(0.05),
        ..Default::default()
    };
    let applied = cg.apply_limits(&req);
    match &applied.cpu {
        Cap::Software { reason } => assert!(reason.contains("minimum"), "{reason}"),
        other => panic!("expected a software cap, got {other:?}"),
    }
    assert_eq!(applied.software_limits(&req).cpu_percent, Some(0.05));
    // 0.5% is under 1 ms per 100 ms but fits with a longer period.
    let applied = cg.apply_limits(&ResourceLimits {
        cpu_percent: Some(0.5),
        ..Default::default()
    });
    assert_eq!(applied.cpu, Cap::Kernel);
    remove(run, cg);
}

/// Without cgroups: measuring only, and the software check flags a module over its
/// memory limit so the caller can stop it ("over limit").
#[test]
fn software_enforcement_without_cgroups() {
    let Some(py) = python3() else {
        return;
    };
    let support = CgroupSupport::none("forced by the test");
    let (run, cg) = module_cgroup(&support, "test-soft", "hog");
    let req = ResourceLimits {
        memory_bytes: Some(32 << 20),
        ..Default::default()
    };
    let applied = cg.apply_limits(&req);
    assert!(matches!(applied.memory, Cap::Software { .. }));
    let mut enforcer = SoftwareEnforcer::default();
    enforcer.set_limits("hog", applied.software_limits(&req));
    let mut hog = spawn_in(
        None,
        Command::new(py).args([
            "-c",
            "import time\nb = b'x' * (96 << 20)\nprint('ready', flush=True)\ntime.sleep(60)",
        ]),
    );
    hog.wait_ready();
    let mut sampler = Sampler::new(SamplerConfig {
        pss_every: 1,
        ..SamplerConfig::default()
    })
    .expect("sampler");
    sampler
        .add(ModuleTarget::new("hog", hog.pid()))
        .expect("add");
    let samples = sampler.sample(Instant::now());
    let s = &samples[0];
    assert!(s.memory_bytes() > 96 << 20, "{s:?}");
    let v = enforcer.check(s).expect("over its memory limit");
    assert_eq!(v.resource, LimitedResource::Memory);
    println!("{v}");
    drop(hog);
    remove(run, cg);
}

/// The cgroup v2 code paths (placement, `cpu.stat` counter, `cgroup.kill`, teardown) on
/// this process's v2 directory, even without controllers (hybrid machines have an empty
/// v2 hierarchy beside the v1 controllers).
#[test]
fn cgroup_v2_placement_counter_kill_and_teardown() {
    let Some(base) = CgroupSupport::own_v2_dir() else {
        skip("cgroup_v2_placement_counter_kill_and_teardown: no cgroup2 file system mounted");
        return;
    };
    let support = match CgroupSupport::with_v2_base(&base) {
        Ok(s) => s,
        Err(e) => {
            skip(&format!(
                "cgroup_v2_placement_counter_kill_and_teardown: cgroup v2 at {} not usable: {e}",
                base.display()
            ));
            return;
        }
    };
    let (run, cg) = module_cgroup(&support, "test-v2", "busy");
    // Without a cpu controller the cap falls to software, with a reason.
    let applied = cg.apply_limits(&ResourceLimits {
        cpu_percent: Some(20.0),
        ..Default::default()
    });
    if !support.has(Controller::Cpu) {
        assert!(matches!(applied.cpu, Cap::Software { .. }), "{applied:?}");
    }
    let mut p = spawn_in(
        Some(&cg),
        Command::new("sh").args(["-c", "echo ready; while :; do :; done"]),
    );
    p.wait_ready();
    assert_eq!(cg.pids().expect("pids"), vec![p.pid()]);
    let mut sampler = Sampler::new(SamplerConfig::default()).expect("sampler");
    sampler
        .add(ModuleTarget::new("proc", p.pid()))
        .expect("add");
    sampler
        .add(ModuleTarget::new("cg", p.pid()).with_cgroup_cpu(cg.cpu_counter()))
        .expect("add cg");
    let (by_proc, _) = measure(&mut sampler, "proc", Duration::from_secs(2));
    let s = sampler.get("cg").expect("cg sample");
    assert_eq!(s.cpu_source, CpuSource::Cgroup);
    let by_cg = s.cpu_percent.expect("cpu");
    println!("v2: /proc {by_proc:.1}%, cpu.stat {by_cg:.1}%");
    assert!(by_cg > 10.0, "a busy loop measured {by_cg:.1}%");
    assert!(
        (by_proc - by_cg).abs() <= 5.0,
        "/proc {by_proc:.1}% vs cgroup {by_cg:.1}%"
    );

    cg.kill_all().expect("cgroup.kill");
    let status = p.0.wait().expect("wait");
    assert_eq!(status.signal(), Some(libc::SIGKILL));
    remove(run, cg);
}

/// The RM's view of a run another process created: `CgroupRun::open` finds it,
/// `existing_module` never creates a group, `kernel_caps` reads the caps back, and
/// dropping the view removes nothing.
#[test]
fn an_opened_run_reads_caps_back_and_removes_nothing() {
    let Some(support) = support_with(&[Controller::Cpu, Controller::Memory]) else {
        return;
    };
    let (run, cg) = module_cgroup(&support, "test-open", "capped");
    let applied = cg.apply_limits(&ResourceLimits {
        cpu_percent: Some(20.0),
        memory_bytes: Some(64 << 20),
        ..Default::default()
    });
    assert_eq!(applied.cpu, Cap::Kernel);
    assert_eq!(applied.memory, Cap::Kernel);
    {
        let view = CgroupRun::open(&support, run.name()).expect("open the run");
        assert!(
            view.existing_module("absent")
                .expect("valid name")
                .is_none(),
            "a view never creates a module cgroup"
        );
        let m = view
            .existing_module("capped")
            .expect("valid name")
            .expect("the module's cgroup");
        let caps = m.kernel_caps();
        assert_eq!(caps.cpu_percent, Some(20.0));
        assert_eq!(caps.memory_bytes, Some(64 << 20));
        assert!(m.cpu_counter().is_some());
        assert!(CgroupRun::open(&support, "no-such-run-here").is_err());
    }
    // The views are gone; the run and the module's group are still there.
    assert!(cg.dirs().all(std::path::Path::is_dir));
    let uncapped = run.module("free").expect("module cgroup");
    let caps = uncapped.kernel_caps();
    assert_eq!((caps.cpu_percent, caps.memory_bytes), (None, None));
    uncapped.remove().expect("remove");
    remove(run, cg);
}

/// A supervisor killed by SIGKILL removes none of its cgroups; the next run removes them
/// (their creator's pid is dead) and leaves alone a run that still holds a process and the
/// runs of live processes.
#[test]
fn the_cgroups_of_a_dead_supervisor_are_removed_by_the_next_run() {
    let Some(support) = support_with(&[Controller::Pids]) else {
        return;
    };
    // A pid that is no more: a child, reaped.
    let mut gone = Command::new("true").spawn().expect("spawn true");
    gone.wait().expect("reap");
    let dead_id = format!("{}-1", gone.id());
    // Its runs: one that still holds a process (an orphaned module), one empty.
    let busy = CgroupRun::create(&support, "test-stalebusy", &dead_id).expect("busy run");
    let busy_cg = busy.module("m").expect("module cgroup");
    let mut orphan = spawn_in(
        Some(&busy_cg),
        Command::new("sh").args(["-c", "echo ready; while :; do read x; done"]),
    );
    orphan.wait_ready();
    let stale = CgroupRun::create(&support, "test-stale", &dead_id).expect("stale run");
    let stale_cg = stale.module("m").expect("module cgroup");
    // Killed: nothing removed.
    std::mem::forget(stale_cg);
    std::mem::forget(stale);
    std::mem::forget(busy_cg);
    std::mem::forget(busy);
    let stale_name = format!("test-stale-{dead_id}");
    let busy_name = format!("test-stalebusy-{dead_id}");
    assert!(
        CgroupRun::open(&support, &stale_name).is_ok(),
        "left behind"
    );

    let live = CgroupRun::create(&support, "test-live", &unique_run_id()).expect("next run");
    assert!(
        CgroupRun::open(&support, &stale_name).is_err(),
        "the dead supervisor's empty run is removed"
    );
    let busy = CgroupRun::open(&support, &busy_name).expect("a run holding a process stays");
    let busy_cg = busy
        .existing_module("m")
        .expect("name")
        .expect("its module cgroup stays");
    assert_eq!(busy_cg.pids().expect("pids"), vec![orphan.pid()]);
    assert!(
        CgroupRun::open(&support, live.name()).is_ok(),
        "the live run stays"
    );

    busy_cg.kill_all().expect("kill the orphan");
    let _ = orphan.0.wait();
    // The orphan gone, its run is removed by the next run too.
    let next = CgroupRun::create(&support, "test-live2", &unique_run_id()).expect("run");
    assert!(CgroupRun::open(&support, &busy_name).is_err(), "removed");
    next.remove().expect("remove");
    live.remove().expect("remove");
}
