//! The flight recorder's commands (the work is in the `hng-recorder` crate, see
//! docs/recording.md):
//!
//! - `hng record [CHANNEL...|--all] -o FILE.mcap`: record a running system.
//! - `hng info FILE.mcap [--json]`: channels, schemas, counts, rates, duration, drops.
//! - `hng replay FILE.mcap [--channels ...] [--speed S|max] [--loop] [--module M -o OUT]`.
//! - `hng foxglove [ADDR]`: live view of a running system (Foxglove WebSocket).
//! - `hng eval replay A.mcap B.mcap --channel slam/pose`: compare two recordings' poses.
//! - `hng bench record` (in `src/bench/record.rs`): recording throughput.
//!
//! `hng run --record FILE` and `hng run --foxglove [ADDR]` run the same recorder in the
//! supervisor ([`start_for_run`]).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_recorder::live::DEFAULT_ADDR;
use hng_recorder::record::Progress;
use hng_recorder::replay::{ModuleUnderTest, ReplayOptions, Speed};
use hng_recorder::{RecordOptions, RecorderThread};

/// `hng record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Channels to record (names, or prefixes ending in `*`).
    pub channels: Vec<String>,
    /// Record every channel (also those that appear later).
    #[arg(long, conflicts_with = "channels")]
    pub all: bool,
    /// The MCAP file to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Stop after this many seconds (default: until Ctrl-C / SIGTERM).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Also serve the live view (Foxglove WebSocket) on this address.
    #[arg(long, num_args = 0..=1, default_missing_value = DEFAULT_ADDR)]
    pub foxglove: Option<String>,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// The run directory of the system whose module logs (`DIR/logs`) and checkpoints
    /// (`DIR/checkpoints`) are recorded too (default: the prefix's default run directory,
    /// when it exists; `hng run --record` always records its own).
    #[arg(long, value_name = "DIR")]
    pub run_dir: Option<PathBuf>,
}

/// The recorder flags of `hng run`.
#[derive(Debug, Args)]
pub struct RunRecordArgs {
    /// Record every channel to this MCAP file, from the first message (docs/recording.md).
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Serve the live view (Foxglove WebSocket) on ADDR while the system runs.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_ADDR)]
    pub foxglove: Option<String>,
}

/// `hng info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The MCAP file.
    pub file: PathBuf,
    /// One JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `hng replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The MCAP file.
    pub file: PathBuf,
    /// Channels to replay (names, or prefixes ending in `*`; default: all but hng's system
    /// channels, the clock included).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    pub channels: Vec<String>,
    /// Pace: a factor of the recorded pace, or `max`.
    #[arg(long, default_value = "1")]
    pub speed: Speed,
    /// Start again at the end, until Ctrl-C.
    #[arg(long = "loop")]
    pub looped: bool,
    /// Run this built-in module alone against the recording (on a fresh prefix of its own)
    /// and record its outputs to --output.
    #[arg(long)]
    pub module: Option<String>,
    /// The module's configuration (TOML; default: the recorded one).
    #[arg(long, requires = "module")]
    pub config: Option<String>,
    /// Where the module's outputs are recorded.
    #[arg(short, long, requires = "module")]
    pub output: Option<PathBuf>,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `hng foxglove`.
#[derive(Debug, Args)]
pub struct FoxgloveArgs {
    /// Address to serve on.
    #[arg(default_value = DEFAULT_ADDR)]
    pub addr: String,
    /// Channels to show (default: all).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    pub channels: Vec<String>,
    /// Stop after this many seconds (default: until Ctrl-C / SIGTERM).
    #[arg(long)]
    pub duration: Option<f64>,
}

/// `hng eval replay`.
#[derive(Debug, Args)]
pub struct EvalReplayArgs {
    /// The reference recording.
    pub a: PathBuf,
    /// The recording to compare with it.
    pub b: PathBuf,
    /// The channel of poses (PoseWithCovariance or Odometry).
    #[arg(long, default_value = "slam/pose")]
    pub channel: String,
    /// Fail (exit 1) when the 95th percentile of the position difference exceeds this, m.
    #[arg(long)]
    pub tolerance_m: Option<f64>,
    /// One JSON object.
    #[arg(long)]
    pub json: bool,
}

fn seconds(s: Option<f64>) -> Result<Option<Duration>> {
    match s {
        None => Ok(None),
        Some(v) if v.is_finite() && v > 0.0 => Ok(Some(Duration::from_secs_f64(v))),
        Some(v) => bail!("--duration {v}: expected a positive number of seconds"),
    }
}

