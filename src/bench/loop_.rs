//! `hng bench loop`: latency of the control loop across processes.
//!
//! Case `lidar_to_command`: this process publishes a lidar scan; the Security module (its own
//! process, `hng module security`) decides a safe command from it and the desired command of
//! a client; the Robot module (`hng module robot`) obeys Security (its most important client)
//! and forwards the command to its output channel, which this process subscribes to.
//!
//! Measured from just before the scan is published (CLOCK_MONOTONIC, which every process
//! shares):
//! - `lidar_to_command`: to the Robot's time stamp on the command it forwards, which it takes
//!   after receiving and arbitrating the command: the path the issue names (scan published,
//!   Security decision, command received by Robot), two process hops and both modules' work;
//! - `lidar_to_command_roundtrip`: to the receipt of that command back in this process, one
//!   hop more.
//!
//! With `--browsers N` the loop is measured twice: as above, then while N headless Chromium
//! browsers show the operator page, which streams the bench's scans (`browsers.rs`); the
//! second pair of rows has the suffix `_Nbrowsers` and the scan frames each page received.
//!
//! Scans alternate between a wall far ahead (command passed through) and a wall close ahead
//! (command slowed), and every answer is checked to be the one for its scan.

use std::process::Child;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_runtime::clock::monotonic_ns;
use hng_runtime::msg::{LaserScan, Twist};
use hng_runtime::shm;
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};

use super::affinity::CpuList;

/// Arguments of `hng bench loop`.
#[derive(Debug, Clone, Args)]
pub struct LoopArgs {
    /// Loops measured (fewer if --max-seconds runs out first).
    #[arg(long, default_value_t = 10_000)]
    pub samples: usize,
    /// Time limit, seconds.
    #[arg(long, default_value_t = 5.0)]
    pub max_seconds: f64,
    /// Scans per second, as a lidar publishes them; 0 publishes the next scan as soon as the
    /// previous command came back (back to back).
    #[arg(long, default_value_t = 0.0)]
    pub rate: f64,
    /// Wait mode of all three processes: `blocking`, `blocking:<µs spin>` or `spin`.
    #[arg(long, default_value = "blocking")]
    pub wait: String,
    /// Also run the flight recorder (as `hng run --record` does: a thread of this process,
    /// every channel to an MCAP file in the temporary directory); the cases are named
    /// `..._recorded`.
    #[arg(long)]
    pub record: bool,
    /// One JSON object per case.
    #[arg(long)]
    pub json: bool,
    /// Also measure the loop while this many headless Chromium browsers watch the operator
    /// page (served for the bench's channels); the cases get the suffix `_Nbrowsers`. Skipped,
    /// saying why, without chromium, node or playwright-core.
    #[arg(long, default_value_t = 0)]
    pub browsers: usize,
    /// How the browsers are scheduled. On a robot the operator's browsers run on the
    /// operator's machine; here they share the loop's cores. `idle` (SCHED_IDLE) gives them
    /// only what the loop leaves, `low` nice 19, `normal` the loop's priority. The page
    /// server's own view threads run at nice `hng_gui::VIEW_NICE` in every case.
    #[arg(long, value_enum, default_value_t = super::browsers::BrowserPriority::Idle)]
    pub browser_priority: super::browsers::BrowserPriority,
    /// CPUs of the loop: this process (with the page server it runs for the browsers) and the
    /// two modules, in both measurements (a list as `taskset -c` takes it: `0`, `0-1`).
    /// Default: all.
    #[arg(long, value_parser = CpuList::parse)]
    pub loop_cpus: Option<CpuList>,
    /// CPUs of the browsers and their driver, standing for the operator's own machine: with
    /// `--loop-cpus 0 --browser-cpus 1` the browsers' rendering never shares a core with the
    /// loop, and what is left of the page's cost on the loop is the server's. Default: all.
    #[arg(long, value_parser = CpuList::parse)]
    pub browser_cpus: Option<CpuList>,
}

const SCAN: &str = "bench/scan";
const TELEOP: &str = "bench/teleop";
const SECURITY: &str = "bench/security_cmd";
const OUT: &str = "bench/robot_cmd";
const DESIRED_V: f64 = 1.0;

/// A 360-beam scan of a wall perpendicular to the heading at `wall` metres.
fn wall_scan(wall: f64) -> LaserScan {
    let mut s = LaserScan::full_circle(&[f32::INFINITY; 360], 0.05, 10.0);
    s.scan_time = 0.1;
    for (i, r) in s.ranges.iter_mut().take(360).enumerate() {
        let a = -std::f64::consts::PI + i as f64 * std::f64::consts::PI / 180.0;
        *r = if a.cos() > 1e-6 && wall / a.cos() < 10.0 {
            (wall / a.cos()) as f32
        } else {
            f32::INFINITY
        };
    }
    s
}

/// The module processes of the loop; killed and cleaned up on drop.
struct Modules {
    children: Vec<Child>,
    prefix: String,
}

