//! One problem of `hng eval nav`: the whole system (`hng run`, every module its own process,
//! lockstep) started at the problem's start, one goal, its summary read back; the CPU time of
//! each module process sampled from /proc while it runs (every 0.2 s, and when the summary
//! appears, which is looked for every 5 ms).
//!
//! `hng run` writes its summary as soon as the mission ends, before it stops its modules
//! (one after the other, about 2 s): the problem is done then, and its run goes on stopping
//! in the background ([`Stopping`]) while the next problem starts, under its own prefix.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result};
use serde::Serialize;
use serde_json::Value;

use super::problems::Problem;

/// How each problem is run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// `hng` executable.
    pub exe: PathBuf,
    /// `--speed` of `hng run`.
    pub speed: String,
    /// Goal tolerance, m.
    pub tolerance_m: f64,
    /// Simulated time allowed: `base + per_m × optimum`, s.
    pub duration_base_s: f64,
    /// Simulated seconds allowed per metre of the optimum.
    pub duration_per_m_s: f64,
    /// Seed of the simulator's noise.
    pub seed: Option<u64>,
    /// Folder of the problems' run directories and outputs.
    pub dir: PathBuf,
    /// Keep each problem's run directory (outputs, logs).
    pub keep: bool,
}

/// What one problem gave.
#[derive(Debug, Clone, Serialize)]
pub struct ProblemResult {
    /// The problem.
    #[serde(flatten)]
    pub problem: Problem,
    /// Goal reached (true pose within tolerance), no collision, in time.
    pub success: bool,
    /// Why not (the mission's failure, the goal's reason).
    pub reason: Option<String>,
    /// Simulated time to the end, s.
    pub time_s: f64,
    /// Wall time of the whole run (start-up and shut-down included), s.
    pub wall_s: f64,
    /// Length of the true path, m.
    pub path_length_m: f64,
    /// `path_length_m / optimum_m` (successful problems).
    pub path_ratio: Option<f64>,
    /// Smallest gap between the robot and an obstacle (world geometry), m.
    pub min_clearance_m: Option<f64>,
    /// Contacts with obstacles.
    pub collisions: u64,
    /// Simulated time the true pose moved less than 5 cm per second while the goal was
    /// pending, s.
    pub stuck_time_s: f64,
    /// Stalls Planning reported (no progress for its stall time).
    pub stalls: u64,
    /// Recovery behaviours Planning started.
    pub recoveries: u64,
    /// True poses the mission monitor lost (an overloaded machine; see `hng run`'s summary).
    pub true_poses_lost: u64,
    /// Distance of the true pose from the goal at the end, m.
    pub true_error_m: Option<f64>,
    /// CPU time of each module process (and `run`, the supervisor), s.
    pub cpu_s: BTreeMap<String, f64>,
}

/// How often the run's summary file and exit are looked for: the problem's wall time ends
/// when the summary is seen, so this bounds what a problem is charged for the look (it was
/// 200 ms, the CPU sampling period: about 0.1 s per problem on average).
pub(super) const SUMMARY_POLL: Duration = Duration::from_millis(5);

/// How often each module process's CPU time is read from /proc (a walk of every process).
pub(super) const CPU_SAMPLE_PERIOD: Duration = Duration::from_millis(200);

/// Clock ticks per second of /proc's CPU times: USER_HZ, 100 on every Linux architecture
/// this runs on (the kernel's ABI constant, whatever its internal HZ).
fn ticks_per_s() -> f64 {
    100.0
}

/// (ppid, utime + stime in ticks) of a process.
fn proc_stat(pid: u32) -> Option<(u32, u64)> {
    let text = std::fs::read(format!("/proc/{pid}/stat")).ok()?;
    let f = hng_rm::sampler::parse_stat(&text)?;
    Some((f.ppid, f.utime + f.stime))
}

/// The module name of an `hng module NAME` process.
fn module_name(pid: u32) -> Option<String> {
    let c = std::fs::read(format!("/proc/{pid}/cmdline")).ok()?;
    let args: Vec<String> = c
        .split(|&b| b == 0)
        .map(|a| String::from_utf8_lossy(a).into_owned())
        .collect();
    let i = args.iter().position(|a| a == "module")?;
    args.get(i + 1).cloned()
}