pub fn record(prefix: &str, args: &RecordArgs) -> Result<()> {
    if !args.all && args.channels.is_empty() {
        bail!("name the channels to record, or --all");
    }
    let mut opts = RecordOptions::new(prefix);
    opts.channels = args.channels.clone();
    opts.output = Some(args.output.clone());
    opts.live = args.foxglove.clone();
    opts.duration = seconds(args.duration)?;
    opts.catch_signals = true;
    let run_dir = args
        .run_dir
        .clone()
        .unwrap_or_else(|| hng_supervisor::default_run_dir(prefix));
    if run_dir.is_dir() {
        opts.internal.logs = Some(hng_supervisor::logs::log_dir(&run_dir));
        opts.internal.checkpoints = Some(run_dir.join("checkpoints"));
    }
    let mut run = BTreeMap::new();
    run.insert("prefix".to_string(), prefix.to_string());
    run.insert("command".to_string(), "hng record".to_string());
    opts.metadata.push(("hng.run".to_string(), run));
    let stop = AtomicBool::new(false);
    let summary = hng_recorder::record(&opts, &stop, &Progress::default())
        .with_context(|| format!("recording to {}", args.output.display()))?;
    show(&summary, args.json)?;
    if let Some(e) = &summary.error {
        bail!("recording stopped early: {e}");
    }
    Ok(())
}

/// Prints `v` as one line of JSON (`--json`) or as text.
fn show<T: serde::Serialize + std::fmt::Display>(v: &T, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(v)?);
    } else {
        print!("{v}");
    }
    Ok(())
}

pub fn foxglove(prefix: &str, args: &FoxgloveArgs) -> Result<()> {
    let mut opts = RecordOptions::new(prefix);
    opts.channels = args.channels.clone();
    opts.live = Some(args.addr.clone());
    opts.duration = seconds(args.duration)?;
    opts.catch_signals = true;
    let stop = AtomicBool::new(false);
    let summary = hng_recorder::record(&opts, &stop, &Progress::default())?;
    println!(
        "live view stopped: {} message(s) on {} channel(s)",
        summary.messages,
        summary.channels.len()
    );
    Ok(())
}

pub fn info(args: &InfoArgs) -> Result<()> {
    let info = hng_recorder::info::info(&args.file)?;
    show(&info, args.json)?;
    if let Some(d) = &info.damage {
        bail!("{d}");
    }
    Ok(())
}

pub fn replay(prefix: &str, args: &ReplayArgs) -> Result<()> {
    let module = match &args.module {
        Some(name) => {
            if !crate::modules::BUILTIN.contains(&name.as_str()) {
                bail!(
                    "--module {name}: not a built-in module ({})",
                    crate::modules::BUILTIN.join(", ")
                );
            }
            let exe = std::env::current_exe().context("locating the hng executable")?;
            Some(ModuleUnderTest {
                name: name.clone(),
                command: vec![
                    exe.to_string_lossy().into_owned(),
                    "module".into(),
                    name.clone(),
                ],
                config: args.config.clone(),
                output: args.output.clone(),
            })
        }
        None => None,
    };
    let opts = ReplayOptions {
        input: args.file.clone(),
        // A module under test runs on a fresh prefix of its own.
        prefix: module.is_none().then(|| prefix.to_string()),
        channels: args.channels.clone(),
        speed: args.speed,
        looped: args.looped,
        module,
    };
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let s2 = std::sync::Arc::clone(&stop);
    // Termination signals go to the signal thread's signalfd only: blocked here, before any
    // thread starts (they inherit the mask; the module under test gets a clean one).
    let mut mask = nix::sys::signal::SigSet::empty();
    for sig in [
        nix::sys::signal::Signal::SIGINT,
        nix::sys::signal::Signal::SIGTERM,
        nix::sys::signal::Signal::SIGHUP,
    ] {
        mask.add(sig);
    }
    mask.thread_block()
        .context("blocking termination signals")?;
    // Ctrl-C / SIGTERM end the replay cleanly (the module under test is stopped, the file
    // closed).
    let _signals = std::thread::Builder::new()
        .name("hng-replay-signals".into())
        .spawn(move || {
            if let Ok(mut w) = hng_runtime::wait::Waiter::new(hng_runtime::wait::WaitMode::SLEEP)
                && w.catch_termination_signals().is_ok()
            {
                while !s2.load(Ordering::Acquire) {
                    if let Ok(hng_runtime::wait::Wake::Signal(_)) =
                        w.wait(Some(Duration::from_millis(200)))
                    {
                        s2.store(true, Ordering::Release);
                    }
                }
            }
        });
    let summary = hng_recorder::replay::replay(&opts, &stop);
    stop.store(true, Ordering::Release);
    let summary = summary?;
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        let n: u64 = summary.published.values().sum();
        println!(
            "replayed {n} message(s) on {} channel(s) in {:.1} s",
            summary.published.len(),
            summary.wall_s
        );
        if let Some(r) = &summary.recorded {
            print!("{r}");
        }
    }
    if let Some(d) = &summary.damage {
        bail!("{d} (the messages before it were replayed)");
    }
    Ok(())
}

