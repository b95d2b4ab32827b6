//! `hng ps`, `hng kill`, `hng restart`, `hng start`, `hng stop`: what they print; the requests
//! themselves are the supervisor host's ([`hng_supervisor::control`]).

use std::str::FromStr;
use std::time::Duration;

use anyhow::Result;
use hng_runtime::system::{CommandOp, SupervisorCommand};
use hng_supervisor::control::{ANSWER_TIMEOUT, command};
use hng_watchdog::Signal;

use hng_supervisor::status::status_reader;

/// How long `hng ps` waits for the resource manager's figures (it publishes at 10 Hz).
const RM_TIMEOUT: Duration = Duration::from_millis(500);

/// `hng ps [--json]`.
pub fn ps(prefix: &str, json: bool) -> Result<()> {
    let mut reader = status_reader(prefix, "hng-ps")?;
    let doc = reader.current(ANSWER_TIMEOUT)?;
    // The resource manager's figures (CPU, memory, caps, R, R_eff), when it runs.
    let rm = crate::top::rm_figures(prefix, RM_TIMEOUT)
        .ok()
        .flatten()
        .unwrap_or_default();
    let resources = |name: &str| rm.get(name).cloned().unwrap_or(serde_json::Value::Null);
    if json {
        let mut v = serde_json::to_value(&doc)?;
        if let Some(mods) = v
            .get_mut("modules")
            .and_then(serde_json::Value::as_array_mut)
        {
            for m in mods {
                let name = m
                    .get("name")
                    .and_then(serde_json::Value::as_str)
                    .unwrap_or("")
                    .to_owned();
                if let Some(obj) = m.as_object_mut() {
                    obj.insert("resources".into(), resources(&name));
                }
            }
        }
        outln!("{}", serde_json::to_string(&v)?)?;
        return Ok(());
    }
    outln!(
        "system {} (prefix {}, supervisor pid {}, up {}){}",
        doc.system,
        doc.prefix,
        doc.supervisor_pid,
        human_ms(doc.uptime_ms),
        if doc.shutting_down { ", stopping" } else { "" }
    )?;
    outln!(
        "{:<16} {:<12} {:>8} {:>9} {:>8} {:>6} {:>9}  {:<18} LAST EXIT",
        "MODULE",
        "STATE",
        "PID",
        "UPTIME",
        "RESTARTS",
        "CPU%",
        "RSS",
        "CAPS"
    )?;
    for m in &doc.modules {
        let state = match m.restart_in_ms {
            Some(t) if m.state == "backing-off" => format!("backing-off ({})", human_ms(t)),
            _ => m.state.clone(),
        };
        let r = resources(&m.name);
        let cpu = r["cpu_percent"]
            .as_f64()
            .map_or_else(|| "-".to_owned(), |c| format!("{c:.1}"));
        let rss = r["rss_bytes"].as_f64().map_or_else(
            || "-".to_owned(),
            |b| format!("{:.1}M", b / (1024.0 * 1024.0)),
        );
        outln!(
            "{:<16} {:<12} {:>8} {:>9} {:>8} {:>6} {:>9}  {:<18} {}",
            format!("{}{}", m.name, if m.manager { "*" } else { "" }),
            state,
            m.pid.map_or_else(|| "-".to_owned(), |p| p.to_string()),
            m.uptime_ms.map_or_else(|| "-".to_owned(), human_ms),
            m.restarts,
            cpu,
            rss,
            m.caps
                .as_ref()
                .map_or_else(|| "-".to_owned(), hng_supervisor::status::CapsRow::short),
            m.last_exit_text.as_deref().unwrap_or("-"),
        )?;
    }
    Ok(())
}

fn human_ms(ms: f64) -> String {
    if ms < 1e3 {
        format!("{ms:.0}ms")
    } else if ms < 120e3 {
        format!("{:.1}s", ms / 1e3)
    } else if ms < 7200e3 {
        format!("{:.0}m", ms / 60e3)
    } else {
        format!("{:.1}h", ms / 3600e3)
    }
}

/// Parses a signal given as a name (`KILL`, `SIGKILL`, `segv`) or a number (`9`).
pub fn parse_signal(s: &str) -> Result<Signal> {
    let t = s.trim();
    if let Ok(n) = t.parse::<i32>() {
        return Signal::try_from(n).map_err(|_| anyhow::anyhow!("{n} is not a signal number"));
    }
    let upper = t.to_ascii_uppercase();
    let name = if upper.starts_with("SIG") {
        upper
    } else {
        format!("SIG{upper}")
    };
    Signal::from_str(&name).map_err(|_| {
        anyhow::anyhow!(
            "{s:?} is not a signal: give a name such as KILL, TERM, SEGV, STOP or a number"
        )
    })
}

/// `hng kill MODULE [--signal SIG]`.
pub fn kill(prefix: &str, module: &str, signal: &str) -> Result<()> {
    let sig = parse_signal(signal)?;
    let mut cmd = SupervisorCommand::new(CommandOp::Kill, module);
    cmd.signal = sig as i32;
    let doc = command(prefix, cmd, "hng-kill")?;
    let pid = doc.module(module).and_then(|m| m.pid);
    println!(
        "sent {} to {module}{}",
        sig.as_str(),
        pid.map(|p| format!(" (pid {p})")).unwrap_or_default()
    );
    Ok(())
}

/// `hng restart MODULE`.
pub fn restart(prefix: &str, module: &str) -> Result<()> {
    command(
        prefix,
        SupervisorCommand::new(CommandOp::Restart, module),
        "hng-restart",
    )?;
    println!("restarting {module}");
    Ok(())
}

/// `hng start MODULE`.
pub fn start(prefix: &str, module: &str) -> Result<()> {
    command(
        prefix,
        SupervisorCommand::new(CommandOp::Start, module),
        "hng-start",
    )?;
    println!("starting {module}");
    Ok(())
}

/// `hng stop [MODULE]`: one module, or the whole system.
pub fn stop(prefix: &str, module: Option<&str>) -> Result<()> {
    match module {
        Some(m) => {
            command(
                prefix,
                SupervisorCommand::new(CommandOp::Stop, m),
                "hng-stop",
            )?;
            println!("stopping {m}");
        }
        None => {
            let doc = command(
                prefix,
                SupervisorCommand::new(CommandOp::Shutdown, ""),
                "hng-stop",
            )?;
            println!(
                "stopping system {} (supervisor pid {})",
                doc.system, doc.supervisor_pid
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signals_by_name_or_number() {
        assert_eq!(parse_signal("KILL").ok(), Some(Signal::SIGKILL));
        assert_eq!(parse_signal("sigsegv").ok(), Some(Signal::SIGSEGV));
        assert_eq!(parse_signal("STOP").ok(), Some(Signal::SIGSTOP));
        assert_eq!(parse_signal("9").ok(), Some(Signal::SIGKILL));
        assert!(parse_signal("NOPE").is_err());
        assert!(parse_signal("999").is_err());
    }
}
