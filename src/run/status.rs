//! The supervisor's status document on [`SUPERVISOR_STATUS`]: what `hng run` publishes and
//! `hng ps` (and the tests) read.

use std::time::{Duration, Instant};

use anyhow::Result;
use hng_runtime::msg::{ModuleReport, ModuleState as ReportState};
use hng_runtime::system::SUPERVISOR_STATUS;
use hng_watchdog::{ModuleState, ModuleStatus};
use serde::{Deserialize, Serialize};

use crate::doc::{DocReader, ensure_channel_exists};

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
    /// From the launch file's caps and what the cgroup layer made of them.
    /// `software_enforcer`: a resource manager runs (else software caps are unenforced).
    /// `None` when no cap is asked for.
    pub fn new(
        caps: &hng_watchdog::ResourceCaps,
        applied: &hng_rm::limits::AppliedLimits,
        software_enforcer: bool,
    ) -> Option<CapsRow> {
        use hng_rm::limits::Cap;
        if *caps == hng_watchdog::ResourceCaps::default() {
            return None;
        }
        let mut fallback = Vec::new();
        let mut how = |what: &str, asked: bool, cap: &Cap, software_ok: bool| -> Option<String> {
            if !asked {
                return None;
            }
            Some(
                match cap {
                    Cap::Kernel => "kernel",
                    Cap::Software { reason } if software_ok && software_enforcer => {
                        fallback.push(format!(
                            "{what}: not in the kernel ({reason}); the resource manager measures it and stops the module over it"
                        ));
                        "software"
                    }
                    Cap::Software { reason } | Cap::Unenforced { reason } => {
                        let why = if software_ok && !software_enforcer {
                            format!("{reason}; no resource manager runs")
                        } else {
                            reason.clone()
                        };
                        fallback.push(format!("{what}: not enforced ({why})"));
                        "unenforced"
                    }
                    // Asked for but not applied (cannot happen with the cgroup layer).
                    Cap::NotRequested => {
                        fallback.push(format!("{what}: not applied"));
                        "unenforced"
                    }
                }
                .to_owned(),
            )
        };
        let cpu = how("cpu_quota", caps.cpu_quota.is_some(), &applied.cpu, true);
        let memory = how(
            "memory_max",
            caps.memory_max.is_some(),
            &applied.memory,
            true,
        );
        let pids = how("pids_max", caps.pids_max.is_some(), &applied.pids, false);
        Some(CapsRow {
            cpu_quota: caps.cpu_quota,
            memory_max: caps.memory_max,
            pids_max: caps.pids_max,
            cpu,
            memory,
            pids,
            fallback,
        })
    }

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
            caps: None,
        }
    }

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

/// A reader of the status document of the system under a prefix.
pub type StatusReader = DocReader<StatusDoc>;

/// Fails with a clear message when nothing has ever published a status under `prefix`
/// (checked without creating any file of the prefix).
pub fn ensure_system_exists(prefix: &str) -> Result<()> {
    // A supervisor holds the prefix's lock while it runs: without it, no node is created
    // (a tool racing with the end of a system would otherwise leave files behind).
    if super::lock::running_supervisor(prefix).is_none() {
        anyhow::bail!(
            "no hng system runs under prefix {prefix:?} (no supervisor holds {}); start one with `hng run` or pass --prefix",
            super::lock::lock_path(prefix).display()
        );
    }
    ensure_channel_exists(
        prefix,
        SUPERVISOR_STATUS,
        "hng system",
        "start one with `hng run` or pass --prefix",
    )
}

/// Opens the status channel of the system under `prefix` (which must exist) as `tool`.
pub fn status_reader(prefix: &str, tool: &str) -> Result<StatusReader> {
    ensure_system_exists(prefix)?;
    DocReader::open(prefix, SUPERVISOR_STATUS, tool, "the supervisor")
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_rm::limits::{AppliedLimits, Cap};
    use hng_watchdog::ResourceCaps;

    #[test]
    fn caps_row_names_who_enforces_each_cap_and_the_fallback() {
        let caps = ResourceCaps {
            cpu_quota: Some(0.0005),
            memory_max: Some(64 << 20),
            pids_max: Some(32),
        };
        let applied = AppliedLimits {
            cpu: Cap::Software {
                reason: "quota under the kernel's minimum".into(),
            },
            memory: Cap::Kernel,
            pids: Cap::Unenforced {
                reason: "no writable pids controller".into(),
            },
        };
        let row = CapsRow::new(&caps, &applied, true).expect("caps asked for");
        assert_eq!(row.cpu.as_deref(), Some("software"));
        assert_eq!(row.memory.as_deref(), Some("kernel"));
        assert_eq!(row.pids.as_deref(), Some("unenforced"));
        assert_eq!(row.fallback.len(), 2, "{row:?}");
        assert!(row.fallback[0].contains("resource manager"), "{row:?}");
        assert_eq!(row.short(), "cpu 0%s mem 64Mk pids 32-");
        // The RM reads cpu_quota and memory_max from the JSON.
        let v = serde_json::to_value(&row).expect("json");
        assert_eq!(v["cpu_quota"], 0.0005);
        assert_eq!(v["memory_max"], 64 << 20);
        // Without a resource manager the software caps are unenforced, and said so.
        let row = CapsRow::new(&caps, &applied, false).expect("caps asked for");
        assert_eq!(row.cpu.as_deref(), Some("unenforced"));
        assert!(row.fallback[0].contains("no resource manager"), "{row:?}");
        assert!(CapsRow::new(&ResourceCaps::default(), &applied, true).is_none());
    }
}
