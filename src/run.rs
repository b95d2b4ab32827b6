//! `hng run [FILE]`: the arguments of `hng run`, the built-in mission's summary, and the
//! call to the supervisor host ([`hng_supervisor::host`]) that starts and supervises the
//! system.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use hng_supervisor::Result;
use hng_supervisor::default_run_dir;
use hng_supervisor::host::{Companion, HostOptions, RunPaths, StartCompanions};
use hng_supervisor::lock::{self, SystemLock};
use hng_supervisor::logs;
use hng_supervisor::mission::{self, Mission, MissionOptions};
use hng_supervisor::monitor::{EpisodeOptions, Monitor, MonitorOptions, Outcome};
use hng_watchdog::{LaunchPlan, LoadOptions, ModuleSpec, launch};

/// Options of `hng run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// The launch file (TOML); without it, the built-in default system.
    pub file: Option<PathBuf>,
    /// Do not add the resource manager (`hng module rm`) when the plan has no module "rm".
    #[arg(long)]
    pub no_rm: bool,
    /// Run directory (checkpoints go to RUN_DIR/checkpoints unless the launch file sets
    /// `checkpoint_dir`). Default: $XDG_RUNTIME_DIR/hng/PREFIX, else /tmp/hng-PREFIX.
    #[arg(long, env = "HNG_RUN_DIR")]
    pub run_dir: Option<PathBuf>,
    /// Period of the status document (`hng ps`), s; it is also sent on every change.
    #[arg(long, default_value_t = 0.5, value_parser = parse_period)]
    pub status_period: f64,
    /// Check the launch file and print the plan as JSON, start nothing.
    #[arg(long)]
    pub check: bool,
    /// Built-in mission: print its launch file (TOML) and start nothing.
    #[arg(long, conflicts_with = "file")]
    pub print_plan: bool,
    /// Built-in mission: the world, a TOML world or a map_server YAML (default: built in).
    #[arg(long, conflicts_with = "file")]
    pub world: Option<PathBuf>,
    /// Built-in mission: start pose X,Y[,THETA] (default: the world's).
    #[arg(long, conflicts_with = "file", value_parser = mission::parse_pose, allow_hyphen_values = true)]
    pub start: Option<hng_simulator::Pose2D>,
    /// Built-in mission: a goal X,Y (repeat for several, in order; default: the default
    /// mission's goals, in the default world only).
    #[arg(long, conflicts_with = "file", value_parser = mission::parse_goal, allow_hyphen_values = true)]
    pub goal: Vec<(f64, f64)>,
    /// Built-in mission: simulation speed, `realtime`, a factor (simulated seconds per wall
    /// second) or `max`.
    #[arg(long, conflicts_with = "file", value_parser = mission::parse_speed,
          default_value = mission::DEFAULT_SPEED)]
    pub speed: String,
    /// Built-in mission: noise seed (overrides the world's).
    #[arg(long, conflicts_with = "file")]
    pub seed: Option<u64>,
    /// Built-in mission: limit of simulated time, s; the mission fails when it is exceeded.
    #[arg(long, conflicts_with = "file", default_value_t = mission::DEFAULT_DURATION_S)]
    pub duration: f64,
    /// Built-in mission: position tolerance of the goals, m (reached when the true pose is
    /// within it).
    #[arg(long, conflicts_with = "file", default_value_t = mission::GOAL_TOLERANCE_M)]
    pub tolerance: f64,
    /// Built-in mission: without the fused localization module (odometry + GPS): Servo and
    /// Planning localize by the raw GPS and SLAM only.
    #[arg(long, conflicts_with = "file")]
    pub no_fusion: bool,
    /// Built-in mission: also write the summary as JSON to this file (as soon as the mission
    /// ends, before the system stops, and again at the end; each time whole, by a rename).
    #[arg(long, conflicts_with = "file")]
    pub summary: Option<PathBuf>,
    /// Built-in mission: run these episodes one after the other on the one system instead of
    /// goals (JSON lines: `{"id", "start": [x, y, theta], "goal": [x, y], "duration_s"}`; the
    /// robot is moved to each start, `hng eval nav`'s reuse; `--start` should be the first
    /// episode's start).
    #[arg(long, conflicts_with_all = ["file", "goal"])]
    pub episodes: Option<PathBuf>,
    /// With `--episodes`: append each episode's summary to this file as one JSON line as soon
    /// as it ends.
    #[arg(long, requires = "episodes")]
    pub episode_out: Option<PathBuf>,
    /// Louder terminal: `-v` shows `hng run`'s info lines and echoes every module's log
    /// lines, `-vv` debug (`HNG_LOG`/`RUST_LOG` set the filter and echo too). Module logs are
    /// always in RUN_DIR/logs (`hng logs`).
    #[arg(short, long, action = clap::ArgAction::Count)]
    pub verbose: u8,
    #[command(flatten)]
    pub recording: crate::recording::RunRecordArgs,
    #[command(flatten)]
    pub gui: crate::gui::RunGuiArgs,
}

