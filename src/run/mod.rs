//! `hng run [FILE]`: start a system from a launch file and supervise it (HNG paper 5.4).
//!
//! One process, two threads:
//! - the main thread owns the [`Supervisor`] (module processes, pidfds, timers) and the
//!   publishers of [`SUPERVISOR_EVENTS`] and [`SUPERVISOR_STATUS`]; it sleeps in the
//!   supervisor's `poll`, which wakes when a module exits, a timer is due, or the receiver
//!   thread has something;
//! - the receiver thread sleeps on `hng/report`, [`SUPERVISOR_COMMAND`] and SIGINT/SIGTERM/
//!   SIGHUP (one [`Waiter`]), stamps each report when it arrives, hands everything to the main
//!   thread over a channel and wakes its poll. Nothing polls on a period.
//!
//! A heartbeat counts only if the report's pid is the module's current process. Supervisor
//! events go out on [`SUPERVISOR_EVENTS`] as they happen (contracts route around a death at
//! once); the status document goes out every `--status-period` and on every change.
//!
//! Ctrl-C / SIGTERM (or `hng stop`): modules stop in reverse start order (SIGTERM, SIGKILL
//! after each one's `stop_timeout`), then the cgroups and every file of the prefix are
//! removed. A second signal SIGKILLs what is left at once.

pub mod ctl;
mod hooks;
pub mod lock;
pub mod logs;
pub mod mission;
pub mod monitor;
mod nav_watch;
pub mod probe;
mod receiver;
pub use receiver::block_termination_signals;
pub mod status;
mod validate;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::rc::Rc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result};
use clap::Args;
use hng_rm::cgroup::{CgroupRun, CgroupSupport, unique_run_id};
use hng_runtime::msg::ModuleReport;
use hng_runtime::system::{
    CommandOp, EventKind as WireEvent, JsonInfo, ModuleEvent, SUPERVISOR_COMMAND,
    SUPERVISOR_EVENTS, SUPERVISOR_STATUS, SupervisorCommand,
};
use hng_runtime::{Node, NodeOptions, Publisher, SlicePublisher};
use hng_watchdog::systemd::SdNotify;
use hng_watchdog::{
    Event, EventKind, LaunchPlan, LoadOptions, ModuleSpec, Signal, Supervisor, SupervisorOptions,
    launch,
};

use self::hooks::RunHooks;
use self::lock::SystemLock;
use self::mission::{Mission, MissionOptions};
use self::monitor::{Monitor, MonitorOptions, Outcome};
use self::receiver::{Inbox, Receiver};
use self::status::{CommandResult, ReportFigures, StatusDoc};

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
    /// Period of the status document (`hng ps`), ms; it is also sent on every change.
    #[arg(long, default_value_t = 500)]
    pub status_period_ms: u64,
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
    /// Built-in mission: also write the summary as JSON to this file.
    #[arg(long, conflicts_with = "file")]
    pub summary: Option<PathBuf>,
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
heartbeat_period = "100ms"
checkpoint_period = "1s"
stop_timeout = "2s"

[[module]]
name = "probe"
command = ["hng", "module", "heartbeat-probe"]