impl Modules {
    fn spawn(&mut self, name: &str, config: &str, wait: &str) -> Result<()> {
        let exe = std::env::current_exe().context("locating the hng executable")?;
        let child = super::quiet_hng(&exe)
            .args(["module", name])
            .env("HNG_PREFIX", &self.prefix)
            .env("HNG_MODULE_NAME", format!("bench-{name}"))
            .env("HNG_MODULE_CONFIG", config)
            .env("HNG_WAIT", wait)
            .env("HNG_CLOCK", "wall")
            .env_remove("HNG_CHECKPOINT_DIR")
            .spawn()
            .with_context(|| format!("starting `hng module {name}`"))?;
        self.children.push(child);
        Ok(())
    }

    fn check_alive(&mut self) -> Result<()> {
        for c in &mut self.children {
            if let Some(status) = c.try_wait()? {
                bail!("a module of the loop exited early: {status}");
            }
        }
        Ok(())
    }
}

impl Drop for Modules {
    fn drop(&mut self) {
        for c in &self.children {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(c.id() as i32),
                nix::sys::signal::Signal::SIGTERM,
            );
        }
        for c in &mut self.children {
            let deadline = Instant::now() + Duration::from_secs(5);
            loop {
                match c.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => {
                        // Waiting for a process to exit: poll its status every millisecond.
                        std::thread::sleep(Duration::from_millis(1));
                    }
                    _ => {
                        let _ = c.kill();
                        let _ = c.wait();
                        break;
                    }
                }
            }
        }
        shm::remove_prefix_files(&self.prefix);
    }
}

/// Runs the loop; returns the rows of `lidar_to_command` and `lidar_to_command_roundtrip`.
pub fn lidar_to_command(a: &LoopArgs) -> Result<Vec<BenchRow>> {
    lidar_to_command_watched(a, 0)
}

