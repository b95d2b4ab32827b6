//! The supervisor's status document on [`SUPERVISOR_STATUS`]: what `hng run` publishes and
//! `hng ps` (and the tests) read.

use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use hng_runtime::channel::{Service, iceoryx_config};
use hng_runtime::msg::{ModuleReport, ModuleState as ReportState};
use hng_runtime::system::{JsonInfo, SUPERVISOR_STATUS};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, SliceSubscriber};
use hng_watchdog::{ModuleState, ModuleStatus};
use serde::{Deserialize, Serialize};

/// The whole document.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StatusDoc {
    /// Name of the system (launch file `system`).
    pub system: String,
    /// The shared-memory prefix.
    pub prefix: String,
    /// Pid of `hng run`.
    pub supervisor_pid: u32,
    /// Time since `hng run` started, ms.
    pub uptime_ms: f64,
    /// The orderly stop has begun.
    pub shutting_down: bool,
    /// Commands executed so far (a command's acknowledgement is a document with a larger count).
    pub commands: u64,
    /// The last command executed and its result.
    pub last_command: Option<CommandResult>,
    /// One row per module, in start order.
    pub modules: Vec<ModuleRow>,
}

/// The outcome of one [`hng_runtime::system::SupervisorCommand`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CommandResult {
    /// Its number (the document's `commands` when it was executed).
    pub seq: u64,
    /// `Kill`, `Restart`, ...
    pub op: String,
    /// Target module (empty for Shutdown).
    pub module: String,
    /// `None`: done; otherwise why not.
    pub error: Option<String>,
}

/// One module as `hng ps` shows it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModuleRow {
    /// Module name.
    pub name: String,
    /// `running`, `starting`, `restarting` (started again, no heartbeat yet), `backing-off`,
    /// `stopping`, `deactivated`, `stopped`.
    pub state: String,
    /// Current pid.
    pub pid: Option<u32>,
    /// Time since the current process started, ms.
    pub uptime_ms: Option<f64>,
    /// Automatic and maintenance restarts so far.
    pub restarts: u32,
    /// Why the previous process ended (structured, see `ExitCause`).
    pub last_exit: Option<serde_json::Value>,
    /// The same, as text.
    pub last_exit_text: Option<String>,
    /// Age of the last heartbeat, ms.
    pub heartbeat_age_ms: Option<f64>,
    /// Time left before a scheduled restart, ms.
    pub restart_in_ms: Option<f64>,
    /// The Manager module.
    pub manager: bool,
    /// Figures of the module's last report (from its current process).
    pub report: Option<ReportFigures>,
}

/// The last [`ModuleReport`] of a module's current process.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReportFigures {
    /// Age of the report, ms.
    pub age_ms: f64,
    /// `configured`, `running`, `idle`, `stopping`.
    pub state: String,
    /// Aptitude f.
    pub aptitude: bool,
    /// Quality Q.
    pub quality: f32,
    /// Messages received.
    pub msgs_in: u64,
    /// Messages published.
    pub msgs_out: u64,
    /// Messages lost.
    pub msgs_dropped: u64,
    /// Input deadlines missed.
    pub deadline_misses: u64,
    /// Checkpoints written.
    pub checkpoints: u64,
    /// Waiting for resources.
    pub waiting_for_resources: bool,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

impl ReportFigures {
    /// From a report received at `at`.
    pub fn new(r: &ModuleReport, at: Instant, now: Instant) -> ReportFigures {
        let state = match ReportState::from_u8(r.state) {
            Some(ReportState::Configured) => "configured",
            Some(ReportState::Running) => "running",
            Some(ReportState::Idle) => "idle",
            Some(ReportState::Stopping) => "stopping",
            None => "unknown",
        };
        ReportFigures {
            age_ms: ms(now.saturating_duration_since(at)),
            state: state.to_owned(),
            aptitude: r.aptitude != 0,
            quality: r.quality,
            msgs_in: r.msgs_in,
            msgs_out: r.msgs_out,
            msgs_dropped: r.msgs_dropped,
            deadline_misses: r.deadline_misses,
            checkpoints: r.checkpoints,
            waiting_for_resources: r.waiting_for_resources != 0,
        }
    }
}

