//! `hng bench recovery`: how fast `hng run` notices a dead or hung module and brings it back.
//!
//! The bench starts `hng run` (this executable) under a fresh prefix with one module, the
//! built-in `heartbeat-probe` (a checkpointed counter that publishes its count at once after
//! start, then every 10 ms), and SIGKILLs it `--samples` times, then SIGSTOPs it as many
//! times. All times are measured from the signal, on `CLOCK_MONOTONIC`, which every process
//! shares:
//!
//! - `kill_to_detect`: to the supervisor's `Died` event (its header stamp: the supervisor
//!   reaped the process through its pidfd and published the event);
//! - `kill_to_running`: to the `Started` event of the new process (dead-node clean-up done,
//!   process spawned);
//! - `kill_to_first_message`: to the first count the bench receives from the new process
//!   (it has opened its channels, restored its checkpoint and published);
//! - `hang_to_detect`: SIGSTOP to the `Died` event of the hung process (heartbeat timeout,
//!   SIGKILL, reap), with `heartbeat_period_ms` and `timeout_ms` in the row.

use std::path::PathBuf;
use std::process::Child;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_runtime::clock::monotonic_ns;
use hng_runtime::msg::Goal;
use hng_runtime::shm;
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_runtime::system::{EventKind, ModuleEvent, SUPERVISOR_EVENTS};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, Subscriber};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

/// Arguments of `hng bench recovery`.
#[derive(Debug, Clone, Args)]
pub struct RecoveryArgs {
    /// Kills (and hangs) measured.
    #[arg(long, default_value_t = 100)]
    pub samples: usize,
    /// Heartbeat period of the probe, ms (the hang timeout is 3 periods).
    #[arg(long, default_value_t = 20)]
    pub heartbeat_ms: u64,
    /// One JSON object per case.
    #[arg(long)]
    pub json: bool,
}

const WAIT: Duration = Duration::from_secs(10);

struct Bench {
    // Ports before the node.
    events: Subscriber<ModuleEvent>,
    count: Subscriber<Goal>,
    waiter: Waiter,
    _node: Node,
    child: Child,
    prefix: String,
    dir: PathBuf,
    pid: u32,
}