/// The loop, while `browsers` browsers watch the operator page (0: none).
fn lidar_to_command_watched(a: &LoopArgs, browsers: usize) -> Result<Vec<BenchRow>> {
    let mode = WaitMode::parse(&a.wait).context("--wait")?;
    if let Some(cpus) = &a.loop_cpus {
        // Before anything starts: the modules and the page server's threads inherit it.
        cpus.apply_to_this_thread()?;
    }
    let prefix = shm::unique_prefix("loop");
    let mut modules = Modules {
        children: Vec::new(),
        prefix: prefix.clone(),
    };
    let node = Node::new(NodeOptions::new("bench-loop").prefix(&prefix))?;
    let scan_pub = node.publisher::<LaserScan>(SCAN)?;
    let teleop = node.publisher::<Twist>(TELEOP)?;
    let out = node.subscriber::<Twist>(OUT)?;
    // This process takes part like a module: it shares the CPUs with the two modules.
    let mut waiter = Waiter::new(mode)?;
    waiter.share_cpus(&node)?;
    waiter.attach(&out)?;

    // Freshness and timeouts far beyond the run: the loop is measured, not the fail-safes.
    let forever = 1.0e6;
    modules.spawn(
        "security",
        &format!(
            "scan = \"{SCAN}\"\ncmd_out = \"{SECURITY}\"\nfreshness_s = {forever}\n\
             scan_timeout_s = {forever}\ncmd_in = \"{TELEOP}\"\n"
        ),
        &a.wait,
    )?;
    modules.spawn(
        "robot",
        &format!(
            "cmd_out = \"{OUT}\"\nodom_in = \"bench/odom\"\nodom_out = \"bench/odom_out\"\n\
             odom_timeout_s = {forever}\nfreshness_s = {forever}\n\
             sources = [{{ channel = \"{SECURITY}\", priority = \"1.1\" }}]\n"
        ),
        &a.wait,
    )?;

    let far = wall_scan(5.0);
    let near = wall_scan(0.6);
    let desired = Twist {
        linear_x: DESIRED_V,
        ..Default::default()
    };
    // Warm-up: the modules subscribe when they start; repeat until a command comes through
    // the whole loop.
    let start = Instant::now();
    loop {
        modules.check_alive()?;
        if start.elapsed() > Duration::from_secs(20) {
            bail!("no command came through the loop within 20 s");
        }
        teleop.publish(desired)?;
        scan_pub.publish(far)?;
        waiter.wait(Some(Duration::from_millis(20)))?;
        if out.receive()?.is_some() {
            break;
        }
    }
    let record_file =
        std::env::temp_dir().join(format!("hng-bench-loop-{}.mcap", std::process::id()));
    let mut recorder = if a.record {
        let mut opts = hng_recorder::RecordOptions::new(&prefix);
        opts.output = Some(record_file.clone());
        let r = hng_recorder::RecorderThread::spawn(opts)?;
        let t0 = Instant::now();
        while ![SCAN, OUT].iter().all(|c| r.progress().has(c)) {
            if t0.elapsed() > Duration::from_secs(10) {
                bail!("the recorder did not subscribe to {SCAN} and {OUT} within 10 s");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Some(r)
    } else {
        None
    };
    let watchers = if browsers > 0 {
        Some(super::browsers::Watchers::start(
            &prefix,
            SCAN,
            browsers,
            a.browser_priority,
            a.browser_cpus.as_ref().map(CpuList::set),
        )?)
    } else {
        None
    };
    // Let the start-up traffic settle, then drain it.
    let settle = Instant::now();
    while settle.elapsed() < Duration::from_millis(200) {
        waiter.wait(Some(Duration::from_millis(20)))?;
        while out.receive()?.is_some() {}
    }

    let mut to_robot = Vec::with_capacity(a.samples);
    let mut samples = Vec::with_capacity(a.samples);
    let limit = Duration::from_secs_f64(a.max_seconds.max(0.1));
    let begin = Instant::now();
    let mut limited = 0u64;
    let period = (a.rate > 0.0).then(|| Duration::from_secs_f64(1.0 / a.rate));
    let mut next_scan = Instant::now();
    for i in 0..a.samples {
        if begin.elapsed() > limit {
            break;
        }
        if let Some(p) = period {
            // A periodic sensor: the next scan leaves at its time, whatever the loop did.
            next_scan += p;
            let now = Instant::now();
            if next_scan > now {
                std::thread::sleep(next_scan - now);
            } else {
                next_scan = now;
            }
        }
        let is_near = i % 2 == 1;
        let scan = if is_near { &near } else { &far };
        let t0_ns = monotonic_ns();
        scan_pub.publish(*scan)?;
        let Some(cmd) = out.receive_timeout(&mut waiter, Duration::from_secs(5))? else {
            modules.check_alive()?;
            bail!("no command for scan {i} within 5 s");
        };
        let cmd = *cmd;
        let back_ns = monotonic_ns();
        let slowed = cmd.linear_x < DESIRED_V - 1e-9;
        if slowed != is_near {
            bail!(
                "loop {i}: command {} m/s does not answer a {} wall",
                cmd.linear_x,
                if is_near { "near" } else { "far" }
            );
        }
        let stamp = cmd.header.stamp_ns;
        if stamp < t0_ns || stamp > back_ns {
            bail!("loop {i}: the Robot's stamp {stamp} ns lies outside [{t0_ns}, {back_ns}] ns");
        }
        limited += u64::from(slowed);
        to_robot.push(stamp - t0_ns);
        samples.push(back_ns - t0_ns);
    }
    let recorded = match recorder.as_mut() {
        Some(r) => {
            let summary = r.finish()?;
            let _ = std::fs::remove_file(&record_file);
            Some(summary)
        }
        None => None,
    };
    let frames = match watchers {
        Some(w) => w.finish()?,
        None => Vec::new(),
    };
    let mut suffix = String::new();
    if browsers > 0 {
        suffix.push_str(&format!("_{browsers}browsers"));
    }
    if a.record {
        suffix.push_str("_recorded");
    }
    let row = |case: &str, samples: &mut Vec<u64>, hops: u64| {
        let mean_ns = samples.iter().sum::<u64>() / (samples.len() as u64).max(1);
        let mut r = BenchRow::new("loop", &format!("{case}{suffix}"), Percentiles::of(samples));
        if let Some(s) = &recorded {
            let by_channel: serde_json::Map<String, serde_json::Value> = s
                .channels
                .iter()
                .filter(|c| c.dropped > 0)
                .map(|c| (c.channel.clone(), c.dropped.into()))
                .collect();
            r = r
                .with("recorded_messages", s.messages)
                .with("recorded_dropped", s.dropped)
                .with(
                    "recorded_dropped_by_channel",
                    serde_json::Value::Object(by_channel),
                );
        }
        r.with("mean_ns", mean_ns)
            .with("wait", a.wait.clone())
            .with("rate_hz", a.rate)
            .with("processes", 3)
            .with("hops", hops)
            .with("limited_commands", limited)
            .with("browsers", browsers as u64)
            .with(
                "browser_priority",
                serde_json::to_value(a.browser_priority).unwrap_or_default(),
            )
            .with("page_scan_frames", serde_json::Value::from(frames.clone()))
            .with(
                "loop_cpus",
                a.loop_cpus.as_ref().map_or("all", CpuList::as_str),
            )
            .with(
                "browser_cpus",
                a.browser_cpus.as_ref().map_or("all", CpuList::as_str),
            )
    };
    Ok(vec![
        row("lidar_to_command", &mut to_robot, 2),
        row("lidar_to_command_roundtrip", &mut samples, 3),
    ])
}

pub fn run(a: &LoopArgs) -> Result<()> {
    let mut rows = lidar_to_command(a)?;
    if a.browsers > 0 {
        match super::browsers::missing() {
            Some(why) => eprintln!("hng bench loop: --browsers skipped: {why}"),
            None => rows.extend(lidar_to_command_watched(a, a.browsers)?),
        }
    }
    super::print_rows(&rows, a.json);
    Ok(())
}