impl RunArgs {
    fn mission_options(&self) -> MissionOptions {
        MissionOptions {
            world: self.world.clone(),
            start: self.start,
            goals: self.goal.clone(),
            speed: self.speed.clone(),
            seed: self.seed,
            duration_s: self.duration,
            tolerance_m: self.tolerance,
            fusion: !self.no_fusion,
            episodes: self.episodes.is_some(),
        }
    }
}

/// A minimal launch file (the heartbeat probe), kept as an example and for tests; `hng run`
/// without a file runs the built-in mission ([`mission`]).
pub fn default_plan() -> &'static str {
    r#"# hng's built-in default system.
system = "hng"

[defaults]
restart = "on-failure"
heartbeat_period_s = 0.1
checkpoint_period_s = 1.0
stop_timeout_s = 2.0

[[module]]
name = "probe"
command = ["hng", "module", "heartbeat-probe"]

[module.config]
output = "probe/count"
period_s = 0.1
"#
}

/// Exit code for a launch file that does not validate.
const EXIT_BAD_LAUNCH_FILE: u8 = 2;

/// `hng run`: returns the process's exit code.
pub fn run(prefix: &str, args: &RunArgs) -> ExitCode {
    let _ = logs::RUN_LOG.set(logs::RunLog::init(logs::Verbosity::new(args.verbose)));
    if args.file.is_none() {
        return run_mission(prefix, args);
    }
    let plan = match load_plan(args) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("hng: error: {e}");
            return ExitCode::from(EXIT_BAD_LAUNCH_FILE);
        }
    };
    for w in &plan.warnings {
        tracing::warn!("{}: {w}", plan.file.display());
    }
    let lock = match check_or_lock(prefix, args, &plan) {
        Ok(l) => l,
        Err(code) => return code,
    };
    match supervise(prefix, args, plan, None, lock).0 {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hng: error: {:#}", anyhow::Error::from(e));
            ExitCode::FAILURE
        }
    }
}

