//! `hng bench idle`: what hng costs when nothing happens.
//!
//! - `module_no_input`: one SDK module with no input and no contract (`hng module
//!   contract-probe` with an empty configuration) alone on its prefix.
//! - `default_system_1x`: the built-in mission's whole system (`hng run --speed 1`), every
//!   process of it, while the robot works through its goals in real time.
//!
//! Each process is read from procfs once a second for `--seconds` after a warm-up: CPU time
//! (utime + stime of the process, all threads) and wake-ups (voluntary and involuntary context
//! switches of every thread: each is one time the thread ran after sleeping or being
//! preempted). A row's percentiles (`p50_ns` ...) are the CPU nanoseconds used per one-second
//! window (`samples` = windows); `cpu_percent` and `wakeups_per_s` are the means. Targets
//! (issue #15): an idle module under 10 wake-ups a second and 0.3 % of a core; the whole
//! default system under 10 % of one core.
//!
//! - `default_system_max`: the same mission at `--speed max` (lockstep as fast as the
//!   machine goes, what `hng eval nav` pays per problem), run to its end: `cpu_s` (the whole
//!   process tree's user + system time, from `getrusage(RUSAGE_CHILDREN)` once it has been
//!   reaped, start-up and stop included), `sim_s` (the mission summary's simulated time),
//!   `wall_s`, and `cpu_per_sim_s`, the CPU seconds the system spends per simulated second
//!   (the #21 target of one 30 m problem, about 70 simulated seconds, in under 2 s of wall
//!   time needs well under 0.03 at two cores). Its percentiles are the per-second CPU of
//!   the tree, sampled like the 1x case. One row per process follows
//!   (`default_system_max/NAME`, `cpu_per_sim_s` from its last procfs reading).
//!
//! `default_system_1x` is followed by one row per process of the system,
//! `default_system_1x/NAME` (NAME: the module's `HNG_MODULE_NAME`, else the executable's name
//! and the pid), with its own `cpu_percent`, `wakeups_per_s` and `share_percent` (its part
//! of the whole system's CPU): the SLAM module's CPU share in the default mission (issue
//! #19) is the row `default_system_1x/slam`.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result};
use clap::Args;
use hng_runtime::shm;
use hng_runtime::stats::{BenchRow, Percentiles};