pub fn eval_replay(args: &EvalReplayArgs) -> Result<()> {
    let c = hng_recorder::compare::compare(&args.a, &args.b, &args.channel)?;
    show(&c, args.json)?;
    if c.pairs == 0 {
        bail!("no poses to compare on {}", args.channel);
    }
    if let Some(t) = args.tolerance_m
        && (c.p95_position_error_m.is_nan() || c.p95_position_error_m > t)
    {
        bail!(
            "p95 position difference {:.4} m exceeds the tolerance {t} m",
            c.p95_position_error_m
        );
    }
    Ok(())
}

/// The recorder of `hng run --record/--foxglove`, started before the first module so the run
/// is recorded from its first message; the plan's module configurations are kept in the
/// file (metadata `hng.modules`) for `hng replay --module`.
///
/// The modules' log lines (`logs`, the supervisor's per-module log files) and checkpoints
/// (`checkpoints`) are recorded too (docs/recording.md, "internal data").
pub fn start_for_run(
    prefix: &str,
    args: &RunRecordArgs,
    plan: &mut hng_watchdog::LaunchPlan,
    logs: &std::path::Path,
    checkpoints: &std::path::Path,
) -> Result<Option<RecorderThread>> {
    if args.record.is_none() && args.foxglove.is_none() {
        return Ok(None);
    }
    let mut opts = RecordOptions::new(prefix);
    opts.output = args.record.clone();
    opts.internal.logs = Some(logs.to_path_buf());
    opts.internal.checkpoints = Some(checkpoints.to_path_buf());
    opts.live = args.foxglove.clone();
    let mut run = BTreeMap::new();
    run.insert("prefix".to_string(), prefix.to_string());
    run.insert("system".to_string(), plan.system.clone());
    let clock = if plan.sim_clock { "sim" } else { "wall" };
    run.insert("clock".to_string(), clock.to_string());
    opts.metadata.push(("hng.run".to_string(), run));
    let modules = plan
        .modules
        .iter()
        .map(|m| (m.name.clone(), m.config.clone()))
        .collect();
    opts.metadata.push(("hng.modules".to_string(), modules));
    if args.record.is_some() && plan.sim_clock && join_lockstep(plan)? {
        opts.lockstep = Some(hng_recorder::lockstep::PARTICIPANT.to_string());
    }
    let r = RecorderThread::spawn(opts).context("starting the recorder")?;
    Ok(Some(r))
}

/// Adds the recorder to the `lockstep` list of every module that has one (the simulator), so
/// the simulated world waits each round until the recorder has read it: a simulated run is
/// recorded without a drop however busy the machine. Returns whether some module had one.
fn join_lockstep(plan: &mut hng_watchdog::LaunchPlan) -> Result<bool> {
    let mut joined = false;
    for m in plan.modules.iter_mut() {
        let Ok(mut table) = m.config.parse::<toml::Table>() else {
            continue;
        };
        let Some(toml::Value::Array(list)) = table.get_mut("lockstep") else {
            continue;
        };
        if list.is_empty() {
            continue;
        }
        let me = toml::Value::String(hng_recorder::lockstep::PARTICIPANT.to_string());
        if !list.contains(&me) {
            list.push(me);
        }
        m.config = toml::to_string(&table)
            .with_context(|| format!("module {}: writing its configuration", m.name))?;
        joined = true;
    }
    Ok(joined)
}

/// Stops the recorder of `hng run` and prints what it recorded.
pub fn finish_for_run(r: Option<RecorderThread>) {
    if let Some(mut r) = r {
        match r.finish() {
            Ok(s) => print!("{s}"),
            Err(e) => eprintln!("hng: error: recorder: {e}"),
        }
    }
}