/// The CPU time of one `hng run` and of its module processes, read from /proc.
pub(super) struct RunCpu {
    pid: u32,
    /// Ticks of each module process seen, by pid (the latest reading of each).
    seen: BTreeMap<u32, (String, u64)>,
    /// Ticks of the run itself.
    own_ticks: u64,
}

impl RunCpu {
    pub(super) fn new(pid: u32) -> Self {
        RunCpu {
            pid,
            seen: BTreeMap::new(),
            own_ticks: 0,
        }
    }

    /// Reads the run's and its children's CPU times again.
    pub(super) fn sample(&mut self) {
        sample_children(self.pid, &mut self.seen);
        if let Some((_, t)) = proc_stat(self.pid) {
            self.own_ticks = self.own_ticks.max(t);
        }
    }

    /// CPU seconds by module so far: the latest reading of every process seen (a restarted
    /// module's processes summed) and the run itself (`run`).
    pub(super) fn seconds(&self) -> BTreeMap<String, f64> {
        let tps = ticks_per_s();
        let mut cpu: BTreeMap<String, f64> = BTreeMap::new();
        for (name, t) in self.seen.values() {
            *cpu.entry(name.clone()).or_default() += *t as f64 / tps;
        }
        cpu.insert("run".into(), self.own_ticks as f64 / tps);
        cpu
    }
}

/// Simulated time allowed for a problem, s.
pub fn duration_s(p: &Problem, o: &RunOptions) -> f64 {
    o.duration_base_s + o.duration_per_m_s * p.optimum_m.unwrap_or(30.0)
}

/// Wall time allowed for a run of `duration_s` of simulated time, s: the run gives up by
/// itself at its duration; this only guards against a system that never ends (0.25x real
/// time or slower), with a minute for start-up.
pub(super) fn wall_limit_s(duration_s: f64) -> f64 {
    60.0 + 4.0 * duration_s
}

/// Starts `cmd` (`hng run`): the child and when it started.
pub(super) fn spawn_run(
    cmd: &mut std::process::Command,
    o: &RunOptions,
) -> Result<(std::process::Child, Instant)> {
    let started = Instant::now();
    let child = cmd
        .spawn()
        .with_context(|| format!("starting {}", o.exe.display()))?;
    Ok((child, started))
}

/// CPU ticks of the children of `parent`, by pid (the latest reading of each).
fn sample_children(parent: u32, seen: &mut BTreeMap<u32, (String, u64)>) {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return;
    };
    for e in dir.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let Some((ppid, ticks)) = proc_stat(pid) else {
            continue;
        };
        if ppid != parent {
            continue;
        }
        match seen.get_mut(&pid) {
            Some(v) => v.1 = v.1.max(ticks),
            None => {
                if let Some(name) = module_name(pid) {
                    seen.insert(pid, (name, ticks));
                }
            }
        }
    }
}

fn f64_of(v: &Value, k: &str) -> Option<f64> {
    v.get(k).and_then(Value::as_f64)
}

/// A problem's `hng run` still stopping after its summary was read: reaped later (its prefix's
/// files removed, its run directory too when the problem needs it no more).
#[derive(Debug)]
pub struct Stopping {
    pub(super) child: std::process::Child,
    pub(super) prefix: String,
    /// The run directory to remove once it has stopped.
    pub(super) remove: Option<PathBuf>,
    pub(super) since: Instant,
}

impl Stopping {
    fn done(&mut self) {
        hng_runtime::shm::remove_prefix_files(&self.prefix);
        if let Some(d) = self.remove.take() {
            let _ = std::fs::remove_dir_all(d);
        }
    }

