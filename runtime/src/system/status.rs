//! The supervisor's status document on [`super::SUPERVISOR_STATUS`], typed: what `hng run`
//! publishes and `hng ps`, `hng top`, the resource manager and the operator page read (JSON,
//! one schema for all of them).

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::msg::{ModuleReport, ModuleState as ReportState};

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

/// The outcome of one [`super::SupervisorCommand`].
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
    /// The caps of the launch file and who enforces each (`None`: no cap asked for).
    /// The resource manager reads `cpu_quota` and `memory_max` here and checks those
    /// the kernel does not enforce.
    #[serde(default)]
    pub caps: Option<CapsRow>,
}

/// A module's caps (launch file `cpu_quota`, `memory_max`, `pids_max`) and how each is
/// enforced: `kernel` (its cgroup), `software` (the resource manager measures it and has
/// the module killed and restarted with cause "over limit" when it goes over), or
/// `unenforced`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CapsRow {
    /// CPU, fraction of one core.
    pub cpu_quota: Option<f64>,
    /// Memory, bytes.
    pub memory_max: Option<u64>,
    /// Tasks.
    pub pids_max: Option<u64>,
    /// How `cpu_quota` is enforced.
    pub cpu: Option<String>,
    /// How `memory_max` is enforced.
    pub memory: Option<String>,
    /// How `pids_max` is enforced.
    pub pids: Option<String>,
    /// One line per cap the kernel does not enforce: why, and the fallback.
    pub fallback: Vec<String>,
}

impl CapsRow {
    /// Short text for tables: `cpu 20%k mem 64M s pids 32k` (`k` kernel, `s` software,
    /// `-` unenforced).
    #[must_use]
    pub fn short(&self) -> String {
        let tag = |h: &Option<String>| match h.as_deref() {
            Some("kernel") => "k",
            Some("software") => "s",
            _ => "-",
        };
        let mut parts = Vec::new();
        if let Some(q) = self.cpu_quota {
            parts.push(format!("cpu {:.0}%{}", q * 100.0, tag(&self.cpu)));
        }
        if let Some(m) = self.memory_max {
            parts.push(format!(
                "mem {:.0}M{}",
                m as f64 / (1024.0 * 1024.0),
                tag(&self.memory)
            ));
        }
        if let Some(p) = self.pids_max {
            parts.push(format!("pids {p}{}", tag(&self.pids)));
        }
        parts.join(" ")
    }
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

/// A duration in milliseconds, as the document writes durations.
#[must_use]
pub fn millis(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

impl ReportFigures {
    /// From a report received at `at`.
    pub fn new(r: &ModuleReport, at: Instant, now: Instant) -> ReportFigures {
        let state = match ReportState::from_repr(r.state) {
            Some(ReportState::Configured) => "configured",
            Some(ReportState::Running) => "running",
            Some(ReportState::Idle) => "idle",
            Some(ReportState::Stopping) => "stopping",
            None => "unknown",
        };
        ReportFigures {
            age_ms: millis(now.saturating_duration_since(at)),
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
    /// Sets the caps.
    #[must_use]
    pub fn with_caps(mut self, caps: Option<CapsRow>) -> ModuleRow {
        self.caps = caps;
        self
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