/// Arguments of `hng bench idle`.
#[derive(Debug, Clone, Args)]
pub struct IdleArgs {
    /// Seconds measured per case (after the warm-up).
    #[arg(long, default_value_t = 10)]
    pub seconds: u32,
    /// Seconds before measuring (start-up, first contracts).
    #[arg(long, default_value_t = 3)]
    pub warmup: u32,
    /// Only this case (`module_no_input`, `default_system_1x` or `default_system_max`).
    #[arg(long)]
    pub case: Option<String>,
    /// One JSON object per case instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Targets of issue #15.
pub const TARGET_MODULE_WAKEUPS_PER_S: f64 = 10.0;
/// See [`TARGET_MODULE_WAKEUPS_PER_S`].
pub const TARGET_MODULE_CPU_PERCENT: f64 = 0.3;
/// See [`TARGET_MODULE_WAKEUPS_PER_S`].
pub const TARGET_SYSTEM_CPU_PERCENT: f64 = 10.0;

/// CPU ticks and context switches of one process, summed over its threads.
#[derive(Debug, Clone, Copy, Default)]
struct Usage {
    cpu_ns: u64,
    switches: u64,
}

fn usage(pid: i32) -> Option<Usage> {
    let p = procfs::process::Process::new(pid).ok()?;
    let stat = p.stat().ok()?;
    let tick_ns = 1_000_000_000 / procfs::ticks_per_second().max(1);
    let mut switches = 0;
    for t in p.tasks().ok()?.flatten() {
        if let Ok(s) = t.status() {
            switches +=
                s.voluntary_ctxt_switches.unwrap_or(0) + s.nonvoluntary_ctxt_switches.unwrap_or(0);
        }
    }
    Some(Usage {
        cpu_ns: (stat.utime + stat.stime) * tick_ns,
        switches,
    })
}

/// `root` and every process descended from it.
fn tree(root: i32) -> Vec<i32> {
    let mut parent: BTreeMap<i32, i32> = BTreeMap::new();
    if let Ok(all) = procfs::process::all_processes() {
        for p in all.flatten() {
            if let Ok(s) = p.stat() {
                parent.insert(s.pid, s.ppid);
            }
        }
    }
    let mut out = vec![root];
    let mut i = 0;
    while i < out.len() {
        let pid = out[i];
        out.extend(parent.iter().filter(|(_, pp)| **pp == pid).map(|(c, _)| *c));
        i += 1;
    }
    out
}

/// The summed usage of `root`'s process tree, per pid (a pid that ends between two windows
/// counts from the window where it is seen in both).
fn tree_usage(root: i32) -> BTreeMap<i32, Usage> {
    tree(root)
        .into_iter()
        .filter_map(|p| Some((p, usage(p)?)))
        .collect()
}

/// One process's part of a measurement: per-window CPU ns and switches.
#[derive(Debug, Clone, Default)]
struct ProcessWindows {
    cpu: Vec<u64>,
    wakeups: Vec<u64>,
}

/// A process's name for the per-process rows: its `HNG_MODULE_NAME` (a module), else its
/// executable's name and pid.
fn process_name(pid: i32) -> String {
    let Ok(p) = procfs::process::Process::new(pid) else {
        return format!("pid{pid}");
    };
    if let Ok(env) = p.environ()
        && let Some(n) = env.get(std::ffi::OsStr::new("HNG_MODULE_NAME"))
    {
        return n.to_string_lossy().into_owned();
    }
    let comm = p.stat().map(|s| s.comm).unwrap_or_default();
    format!("{comm}-{pid}")
}

/// Measures `root`'s tree once a second for `seconds`; per-window CPU ns and switches, in
/// all and per pid (a pid's windows count only while it is seen at both ends).
fn measure(root: i32, seconds: u32) -> (Vec<u64>, Vec<u64>, f64) {
    let (cpu, wakeups, wall, _) = measure_per_process(root, seconds);
    (cpu, wakeups, wall)
}

/// [`measure`], also per pid.
fn measure_per_process(
    root: i32,
    seconds: u32,
) -> (Vec<u64>, Vec<u64>, f64, BTreeMap<i32, ProcessWindows>) {
    let mut cpu = Vec::new();
    let mut wakeups = Vec::new();
    let mut per: BTreeMap<i32, ProcessWindows> = BTreeMap::new();
    let mut before = tree_usage(root);
    let start = Instant::now();
    let mut next = start;
    for _ in 0..seconds {
        next += Duration::from_secs(1);
        // The window's length: the measurement's pace, not a synchronisation.
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        let now = tree_usage(root);
        let (mut c, mut w) = (0, 0);
        for (pid, u) in &now {
            if let Some(b) = before.get(pid) {
                let (pc, pw) = (
                    u.cpu_ns.saturating_sub(b.cpu_ns),
                    u.switches.saturating_sub(b.switches),
                );
                c += pc;
                w += pw;
                let e = per.entry(*pid).or_default();
                e.cpu.push(pc);
                e.wakeups.push(pw);
            }
        }
        cpu.push(c);
        wakeups.push(w);
        before = now;
    }
    (cpu, wakeups, start.elapsed().as_secs_f64(), per)
}

/// A child process that is stopped (SIGTERM, then SIGKILL) when dropped.
struct Guard(Child);

impl Drop for Guard {
    fn drop(&mut self) {
        if let Ok(Some(_)) = self.0.try_wait() {
            return; // ended (and reaped) already: its pid may belong to another process now
        }
        let pid = nix::unistd::Pid::from_raw(self.0.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(20);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            // Waiting for the process to exit.
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn row(case: &str, cpu: &mut [u64], wakeups: &[u64], wall_s: f64, processes: usize) -> BenchRow {
    let total_cpu: u64 = cpu.iter().sum();
    let total_wake: u64 = wakeups.iter().sum();
    let cpu_percent = total_cpu as f64 / 1e9 / wall_s * 100.0;
    let wakeups_per_s = total_wake as f64 / wall_s;
    BenchRow::new("idle", case, Percentiles::of(cpu))
        .with("processes", processes as u64)
        .with("seconds", (wall_s * 100.0).round() / 100.0)
        .with("cpu_percent", (cpu_percent * 1000.0).round() / 1000.0)
        .with("wakeups_per_s", (wakeups_per_s * 10.0).round() / 10.0)
}

fn module_no_input(args: &IdleArgs) -> Result<BenchRow> {
    let prefix = shm::unique_prefix("benchidle");
    let exe = std::env::current_exe().context("the hng binary")?;
    let child = Command::new(&exe)
        .args(["module", "contract-probe"])
        .env("HNG_PREFIX", &prefix)
        .env("HNG_MODULE_NAME", "idle")
        .env("HNG_LOG", "warn")
        .stdin(Stdio::null())
        .spawn()
        .context("start hng module contract-probe")?;
    let guard = Guard(child);
    std::thread::sleep(Duration::from_secs(u64::from(args.warmup)));
    let (mut cpu, wake, wall) = measure(guard.0.id() as i32, args.seconds);
    drop(guard);
    shm::remove_prefix_files(&prefix);
    let r = row("module_no_input", &mut cpu, &wake, wall, 1);
    let ok = r
        .get("cpu_percent")
        .and_then(|v| v.as_f64())
        .is_some_and(|c| c < TARGET_MODULE_CPU_PERCENT)
        && r.get("wakeups_per_s")
            .and_then(|v| v.as_f64())
            .is_some_and(|w| w < TARGET_MODULE_WAKEUPS_PER_S);
    Ok(r.with("target_cpu_percent", TARGET_MODULE_CPU_PERCENT)
        .with("target_wakeups_per_s", TARGET_MODULE_WAKEUPS_PER_S)
        .with("meets_target", ok))
}

/// `hng run --no-gui ARGS` of this binary on `prefix`, quiet, its run directory `run_dir`.
fn spawn_run(prefix: &str, run_dir: &std::path::Path, args: &[&str]) -> Result<Guard> {
    let exe = std::env::current_exe().context("the hng binary")?;
    let child = Command::new(&exe)
        .args(["run", "--no-gui"])
        .args(args)
        .env("HNG_PREFIX", prefix)
        .env("HNG_RUN_DIR", run_dir)
        .env_remove("HNG_LOG")
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .with_context(|| format!("start hng run {}", args.join(" ")))?;
    Ok(Guard(child))
}

fn default_system(args: &IdleArgs) -> Result<Vec<BenchRow>> {
    let prefix = shm::unique_prefix("benchidlesys");
    let run_dir: PathBuf = std::env::temp_dir().join(format!("hng-{prefix}bench"));
    let duration = (args.warmup + args.seconds + 30).to_string();
    let guard = spawn_run(
        &prefix,
        &run_dir,
        &["--speed", "1", "--duration", &duration],
    )?;
    std::thread::sleep(Duration::from_secs(u64::from(args.warmup)));
    let processes = tree(guard.0.id() as i32).len();
    let (mut cpu, wake, wall, per) = measure_per_process(guard.0.id() as i32, args.seconds);
    // Named while the processes still run.
    let names: Vec<(String, ProcessWindows)> = per
        .into_iter()
        .map(|(pid, w)| (process_name(pid), w))
        .collect();
    drop(guard);
    shm::remove_prefix_files(&prefix);
    let _ = std::fs::remove_dir_all(&run_dir);
    let total_cpu: u64 = cpu.iter().sum();
    let r = row("default_system_1x", &mut cpu, &wake, wall, processes);
    let ok = r
        .get("cpu_percent")
        .and_then(|v| v.as_f64())
        .is_some_and(|c| c < TARGET_SYSTEM_CPU_PERCENT);
    let mut rows = vec![
        r.with("target_cpu_percent", TARGET_SYSTEM_CPU_PERCENT)
            .with("meets_target", ok),
    ];
    for (name, mut w) in names {
        let own: u64 = w.cpu.iter().sum();
        let share = own as f64 / total_cpu.max(1) as f64 * 100.0;
        rows.push(
            row(
                &format!("default_system_1x/{name}"),
                &mut w.cpu,
                &w.wakeups,
                wall,
                1,
            )
            .with("share_percent", (share * 10.0).round() / 10.0),
        );
    }
    Ok(rows)
}

/// CPU time of the reaped descendants of this process (user + system), ns.
fn children_cpu_ns() -> u64 {
    use nix::sys::resource::{UsageWho, getrusage};
    getrusage(UsageWho::RUSAGE_CHILDREN).map_or(0, |u| {
        let t = |v: nix::sys::time::TimeVal| {
            (v.tv_sec().max(0) as u64) * 1_000_000_000 + (v.tv_usec().max(0) as u64) * 1_000
        };
        t(u.user_time()) + t(u.system_time())
    })
}

/// The built-in mission at `--speed max`, to its end: CPU per simulated second.
fn default_system_max() -> Result<Vec<BenchRow>> {
    let prefix = shm::unique_prefix("benchmaxsys");
    let run_dir: PathBuf = std::env::temp_dir().join(format!("hng-{prefix}bench"));
    let summary = run_dir.join("bench-summary.json");
    std::fs::create_dir_all(&run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    let before = children_cpu_ns();
    let started = Instant::now();
    let summary_arg = summary.to_string_lossy();
    let mut guard = spawn_run(
        &prefix,
        &run_dir,
        &["--speed", "max", "--summary", &summary_arg],
    )?;
    let root = guard.0.id() as i32;
    // Per process: the last reading seen (a process's last fraction of a second is lost,
    // the total below is exact), and per-second CPU of the tree for the percentiles.
    let mut last: BTreeMap<i32, (String, u64)> = BTreeMap::new();
    let mut windows = Vec::new();
    let mut prev_total = 0u64;
    let mut next = Instant::now();
    let deadline = started + Duration::from_secs(600);
    let status = loop {
        if let Some(st) = guard.0.try_wait().context("waiting for hng run")? {
            break st;
        }
        anyhow::ensure!(
            Instant::now() < deadline,
            "hng run --speed max: no end after 600 s"
        );
        for (pid, u) in tree_usage(root) {
            let e = last.entry(pid).or_insert_with(|| (process_name(pid), 0));
            e.1 = e.1.max(u.cpu_ns);
        }
        let total: u64 = last.values().map(|(_, c)| *c).sum();
        if Instant::now() >= next {
            windows.push(total.saturating_sub(prev_total));
            prev_total = total;
            next += Duration::from_secs(1);
        }
        // The sampling pace, not a synchronisation: the loop ends when the child exits.
        std::thread::sleep(Duration::from_millis(100));
    };
    let wall_s = started.elapsed().as_secs_f64();
    let cpu_ns = children_cpu_ns().saturating_sub(before);
    drop(guard);
    let text = std::fs::read_to_string(&summary)
        .with_context(|| format!("the mission summary {}", summary.display()));
    shm::remove_prefix_files(&prefix);
    let _ = std::fs::remove_dir_all(&run_dir);
    let doc: serde_json::Value = serde_json::from_str(&text?).context("the mission summary")?;
    let sim_s = doc
        .get("sim_time_s")
        .and_then(serde_json::Value::as_f64)
        .filter(|s| *s > 0.0)
        .context("the mission summary has no sim_time_s")?;
    let success = doc.get("success").and_then(serde_json::Value::as_bool);
    let per_sim = |ns: u64| (ns as f64 * 1e-9 / sim_s * 10_000.0).round() / 10_000.0;
    if windows.is_empty() {
        windows.push(cpu_ns);
    }
    let mut rows = vec![
        BenchRow::new("idle", "default_system_max", Percentiles::of(&mut windows))
            .with("processes", last.len() as u64)
            .with("exit_ok", status.success())
            .with("mission_success", success.unwrap_or(false))
            .with("cpu_s", (cpu_ns as f64 * 1e-9 * 1000.0).round() / 1000.0)
            .with("sim_s", (sim_s * 100.0).round() / 100.0)
            .with("wall_s", (wall_s * 100.0).round() / 100.0)
            .with("cpu_per_sim_s", per_sim(cpu_ns)),
    ];
    for (name, c) in last.values() {
        let mut one = vec![*c];
        rows.push(
            BenchRow::new(
                "idle",
                &format!("default_system_max/{name}"),
                Percentiles::of(&mut one),
            )
            .with("cpu_s", (*c as f64 * 1e-9 * 1000.0).round() / 1000.0)
            .with("cpu_per_sim_s", per_sim(*c))
            .with(
                "share_percent",
                (*c as f64 / cpu_ns.max(1) as f64 * 1000.0).round() / 10.0,
            ),
        );
    }
    Ok(rows)
}

/// `hng bench idle`.
pub fn run(args: &IdleArgs) -> Result<()> {
    anyhow::ensure!(args.seconds > 0, "--seconds must be at least 1");
    let want = |c: &str| args.case.as_deref().is_none_or(|w| w == c);
    if let Some(c) = &args.case {
        anyhow::ensure!(
            ["module_no_input", "default_system_1x", "default_system_max"].contains(&c.as_str()),
            "unknown case {c:?}: module_no_input, default_system_1x or default_system_max"
        );
    }
    let mut rows = Vec::new();
    if want("module_no_input") {
        rows.push(module_no_input(args)?);
    }
    if want("default_system_1x") {
        rows.extend(default_system(args)?);
    }
    if want("default_system_max") {
        rows.extend(default_system_max()?);
    }
    crate::bench::print_rows(&rows, args.json);
    Ok(())
}
