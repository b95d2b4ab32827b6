//! The supervisor host: start a system from its launch plan and supervise it (HNG paper 5.4).
//! `hng run` parses its arguments and calls [`supervise`].
//!
//! One process, two threads:
//! - the main thread owns the [`Supervisor`] (module processes, pidfds, timers) and the
//!   publishers of [`SUPERVISOR_EVENTS`] and [`SUPERVISOR_STATUS`]; it sleeps in the
//!   supervisor's `poll`, which wakes when a module exits, a timer is due, or the receiver
//!   thread has something;
//! - the receiver thread sleeps on `hng/report`, [`SUPERVISOR_COMMAND`] and SIGINT/SIGTERM/
//!   SIGHUP (one [`Waiter`](hng_runtime::wait::Waiter)), stamps each report when it arrives,
//!   hands everything to the main thread over a channel and wakes its poll. Nothing polls on
//!   a period.
//!
//! A heartbeat counts only if the report's pid is the module's current process. Supervisor
//! events go out on [`SUPERVISOR_EVENTS`] as they happen (contracts route around a death at
//! once); the status document goes out every [`HostOptions::status_period`] and on every
//! change.
//!
//! Ctrl-C / SIGTERM (or `hng stop`): modules stop in reverse start order (SIGTERM, SIGKILL
//! after each one's `stop_timeout`), then the cgroups and every file of the prefix are
//! removed. A second signal SIGKILLs what is left at once.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use crate::error::{Context as _, HostError, Result};
use hng_rm::cgroup::{CgroupRun, CgroupSupport, unique_run_id};
use hng_runtime::msg::ModuleReport;
use hng_runtime::system::{
    CommandOp, EventKind as WireEvent, JsonInfo, ModuleEvent, SUPERVISOR_COMMAND,
    SUPERVISOR_EVENTS, SUPERVISOR_STATUS, SupervisorCommand,
};
use hng_runtime::{Node, NodeOptions, Publisher, SlicePublisher};
use hng_watchdog::systemd::SdNotify;
use hng_watchdog::{Event, EventKind, LaunchPlan, Signal, Supervisor, SupervisorOptions};

use crate::hooks::RunHooks;
use crate::lock::{self, SystemLock};
use crate::logs;
use crate::monitor::{Monitor, Outcome};
use crate::receiver::{Inbox, Receiver, block_termination_signals};
use crate::status::{self, CommandResult, ReportFigures, StatusDoc};

/// How the host runs a system.
#[derive(Debug, Clone)]
pub struct HostOptions {
    /// The run directory: `logs/` and (unless the launch plan sets `checkpoint_dir`)
    /// `checkpoints/` go there.
    pub run_dir: PathBuf,
    /// Period of the status document; it is also sent on every change.
    pub status_period: Duration,
}

/// Where a run keeps its files, for the companions started with it.
#[derive(Debug, Clone, Copy)]
pub struct RunPaths<'a> {
    /// The modules' and the host's log files.
    pub log_dir: &'a Path,
    /// The modules' checkpoints.
    pub checkpoint_dir: &'a Path,
}

/// Something the caller runs beside the system for the length of the run (`hng run` starts
/// its operator page and its recorder this way), told when the run reaches each stage.
pub trait Companion {
    /// With every status document (at least once a status period): a chance to notice
    /// that the companion's own work ended.
    fn check(&mut self) {}
    /// Every module has stopped; the mission monitor has not finished yet.
    fn modules_stopped(&mut self) {}
    /// After the mission monitor finished, before the prefix's files are removed.
    fn finish(self: Box<Self>) {}
}

/// Starts the companions once the run's paths are known; may add modules to the plan.
pub type StartCompanions<'a> =
    Box<dyn FnOnce(&mut LaunchPlan, RunPaths<'_>) -> Result<Vec<Box<dyn Companion>>> + 'a>;

/// `$XDG_RUNTIME_DIR/hng/<prefix>` or `/tmp/hng-<prefix>`.
pub fn default_run_dir(prefix: &str) -> PathBuf {
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
    companions: Vec<Box<dyn Companion>>,
}

/// Runs the system until it stops; with a mission `monitor`, also returns its outcome (the
/// monitor is finished before the prefix's files are removed).
/// The prefix's files and its `lock` are removed last, whatever happened.
pub fn supervise(
    prefix: &str,
    opts: &HostOptions,
    plan: LaunchPlan,
    monitor: Option<Monitor>,
    lock: SystemLock,
    companions: StartCompanions<'_>,
) -> (Result<()>, Option<Result<Outcome>>) {
    let mut monitor = monitor;
    // A panic in the host (a bug, a companion's) must not leave the prefix's files behind:
    // unwinding drops the watchdog's `Supervisor`, which SIGKILLs and reaps every module; the
    // files and the lock go below, and the panic becomes the run's error.
    let inner = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        supervise_inner(prefix, opts, plan, &mut monitor, companions)
    }));
    let r = match inner {
        Ok(Ok((r, outcome))) => (r, outcome),
        Ok(Err(e)) => (Err(e), monitor.map(Monitor::finish)),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".to_owned());
            let e = HostError::Message(format!(
                "the supervisor host panicked ({what}); every module was killed"
            ));
            (Err(e), None)
        }
    };
    let n = lock::remove_prefix_files_but_lock(prefix);
    lock.release();
    tracing::info!(files = n, "stopped; prefix files removed");
    r
}

#[allow(clippy::type_complexity)]
fn supervise_inner(
    prefix: &str,
    opts: &HostOptions,
    mut plan: LaunchPlan,
    monitor: &mut Option<Monitor>,
    companions: StartCompanions<'_>,
) -> Result<(Result<()>, Option<Result<Outcome>>)> {
    // Termination signals are read by the receiver thread (signalfd); `main` blocked them
    // before any thread started (this is for callers that did not). Modules start with an
    // empty mask and default dispositions (the supervisor's pre_exec).
    block_termination_signals();

    let run_dir = &opts.run_dir;
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
    let log_dir = logs::log_dir(run_dir);
    let companions = companions(
        &mut plan,
        RunPaths {
            log_dir: &log_dir,
            checkpoint_dir: &checkpoint_dir,
        },
    )?;
    let logs = logs::RUN_LOG.get().map(|l| l.open(&log_dir));
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
        companions,
    };
    tracing::info!(
        system = %runner.system,
        prefix,
        checkpoints = %checkpoint_dir.display(),
        "starting"
    );
    let result = runner.event_loop(&receiver, opts.status_period.max(Duration::from_millis(10)));
    let outcome = runner.finish(receiver);
    Ok((result, outcome))
}

impl Runner {
    fn event_loop(&mut self, receiver: &Receiver, status_period: Duration) -> Result<()> {
        let mut sd = SdNotify::from_env();
        let spawning = Instant::now();
        self.sup.start_all();
        tracing::info!(
            modules = self.sup.modules().count(),
            ms = spawning.elapsed().as_secs_f64() * 1e3,
            "every module spawned"
        );
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
                for c in &mut self.companions {
                    c.check();
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
            crate::say!("[watchdog] module {} (pid {pid}) {cause}", e.module);
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
            mut companions,
            ..
        } = self;
        for c in &mut companions {
            c.modules_stopped();
        }
        let _ = sup.shutdown();
        let outcome = monitor.map(Monitor::finish);
        for c in companions {
            c.finish();
        }
        sup.hooks_mut().remove_cgroups();
        drop(sup);
        drop((events, status, commands_out));
        drop(node);
        // The prefix's files go in `supervise`, with the lock, last.
        outcome
    }
}