    /// True (and cleaned up) once it has stopped; SIGKILL if it has not within 30 s.
    pub fn poll(&mut self) -> bool {
        match self.child.try_wait() {
            Ok(Some(_)) | Err(_) => {
                self.done();
                true
            }
            Ok(None) if self.since.elapsed() > Duration::from_secs(30) => {
                tracing::warn!(
                    pid = self.child.id(),
                    "a finished run did not stop in 30 s: killed"
                );
                let _ = self.child.kill();
                let _ = self.child.wait();
                self.done();
                true
            }
            Ok(None) => false,
        }
    }

    /// Waits until it has stopped.
    pub fn wait(mut self) {
        while !self.poll() {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// Sends SIGTERM to `hng run` and waits for its orderly stop (at most 30 s, then SIGKILL).
pub(super) fn stop_child(
    child: &mut std::process::Child,
    sig: i32,
) -> Option<std::process::ExitStatus> {
    tracing::info!(
        signal = sig,
        pid = child.id(),
        "stopping the current problem's run"
    );
    if let Ok(pid) = i32::try_from(child.id()) {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(pid),
            nix::sys::signal::Signal::SIGTERM,
        );
    }
    let asked = Instant::now();
    while asked.elapsed() < Duration::from_secs(30) {
        if let Ok(Some(st)) = child.try_wait() {
            return Some(st);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    child.wait().ok()
}

/// `hng run` of the problems' system on `prefix` in `dir`, headless, from `start` in `world`,
/// at the options' speed, tolerance and seed; its output to `dir`. The caller adds the goal
/// or the episodes. The run gets SIGTERM when this process dies.
pub(super) fn run_command(
    o: &RunOptions,
    prefix: &str,
    dir: &Path,
    world: &Path,
    start: [f64; 3],
) -> Result<Command> {
    let mut cmd = Command::new(&o.exe);
    cmd.env("HNG_LOG", "warn")
        .arg("--prefix")
        .arg(prefix)
        .arg("run")
        .arg("--no-gui")
        .arg("--run-dir")
        .arg(dir.join("run"))
        .arg("--world")
        .arg(world)
        .arg("--start")
        .arg(format!("{},{},{}", start[0], start[1], start[2]))
        .arg("--speed")
        .arg(&o.speed)
        .arg("--tolerance")
        .arg(format!("{}", o.tolerance_m))
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(dir.join("stdout.txt"))?)
        .stderr(std::fs::File::create(dir.join("stderr.txt"))?);
    if let Some(s) = o.seed {
        cmd.arg("--seed").arg(s.to_string());
    }
    // An eval killed outright still stops this run in order (SIGTERM to it when we die).
    super::stop::terminate_with_parent(&mut cmd);
    Ok(cmd)
}

/// Runs one problem: its result, and its run if it is still stopping.
pub fn run(p: &Problem, o: &RunOptions) -> Result<(ProblemResult, Option<Stopping>)> {
    let prefix = hng_runtime::shm::unique_prefix("evalnav");
    let dir = o.dir.join(format!("p{:04}", p.id));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let summary_path = dir.join("summary.json");
    let _ = std::fs::remove_file(&summary_path);
    let duration = duration_s(p, o);
    let mut cmd = run_command(o, &prefix, &dir, &p.world, p.start)?;
    cmd.arg("--goal")
        .arg(format!("{},{}", p.goal[0], p.goal[1]))
        .arg("--duration")
        .arg(format!("{duration}"))
        .arg("--summary")
        .arg(&summary_path);
    let (mut child, started) = spawn_run(&mut cmd, o)?;
    let mut cpu = RunCpu::new(child.id());
    let wall_limit = Duration::from_secs_f64(wall_limit_s(duration));
    // Set when the summary was written before `hng run` ended: it is still stopping.
    let mut finished = false;
    let mut next_sample = started;
    let status = loop {
        if let Some(st) = child.try_wait()? {
            break Some(st);
        }
        let done = summary_path.exists();
        // The CPU figures: every `CPU_SAMPLE_PERIOD`, and once more when the summary is there.
        if done || Instant::now() >= next_sample {
            cpu.sample();
            next_sample = Instant::now() + CPU_SAMPLE_PERIOD;
        }
        if done {
            finished = true;
            break None;
        }
        if let Some(sig) = super::stop::requested() {
            // The eval is asked to stop: this run stops in order too (its modules in
            // reverse order, its prefix files removed), SIGKILL only if it hangs.
            break stop_child(&mut child, sig);
        }
        if started.elapsed() > wall_limit {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(SUMMARY_POLL);
    };
    let wall_s = started.elapsed().as_secs_f64();
    if !finished {
        hng_runtime::shm::remove_prefix_files(&prefix);
    }
    let cpu_s = cpu.seconds();
    let summary: Option<Value> = std::fs::read_to_string(&summary_path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    let stdout = std::fs::read_to_string(dir.join("stdout.txt")).unwrap_or_default();
    let result = match summary {
        Some(s) => from_summary(p, &s, &stdout, wall_s, cpu_s),
        None => {
            let why = match status {
                None => format!("no end after {:.0} s of wall time: killed", wall_s),
                Some(st) => format!(
                    "hng run ended ({st}) without a summary; stderr: {}",
                    last_lines(&dir.join("stderr.txt"), 3)
                ),
            };
            failed(p, why, wall_s, cpu_s)
        }
    };
    let remove = (!o.keep && result.success).then_some(dir);
    if finished {
        let stopping = Stopping {
            child,
            prefix,
            remove,
            since: Instant::now(),
        };
        return Ok((result, Some(stopping)));
    }
    if let Some(d) = remove {
        let _ = std::fs::remove_dir_all(d);
    }
    Ok((result, None))
}

/// A problem that gave no figures, with the reason.
pub(super) fn failed(
    p: &Problem,
    why: String,
    wall_s: f64,
    cpu_s: BTreeMap<String, f64>,
) -> ProblemResult {
    ProblemResult {
        problem: p.clone(),
        success: false,
        reason: Some(why),
        time_s: 0.0,
        wall_s,
        path_length_m: 0.0,
        path_ratio: None,
        min_clearance_m: None,
        collisions: 0,
        stuck_time_s: 0.0,
        stalls: 0,
        recoveries: 0,
        true_poses_lost: 0,
        true_error_m: None,
        cpu_s,
    }
}

pub(super) fn last_lines(path: &Path, n: usize) -> String {
    let t = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = t.lines().collect();
    lines[lines.len().saturating_sub(n)..].join(" | ")
}

pub(super) fn from_summary(
    p: &Problem,
    s: &Value,
    stdout: &str,
    wall_s: f64,
    cpu_s: BTreeMap<String, f64>,
) -> ProblemResult {
    let success = s.get("success").and_then(Value::as_bool).unwrap_or(false);
    let goal = s
        .get("goals")
        .and_then(Value::as_array)
        .and_then(|g| g.first());
    let failure_line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("mission failed: "))
        .map(str::to_owned);
    let reason = if success {
        None
    } else {
        s.get("failure")
            .and_then(Value::as_str)
            .map(str::to_owned)
            .or(failure_line)
            .or_else(|| {
                goal.and_then(|g| g.get("reason"))
                    .and_then(Value::as_str)
                    .map(str::to_owned)
            })
            .or_else(|| Some("failed (no reason given)".into()))
    };
    let path_length_m = f64_of(s, "path_length_m").unwrap_or(0.0);
    let count = |k: &str| s.get(k).and_then(Value::as_u64).unwrap_or(0);
    ProblemResult {
        problem: p.clone(),
        success,
        reason,
        time_s: f64_of(s, "sim_time_s").unwrap_or(0.0),
        wall_s,
        path_length_m,
        path_ratio: p
            .optimum_m
            .filter(|o| *o > 0.0 && success)
            .map(|o| path_length_m / o),
        min_clearance_m: f64_of(s, "min_obstacle_distance_m"),
        collisions: count("collisions"),
        stuck_time_s: f64_of(s, "stuck_time_s").unwrap_or(0.0),
        stalls: count("stalls"),
        recoveries: count("recoveries"),
        true_poses_lost: count("true_poses_lost"),
        true_error_m: goal.and_then(|g| f64_of(g, "true_error_m")),
        cpu_s,
    }
}