/// `hng run` without a file: the built-in mission, its monitor and its summary.
fn run_mission(prefix: &str, args: &RunArgs) -> ExitCode {
    let run_dir = args
        .run_dir
        .clone()
        .unwrap_or_else(|| default_run_dir(prefix));
    let mission = match Mission::new(&args.mission_options(), &run_dir) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("hng: error: {:#}", anyhow::Error::from(e));
            return ExitCode::from(EXIT_BAD_LAUNCH_FILE);
        }
    };
    if args.print_plan {
        hng_supervisor::say!("{}", mission.plan.trim_end());
        return ExitCode::SUCCESS;
    }
    let plan = match add_rm(
        launch::parse(
            &mission.plan,
            Path::new("<built-in mission>"),
            &load_options(),
        ),
        args,
    ) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("hng: error: {e}");
            return ExitCode::from(EXIT_BAD_LAUNCH_FILE);
        }
    };
    let lock = match check_or_lock(prefix, args, &plan) {
        Ok(l) => l,
        Err(code) => return code,
    };
    if let Err(e) = mission.prepare() {
        eprintln!("hng: error: {:#}", anyhow::Error::from(e));
        lock.release();
        return ExitCode::FAILURE;
    }
    hng_supervisor::say!(
        "mission: {} goal(s) from ({:.2}, {:.2}), speed {}, limit {} s simulated",
        mission.goals.len(),
        mission.start.x,
        mission.start.y,
        args.speed,
        mission.duration_s
    );
    hng_supervisor::say!(
        "logs: {} (hng logs MODULE [-f]; -v shows them here)",
        logs::log_dir(&run_dir).display()
    );
    let episodes = match &args.episodes {
        Some(f) => match hng_supervisor::monitor::read_episodes(f) {
            Ok(list) => {
                let first_placed = list.first().is_some_and(|e| {
                    (e.start[0] - mission.start.x).hypot(e.start[1] - mission.start.y) < 1e-6
                        && (e.start[2] - mission.start.theta).abs() < 1e-6
                });
                Some(EpisodeOptions {
                    list,
                    out: args.episode_out.clone(),
                    tolerance_m: args.tolerance,
                    pose_channels: if args.no_fusion {
                        vec!["slam/pose".to_owned()]
                    } else {
                        vec!["localization/pose".to_owned(), "slam/pose".to_owned()]
                    },
                    first_placed,
                })
            }
            Err(e) => {
                eprintln!("hng: error: {:#}", anyhow::Error::from(e));
                lock.release();
                return ExitCode::from(EXIT_BAD_LAUNCH_FILE);
            }
        },
        None => None,
    };
    let monitor = match Monitor::start(MonitorOptions {
        prefix: prefix.to_owned(),
        goals: mission.goals.clone(),
        duration_s: mission.duration_s,
        stall_timeout: Duration::from_secs(30),
        summary_file: args.summary.clone(),
        episodes,
    }) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("hng: error: {:#}", anyhow::Error::from(e));
            lock::remove_prefix_files_but_lock(prefix);
            lock.release();
            return ExitCode::FAILURE;
        }
    };
    let (result, outcome) = supervise(prefix, args, plan, Some(monitor), lock);
    if let Err(e) = result {
        eprintln!("hng: error: {:#}", anyhow::Error::from(e));
        return ExitCode::FAILURE;
    }
    let outcome = match outcome {
        Some(Ok(o)) => o,
        Some(Err(e)) => {
            eprintln!("hng: error: mission monitor: {:#}", anyhow::Error::from(e));
            return ExitCode::FAILURE;
        }
        None => return ExitCode::FAILURE,
    };
    report(&outcome, args.summary.as_deref())
}

/// With `--check`, the plan printed and the exit code; otherwise the prefix's lock (or the
/// failure to take it, said).
fn check_or_lock(
    prefix: &str,
    args: &RunArgs,
    plan: &LaunchPlan,
) -> std::result::Result<SystemLock, ExitCode> {
    if args.check {
        return Err(print_plan(plan));
    }
    lock::lock_prefix(prefix).map_err(|e| {
        eprintln!("hng: error: {:#}", anyhow::Error::from(e));
        ExitCode::FAILURE
    })
}

