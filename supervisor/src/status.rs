//! The supervisor's status document on [`SUPERVISOR_STATUS`]: what `hng run` publishes and
//! `hng ps` (and the tests) read.

use crate::error::{Result, bail};
use hng_runtime::system::SUPERVISOR_STATUS;
use hng_watchdog::{ModuleState, ModuleStatus};

use hng_runtime::system::status::millis as ms;
pub use hng_runtime::system::status::{
    CapsRow, CommandResult, ModuleRow, ReportFigures, StatusDoc,
};

use crate::doc::{DocReader, ensure_channel_exists};

/// From the launch file's caps and what the cgroup layer made of them.
/// `software_enforcer`: a resource manager runs (else software caps are unenforced).
/// `None` when no cap is asked for.
pub fn caps_row(
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

/// From the supervisor's status of one module and its last report.
pub fn module_row(s: &ModuleStatus, report: Option<ReportFigures>) -> ModuleRow {
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

/// A reader of the status document of the system under a prefix.
pub type StatusReader = DocReader<StatusDoc>;

/// Fails with a clear message when nothing has ever published a status under `prefix`
/// (checked without creating any file of the prefix).
pub fn ensure_system_exists(prefix: &str) -> Result<()> {
    // A supervisor holds the prefix's lock while it runs: without it, no node is created
    // (a tool racing with the end of a system would otherwise leave files behind).
    if super::lock::running_supervisor(prefix).is_none() {
        bail!(
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
        let row = caps_row(&caps, &applied, true).expect("caps asked for");
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
        let row = caps_row(&caps, &applied, false).expect("caps asked for");
        assert_eq!(row.cpu.as_deref(), Some("unenforced"));
        assert!(row.fallback[0].contains("no resource manager"), "{row:?}");
        assert!(caps_row(&ResourceCaps::default(), &applied, true).is_none());
    }
}