impl Bench {
    fn start(exe: &std::path::Path, heartbeat_ms: u64) -> Result<Bench> {
        let prefix = shm::unique_prefix("benchrec");
        let dir = std::env::temp_dir().join(format!("{prefix}run"));
        std::fs::create_dir_all(&dir).context("creating the bench's folder")?;
        let file = dir.join("recovery.toml");
        let period_s = heartbeat_ms as f64 / 1000.0;
        std::fs::write(
            &file,
            format!(
                r#"system = "bench-recovery"

[[module]]
name = "probe"
command = ["hng", "module", "heartbeat-probe"]
restart = "always"
backoff_reset_after_s = 0.001     # every kill is a first failure: restart at once
give_up_failures = 1000000
heartbeat_period_s = {period_s}
checkpoint_period_s = 0.01
stop_timeout_s = 2.0
config = {{ output = "bench/probe", period_s = 0.01 }}
"#
            ),
        )
        .context("writing the launch file")?;
        let node = Node::new(NodeOptions::new("bench-recovery").prefix(&prefix))?;
        let events = node.subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)?;
        let count = node.subscriber::<Goal>("bench/probe")?;
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&events)?;
        waiter.attach(&count)?;
        let child = super::quiet_hng(exe)
            .args(["run", "--no-rm", "--no-gui", "--run-dir"])
            .arg(&dir)
            .arg(&file)
            .env("HNG_PREFIX", &prefix)
            .spawn()
            .context("starting hng run")?;
        let mut b = Bench {
            events,
            count,
            waiter,
            _node: node,
            child,
            prefix,
            dir,
            pid: 0,
        };
        b.pid = b.event(EventKind::Started)?.pid;
        Ok(b)
    }

    fn event(&mut self, kind: EventKind) -> Result<ModuleEvent> {
        let deadline = Instant::now() + WAIT;
        loop {
            while let Some(e) = self.events.receive()? {
                if e.kind() == Some(kind) && e.module() == "probe" {
                    return Ok(*e);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!("no {kind:?} event from the supervisor within {WAIT:?}");
            }
            self.waiter.wait(Some(left))?;
        }
    }

    /// Waits for the next count; returns it, its sequence number (1 for the first message of
    /// a process) and when it was received.
    fn message(&mut self) -> Result<(u32, u64, u64)> {
        let deadline = Instant::now() + WAIT;
        loop {
            if let Some(g) = self.count.receive()? {
                return Ok((g.id, g.header.seq, monotonic_ns()));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!("the probe published nothing within {WAIT:?}");
            }
            self.waiter.wait(Some(left))?;
        }
    }

    /// Drops what is queued, then waits for the live process's second message: it has
    /// restored its state and sent its first report (the supervisor's first heartbeat) by then.
    /// Waits until the probe counts steadily (its second message since it started), following
    /// any restart meanwhile: on a loaded machine a heartbeat can come late enough for the
    /// supervisor to kill the probe as hung and restart it, and the next signal must go to the
    /// new process, not to a pid that no longer exists (ESRCH).
    fn settle(&mut self) -> Result<()> {
        while self.count.receive()?.is_some() {}
        self.follow_restarts()?;
        loop {
            while self.message()?.1 < 2 {}
            if !self.follow_restarts()? {
                return Ok(());
            }
        }
    }

    /// Reads the supervisor's events so far; takes the pid of the probe's latest start. True
    /// if it started again.
    fn follow_restarts(&mut self) -> Result<bool> {
        let mut restarted = false;
        while let Some(e) = self.events.receive()? {
            if e.kind() == Some(EventKind::Started) && e.module() == "probe" {
                self.pid = e.pid;
                restarted = true;
            }
        }
        Ok(restarted)
    }

    fn signal(&self, sig: Signal) -> Result<u64> {
        let pid = i32::try_from(self.pid).context("pid")?;
        let t0 = monotonic_ns();
        kill(Pid::from_raw(pid), sig).with_context(|| format!("sending {sig} to the probe"))?;
        Ok(t0)
    }

    /// One SIGKILL: (detect, running, first message) in ns.
    fn kill_once(&mut self) -> Result<(u64, u64, u64, bool)> {
        self.settle()?;
        // The count of the live process (its checkpoint is at most a few counts older).
        let (before, _, _) = self.message()?;
        let t0 = self.signal(Signal::SIGKILL)?;
        let died = self.event(EventKind::Died)?;
        let started = self.event(EventKind::Started)?;
        self.pid = started.pid;
        // Skip what the dead process published: a new publisher starts at sequence 1.
        let (first, at) = loop {
            let (n, seq, at) = self.message()?;
            if seq == 1 {
                break (n, at);
            }
        };
        // Restored: the new process counts on from a checkpoint, not from zero.
        let restored = first > 1 && first + 20 > before;
        Ok((
            died.header.stamp_ns.saturating_sub(t0),
            started.header.stamp_ns.saturating_sub(t0),
            at.saturating_sub(t0),
            restored,
        ))
    }

    fn hang_once(&mut self) -> Result<u64> {
        self.settle()?;
        let t0 = self.signal(Signal::SIGSTOP)?;
        let died = self.event(EventKind::Died)?;
        self.pid = self.event(EventKind::Started)?.pid;
        Ok(died.header.stamp_ns.saturating_sub(t0))
    }

    fn stop(mut self) -> Result<()> {
        let pid = i32::try_from(self.child.id()).context("pid")?;
        let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
        let status = self.child.wait().context("waiting for hng run")?;
        let _ = std::fs::remove_dir_all(&self.dir);
        if !status.success() {
            bail!("hng run ended with {status}");
        }
        Ok(())
    }
}

impl Drop for Bench {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
        shm::remove_prefix_files(&self.prefix);
    }
}

/// Runs the bench; returns its rows.
pub fn measure(exe: &std::path::Path, a: &RecoveryArgs) -> Result<Vec<BenchRow>> {
    let n = a.samples.max(1);
    let mut b = Bench::start(exe, a.heartbeat_ms)?;
    let (mut detect, mut running, mut first) = (Vec::new(), Vec::new(), Vec::new());
    let mut restored = 0u64;
    for _ in 0..n {
        let (d, r, f, ok) = b.kill_once()?;
        detect.push(d);
        running.push(r);
        first.push(f);
        restored += u64::from(ok);
    }
    let mut hang = Vec::new();
    for _ in 0..n {
        hang.push(b.hang_once()?);
    }
    let period_ms = a.heartbeat_ms;
    let row = |case: &str, v: &mut Vec<u64>| BenchRow::new("recovery", case, Percentiles::of(v));
    let rows = vec![
        row("kill_to_detect", &mut detect).with("target_p50_ns", 5_000_000u64),
        row("kill_to_running", &mut running),
        row("kill_to_first_message", &mut first)
            .with("target_p50_ns", 100_000_000u64)
            .with("restored_from_checkpoint", restored),
        row("hang_to_detect", &mut hang)
            .with("heartbeat_period_ms", period_ms)
            .with("timeout_ms", 3 * period_ms)
            .with("target_max_ns", 3 * period_ms * 1_000_000),
    ];
    b.stop()?;
    Ok(rows)
}

/// `hng bench recovery`.
pub fn run(a: &RecoveryArgs) -> Result<()> {
    let exe = std::env::current_exe().context("locating the hng executable")?;
    let rows = measure(&exe, a)?;
    super::print_rows(&rows, a.json);
    Ok(())
}