/// `--check`: the plan as JSON on stdout.
fn print_plan(plan: &LaunchPlan) -> ExitCode {
    match serde_json::to_string_pretty(plan) {
        Ok(json) => {
            hng_supervisor::say!("{json}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("hng: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Prints the summary, writes it as JSON, and returns the exit code.
fn report(outcome: &Outcome, file: Option<&Path>) -> ExitCode {
    if let Some(why) = &outcome.failure {
        hng_supervisor::say!("mission failed: {why}");
    }
    hng_supervisor::say!("{}", outcome.summary);
    if let Some(f) = file
        && let Err(e) = hng_supervisor::monitor::write_summary(f, &outcome.summary)
    {
        eprintln!("hng: error: {:#}", anyhow::Error::from(e));
        return ExitCode::FAILURE;
    }
    if outcome.summary.success {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

/// Loads the launch file (or the default plan) and adds the resource manager module.
fn load_plan(args: &RunArgs) -> Result<LaunchPlan, launch::LaunchErrors> {
    let opts = load_options();
    let plan = match &args.file {
        Some(f) => launch::load(f, &opts),
        None => launch::parse(
            default_plan(),
            Path::new("<built-in default system>"),
            &opts,
        ),
    };
    add_rm(plan, args)
}

/// How launch files are loaded: built-in modules' names and configurations are checked too.
fn load_options() -> LoadOptions {
    LoadOptions {
        check_module: crate::validate::module_check(),
        ..LoadOptions::default()
    }
}

/// Adds the resource manager module unless the plan has one or `--no-rm`.
fn add_rm(
    plan: Result<LaunchPlan, launch::LaunchErrors>,
    args: &RunArgs,
) -> Result<LaunchPlan, launch::LaunchErrors> {
    let mut plan = plan?;
    let has_rm = plan.modules.iter().any(|m| m.name == "rm");
    if !args.no_rm
        && !has_rm
        && crate::modules::BUILTIN.contains(&"rm")
        && let Ok(exe) = std::env::current_exe()
    {
        let mut rm = ModuleSpec::new("rm", exe, &["module", "rm"]);
        rm.heartbeat = plan.modules.iter().find_map(|m| m.heartbeat);
        // The RM starts first and stops last: it measures everyone.
        plan.modules.insert(0, rm);
    }
    Ok(plan)
}

/// Runs the system under the supervisor host, with the operator page and the recorder the
/// arguments ask for beside it.
fn supervise(
    prefix: &str,
    args: &RunArgs,
    plan: LaunchPlan,
    monitor: Option<Monitor>,
    lock: SystemLock,
) -> (Result<()>, Option<Result<Outcome>>) {
    let opts = HostOptions {
        run_dir: args
            .run_dir
            .clone()
            .unwrap_or_else(|| default_run_dir(prefix)),
        status_period: Duration::from_secs_f64(args.status_period),
    };
    let companions: StartCompanions<'_> = Box::new(|plan: &mut LaunchPlan, paths: RunPaths<'_>| {
        let mut out: Vec<Box<dyn Companion>> = Vec::new();
        // The operator page first: its address is among the first lines printed.
        if let Some(page) = crate::gui::start_for_run(prefix, &args.gui) {
            out.push(Box::new(PageCompanion(Some(page))));
        }
        let recorder = crate::recording::start_for_run(
            prefix,
            &args.recording,
            plan,
            paths.log_dir,
            paths.checkpoint_dir,
        )
        .map_err(|e| hng_supervisor::HostError::msg(format!("{e:#}")))?;
        if recorder.is_some() {
            out.push(Box::new(RecorderCompanion(recorder)));
        }
        Ok(out)
    });
    hng_supervisor::supervise(prefix, &opts, plan, monitor, lock, companions)
}

/// The operator page's process: said once if it ends; stopped first (its nodes are gone
/// before the prefix's files).
struct PageCompanion(Option<crate::gui::GuiChild>);

impl Companion for PageCompanion {
    fn check(&mut self) {
        if let Some(g) = &mut self.0 {
            g.check();
        }
    }

    fn modules_stopped(&mut self) {
        self.0 = None;
    }
}

/// The recorder's thread: finished (and its summary printed) after the mission monitor.
struct RecorderCompanion(Option<hng_recorder::RecorderThread>);

impl Companion for RecorderCompanion {
    fn finish(self: Box<Self>) {
        crate::recording::finish_for_run(self.0);
    }
}

/// `--status-period`: seconds, finite, from 0.01 to one hour.
fn parse_period(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (0.01..=3600.0).contains(&v) => Ok(v),
        _ => Err(format!(
            "{s:?} is not a period in seconds from 0.01 to 3600"
        )),
    }
}