impl ModuleRow {
    /// From the supervisor's status of one module and its last report.
    pub fn new(s: &ModuleStatus, report: Option<ReportFigures>) -> ModuleRow {
        let state = match s.state {
            ModuleState::Starting if s.restarts > 0 => "restarting".to_owned(),
            other => other.to_string(),
        };
        ModuleRow {
            name: s.name.clone(),
            state,
            pid: s.pid,
            uptime_ms: s.uptime.map(ms),
            restarts: s.restarts,
            last_exit: s
                .last_exit
                .as_ref()
                .and_then(|c| serde_json::to_value(c).ok()),
            last_exit_text: s.last_exit.as_ref().map(ToString::to_string),
            heartbeat_age_ms: s.heartbeat_age.map(ms),
            restart_in_ms: s.restart_in.map(ms),
            manager: s.manager,
            report,
        }
    }
}

impl StatusDoc {
    /// The row of `name`.
    pub fn module(&self, name: &str) -> Option<&ModuleRow> {
        self.modules.iter().find(|m| m.name == name)
    }

    /// The module names, comma-separated (for error messages).
    pub fn names(&self) -> String {
        let names: Vec<&str> = self.modules.iter().map(|m| m.name.as_str()).collect();
        names.join(", ")
    }
}

/// A reader of the status document of the system under a prefix.
pub struct StatusReader {
    // Field order: ports before the node that owns them.
    sub: SliceSubscriber<JsonInfo>,
    waiter: Waiter,
    node: Node,
}

/// Fails with a clear message when nothing has ever published a status under `prefix`
/// (checked without creating any file of the prefix).
pub fn ensure_system_exists(prefix: &str) -> Result<()> {
    let config = iceoryx_config(prefix)?;
    let name = iceoryx2::prelude::ServiceName::new(SUPERVISOR_STATUS)
        .map_err(|e| anyhow::anyhow!("service name: {e:?}"))?;
    let details = <Service as iceoryx2::service::Service>::details(
        &name,
        &config,
        iceoryx2::service::messaging_pattern::MessagingPattern::PublishSubscribe,
    )
    .map_err(|e| anyhow::anyhow!("looking up the supervisor of prefix {prefix:?}: {e:?}"))?;
    if details.is_none() {
        bail!(
            "no hng system runs under prefix {prefix:?} (no supervisor status channel); start one with `hng run` or pass --prefix"
        );
    }
    Ok(())
}

impl StatusReader {
    /// Opens the status channel of the system under `prefix` (which must exist).
    pub fn open(prefix: &str, tool: &str) -> Result<StatusReader> {
        ensure_system_exists(prefix)?;
        let node =
            Node::new(NodeOptions::new(&format!("{tool}-{}", std::process::id())).prefix(prefix))
                .context("creating a node")?;
        let sub = node
            .slice_subscriber::<JsonInfo>(SUPERVISOR_STATUS)
            .context("subscribing to the supervisor status")?;
        let mut waiter = Waiter::new(WaitMode::Blocking {
            max_spin: Duration::ZERO,
        })?;
        waiter.attach(&sub)?;
        Ok(StatusReader { sub, waiter, node })
    }

    /// The node (to open more ports).
    pub fn node(&self) -> &Node {
        &self.node
    }

    /// The next document that satisfies `pred`, waiting up to `timeout`.
    pub fn next_where(
        &mut self,
        timeout: Duration,
        mut pred: impl FnMut(&StatusDoc) -> bool,
    ) -> Result<StatusDoc> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(s) = self.sub.receive()? {
                let doc: StatusDoc = serde_json::from_slice(s.data())
                    .context("the supervisor's status document is not valid")?;
                if pred(&doc) {
                    return Ok(doc);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!(
                    "no answer from the supervisor of prefix {:?} within {timeout:?} (is `hng run` still running?)",
                    self.node.prefix()
                );
            }
            self.waiter.wait(Some(left))?;
        }
    }

    /// The current document.
    pub fn current(&mut self, timeout: Duration) -> Result<StatusDoc> {
        self.next_where(timeout, |_| true)
    }
}