[module.config]
output = "probe/count"
period_ms = 100
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
    if args.check {
        return match serde_json::to_string_pretty(&plan) {
            Ok(json) => {
                println!("{json}");
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("hng: error: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let lock = match lock::lock_prefix(prefix) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("hng: error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    match supervise(prefix, args, plan, None, lock).0 {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hng: error: {e:#}");
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
            eprintln!("hng: error: {e:#}");
            return ExitCode::from(EXIT_BAD_LAUNCH_FILE);
        }
    };
    if args.print_plan {
        print!("{}", mission.plan);
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
    if args.check {
        return match serde_json::to_string_pretty(&plan) {
            Ok(json) => {
                println!("{json}");
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("hng: error: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let lock = match lock::lock_prefix(prefix) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("hng: error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    if let Err(e) = mission.prepare() {
        eprintln!("hng: error: {e:#}");
        lock.release();
        return ExitCode::FAILURE;
    }
    println!(
        "mission: {} goal(s) from ({:.2}, {:.2}), speed {}, limit {} s simulated",
        mission.goals.len(),
        mission.start.x,
        mission.start.y,
        args.speed,
        mission.duration_s
    );
    println!(
        "logs: {} (hng logs MODULE [-f]; -v shows them here)",
        logs::log_dir(&run_dir).display()
    );
    let monitor = match Monitor::start(MonitorOptions {
        prefix: prefix.to_owned(),
        goals: mission.goals.clone(),
        duration_s: mission.duration_s,
        stall_timeout: Duration::from_secs(30),
    }) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("hng: error: {e:#}");
            lock::remove_prefix_files_but_lock(prefix);
            lock.release();
            return ExitCode::FAILURE;
        }
    };
    let (result, outcome) = supervise(prefix, args, plan, Some(monitor), lock);
    if let Err(e) = result {
        eprintln!("hng: error: {e:#}");
        return ExitCode::FAILURE;
    }
    let outcome = match outcome {
        Some(Ok(o)) => o,
        Some(Err(e)) => {
            eprintln!("hng: error: mission monitor: {e:#}");
            return ExitCode::FAILURE;
        }
        None => return ExitCode::FAILURE,
    };
    report(&outcome, args.summary.as_deref())
}

/// Prints the summary, writes it as JSON, and returns the exit code.
fn report(outcome: &Outcome, file: Option<&Path>) -> ExitCode {
    if let Some(why) = &outcome.failure {
        println!("mission failed: {why}");
    }
    println!("{}", outcome.summary);
    if let Some(f) = file {
        let written = serde_json::to_string_pretty(&outcome.summary)
            .map_err(anyhow::Error::from)
            .and_then(|j| std::fs::write(f, j + "\n").map_err(anyhow::Error::from));
        if let Err(e) = written {
            eprintln!("hng: error: writing the summary to {}: {e:#}", f.display());
            return ExitCode::FAILURE;
        }
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
        check_module: validate::module_check(),
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

/// `$XDG_RUNTIME_DIR/hng/<prefix>` or `/tmp/hng-<prefix>`.
pub(crate) fn default_run_dir(prefix: &str) -> PathBuf {
    let tag = prefix.trim_end_matches('_');
    match std::env::var_os("XDG_RUNTIME_DIR").filter(|d| !d.is_empty()) {
        Some(d) => PathBuf::from(d).join("hng").join(tag),
        None => std::env::temp_dir().join(format!("hng-{tag}")),
    }
}

/// The main thread's state.
struct Runner {
    sup: Supervisor<RunHooks>,
    // Ports before the node.
    events: Publisher<ModuleEvent>,
    status: SlicePublisher<JsonInfo>,
    commands_out: Publisher<SupervisorCommand>,
    node: Rc<Node>,
    system: String,
    prefix: String,
    started: Instant,
    reports: HashMap<String, (ModuleReport, Instant)>,
    commands: u64,
    last_command: Option<CommandResult>,
    shutdown_signals: u32,
    monitor: Option<Monitor>,
    recorder: Option<hng_recorder::RecorderThread>,
    gui: Option<crate::gui::GuiChild>,
}

/// Runs the system until it stops; with a mission `monitor`, also returns its outcome (the
/// monitor is finished before the prefix's files are removed).
/// The prefix's files and its `lock` are removed last, whatever happened.
fn supervise(
    prefix: &str,
    args: &RunArgs,
    plan: LaunchPlan,
    monitor: Option<Monitor>,
    lock: SystemLock,
) -> (Result<()>, Option<Result<Outcome>>) {
    let mut monitor = monitor;
    let r = supervise_inner(prefix, args, plan, &mut monitor);
    let r = match r {
        Ok((r, outcome)) => (r, outcome),
        Err(e) => (Err(e), monitor.map(Monitor::finish)),
    };
    let n = lock::remove_prefix_files_but_lock(prefix);
    lock.release();
    tracing::info!(files = n, "stopped; prefix files removed");
    r
}

#[allow(clippy::type_complexity)]
fn supervise_inner(
    prefix: &str,
    args: &RunArgs,
    mut plan: LaunchPlan,
    monitor: &mut Option<Monitor>,
) -> Result<(Result<()>, Option<Result<Outcome>>)> {
    // Termination signals are read by the receiver thread (signalfd); `main` blocked them
    // before any thread started (this is for callers that did not). Modules start with an
    // empty mask and default dispositions (the supervisor's pre_exec).
    block_termination_signals();

    let run_dir = args
        .run_dir
        .clone()
        .unwrap_or_else(|| default_run_dir(prefix));
    let checkpoint_dir = plan
        .checkpoint_dir
        .clone()
        .unwrap_or_else(|| run_dir.join("checkpoints"));
    if monitor.is_some() && checkpoint_dir.exists() {
        // A mission starts afresh: no module resumes from a previous run's checkpoint.
        std::fs::remove_dir_all(&checkpoint_dir).with_context(|| {
            format!(
                "removing the previous mission's checkpoints {}",
                checkpoint_dir.display()
            )
        })?;
    }
    std::fs::create_dir_all(&checkpoint_dir).with_context(|| {
        format!(
            "creating the checkpoint directory {}",
            checkpoint_dir.display()
        )
    })?;

    let node = Rc::new(
        Node::new(NodeOptions::new("hng-supervisor").prefix(prefix))
            .context("creating the supervisor's node")?,
    );
    let events = node.publisher::<ModuleEvent>(SUPERVISOR_EVENTS)?;
    let status = node.slice_publisher::<JsonInfo>(SUPERVISOR_STATUS, 4096)?;
    let commands_out = node.publisher::<SupervisorCommand>(SUPERVISOR_COMMAND)?;

    let support = CgroupSupport::detect();
    let system_tag: String = plan
        .system
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let cgroup_run = match CgroupRun::create(&support, &system_tag, &unique_run_id()) {
        Ok(r) => Some(r),
        Err(e) => {
            tracing::warn!(
                "no cgroups for this run ({e}); caps are checked in software by the resource manager"
            );
            None
        }
    };

    let mut env = BTreeMap::new();
    env.insert("HNG_PREFIX".to_owned(), prefix.to_owned());
    env.insert(
        "HNG_CHECKPOINT_DIR".to_owned(),
        checkpoint_dir.to_string_lossy().into_owned(),
    );
    if plan.sim_clock {
        env.insert("HNG_CLOCK".to_owned(), "sim".to_owned());
    }
    if let Some(run) = &cgroup_run
        && run.support().is_writable()
    {
        env.insert("HNG_CGROUP_RUN".to_owned(), run.name().to_owned());
    }
    let hooks = RunHooks {
        node: Rc::clone(&node),
        cgroup_run,
        cgroups: HashMap::new(),
        caps: HashMap::new(),
        software_enforcer: plan.modules.iter().any(|m| m.name == "rm"),
    };
    // The operator page first: its address is among the first lines printed.
    let gui = crate::gui::start_for_run(prefix, &args.gui);
    let recorder = crate::recording::start_for_run(
        prefix,
        &args.recording,
        &mut plan,
        &logs::log_dir(&run_dir),
        &checkpoint_dir,
    )?;
    let logs = logs::RUN_LOG
        .get()
        .map(|l| l.open(&logs::log_dir(&run_dir)));
    let sup = Supervisor::with_hooks(
        plan.modules,
        SupervisorOptions {
            env,
            logs,
            ..SupervisorOptions::default()
        },
        hooks,
    )?;
    let receiver = Receiver::start(prefix, sup.waker())?;

    let mut runner = Runner {
        sup,
        events,
        status,
        commands_out,
        node,
        system: plan.system,
        prefix: prefix.to_owned(),
        started: Instant::now(),
        reports: HashMap::new(),
        commands: 0,
        last_command: None,
        shutdown_signals: 0,
        monitor: monitor.take(),
        recorder,
        gui,
    };
    tracing::info!(
        system = %runner.system,
        prefix,
        checkpoints = %checkpoint_dir.display(),
        "starting"
    );
    let result = runner.event_loop(
        &receiver,
        Duration::from_millis(args.status_period_ms.max(10)),
    );
    let outcome = runner.finish(receiver);
    Ok((result, outcome))
}

impl Runner {
    fn event_loop(&mut self, receiver: &Receiver, status_period: Duration) -> Result<()> {
        let mut sd = SdNotify::from_env();
        self.sup.start_all();
        let mut ready_sent = false;
        let mut next_status = Instant::now();
        loop {
            let mut changed = false;
            while let Ok(msg) = receiver.rx.try_recv() {
                match msg {
                    Inbox::Report { report, at } => self.on_report(report, at),
                    Inbox::Command(c) => {
                        self.on_command(&c, &sd);
                        changed = true;
                    }
                    Inbox::Signal(sig) => {
                        tracing::info!(signal = sig, "stopping the system");
                        self.begin_shutdown(&sd);
                        changed = true;
                    }
                    Inbox::Failed(e) => {
                        tracing::error!("receiver thread failed: {e}; stopping the system");
                        self.begin_shutdown(&sd);
                        changed = true;
                    }
                }
            }
            let now = Instant::now();
            let mut timeout = next_status.saturating_duration_since(now);
            if let Some(ping) = sd.next_ping_in(now) {
                timeout = timeout.min(ping);
            }
            if changed {
                // A command or a stop request to acknowledge: do not sleep before publishing.
                timeout = Duration::ZERO;
            }
            let events = self.sup.poll(timeout)?;
            for e in &events {
                self.on_event(e);
                changed = true;
            }
            if !ready_sent {
                // Every module has been spawned (start_all's events are out).
                ready_sent = true;
                sd.ready();
            }
            let now = Instant::now();
            sd.ping_if_due(now);
            if self.sup.is_shut_down() {
                self.publish_status(now);
                return Ok(());
            }
            self.node.update_connections();
            if changed || now >= next_status {
                if let Some(g) = &mut self.gui {
                    g.check();
                }
                self.publish_status(now);
                next_status = now + status_period;
            }
        }
    }

    fn begin_shutdown(&mut self, sd: &SdNotify) {
        self.shutdown_signals += 1;
        if self.shutdown_signals == 1 {
            sd.stopping();
            self.sup.begin_shutdown();
        } else {
            tracing::warn!("second stop request: killing every module now");
            let names: Vec<String> = self.sup.modules().map(|m| m.name.clone()).collect();
            for n in names {
                let _ = self.sup.kill(&n, Signal::SIGKILL);
            }
        }
    }

    fn on_report(&mut self, report: ModuleReport, at: Instant) {
        let name = report.name();
        // Only the module's current process counts; a report of a dead predecessor is stale.
        if let Ok(Some(pid)) = self.sup.pid(name)
            && pid == report.pid
        {
            // The report announces when the next comes (an idle module stretches it).
            let next = (report.period_ns > 0).then(|| Duration::from_nanos(report.period_ns));
            let _ = self.sup.heartbeat_promising(name, at, next);
            self.reports.insert(name.to_owned(), (report, at));
        }
    }

    fn on_event(&mut self, e: &Event) {
        tracing::info!("{e}");
        if self.monitor.is_some()
            && self.shutdown_signals == 0
            && let EventKind::Exited { pid, cause, .. } = &e.kind
            && cause.is_failure()
        {
            // The mission's progress names why a module went (a missed heartbeat above all:
            // the monitor only sees that it died).
            println!("[watchdog] module {} (pid {pid}) {cause}", e.module);
        }
        let wire = match &e.kind {
            EventKind::Started { pid, .. } => {
                Some(ModuleEvent::new(WireEvent::Started, &e.module, *pid))
            }
            EventKind::Exited { pid, .. } => {
                self.reports.remove(&e.module);
                Some(ModuleEvent::new(WireEvent::Died, &e.module, *pid))
            }
            EventKind::Deactivated { .. } => {
                Some(ModuleEvent::new(WireEvent::Deactivated, &e.module, 0))
            }
            EventKind::Stopped => Some(ModuleEvent::new(WireEvent::Stopped, &e.module, 0)),
            _ => None,
        };
        if let Some(w) = wire
            && let Err(err) = self.events.publish(w)
        {
            tracing::warn!("publishing a supervisor event: {err}");
        }
        if matches!(e.kind, EventKind::Deactivated { .. } | EventKind::Stopped) {
            // Nobody restarts it soon: release its ports in every service now.
            self.sup.hooks_mut().clean_dead_nodes();
        }
    }

    fn on_command(&mut self, c: &SupervisorCommand, sd: &SdNotify) {
        let Some(op) = c.op() else {
            // Not a command (the main thread's wake-up of the receiver thread).
            return;
        };
        let module = c.module().to_owned();
        let result = match op {
            CommandOp::Kill => match Signal::try_from(c.signal) {
                Ok(sig) => self.sup.kill(&module, sig).map_err(|e| e.to_string()),
                Err(_) => Err(format!("{} is not a signal", c.signal)),
            },
            CommandOp::Restart => self.sup.restart(&module).map_err(|e| e.to_string()),
            CommandOp::Stop => self.sup.stop(&module).map_err(|e| e.to_string()),
            CommandOp::Start => self.sup.start(&module).map_err(|e| e.to_string()),
            CommandOp::OverLimit => self
                .sup
                .kill_over_limit(&module, c.reason())
                .map_err(|e| e.to_string()),
            CommandOp::Shutdown => {
                self.begin_shutdown(sd);
                Ok(())
            }
        };
        self.commands += 1;
        match &result {
            Ok(()) => tracing::info!(?op, module, "command"),
            Err(e) => tracing::warn!(?op, module, "command failed: {e}"),
        }
        self.last_command = Some(CommandResult {
            seq: self.commands,
            op: format!("{op:?}"),
            module,
            error: result.err(),
        });
    }

    fn status_doc(&self, now: Instant) -> StatusDoc {
        let modules = self
            .sup
            .status(now)
            .iter()
            .map(|s| {
                let report = self
                    .reports
                    .get(&s.name)
                    .map(|(r, at)| ReportFigures::new(r, *at, now));
                let caps = self.sup.hooks().caps.get(&s.name).cloned().flatten();
                status::module_row(s, report).with_caps(caps)
            })
            .collect();
        StatusDoc {
            system: self.system.clone(),
            prefix: self.prefix.clone(),
            supervisor_pid: std::process::id(),
            uptime_ms: now.saturating_duration_since(self.started).as_secs_f64() * 1e3,
            shutting_down: self.shutdown_signals > 0,
            commands: self.commands,
            last_command: self.last_command.clone(),
            modules,
        }
    }

    fn publish_status(&mut self, now: Instant) {
        let doc = self.status_doc(now);
        match serde_json::to_vec(&doc) {
            Ok(bytes) => {
                if let Err(e) = self.status.publish_copy(JsonInfo::default(), &bytes) {
                    tracing::warn!("publishing the status: {e}");
                }
            }
            Err(e) => tracing::warn!("encoding the status: {e}"),
        }
    }

    /// After the last module stopped: stop the receiver, drop every port and node, remove
    /// the cgroups and the prefix's files.
    fn finish(self, mut receiver: Receiver) -> Option<Result<Outcome>> {
        receiver.stop.store(true, Ordering::Release);
        // Wake the receiver thread with a non-command (op 0) so it sees the flag.
        let _ = self.commands_out.publish(SupervisorCommand::default());
        if let Some(t) = receiver.thread.take() {
            let _ = t.join();
        }
        drop(receiver);
        let Runner {
            mut sup,
            events,
            status,
            commands_out,
            node,
            monitor,
            recorder,
            gui,
            ..
        } = self;
        // The page's process goes first: its nodes are gone before the prefix's files.
        drop(gui);
        let _ = sup.shutdown();
        let outcome = monitor.map(Monitor::finish);
        crate::recording::finish_for_run(recorder);
        sup.hooks_mut().remove_cgroups();
        drop(sup);
        drop((events, status, commands_out));
        drop(node);
        // The prefix's files go in `supervise`, with the lock, last.
        outcome
    }
}
