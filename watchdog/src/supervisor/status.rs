//! What the supervisor reports: module states, exit causes, events and status rows.

use std::fmt;
use std::os::unix::process::ExitStatusExt;
use std::process::ExitStatus;
use std::time::{Duration, Instant};

use nix::sys::signal::Signal;
use serde::Serialize;

/// Serialize a `Duration` as floating-point milliseconds (for JSON).
mod ms {
    use serde::Serializer;
    use std::time::Duration;

    pub fn serialize<S: Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(d.as_secs_f64() * 1e3)
    }

    pub mod opt {
        use serde::Serializer;
        use std::time::Duration;

        pub fn serialize<S: Serializer>(d: &Option<Duration>, s: S) -> Result<S::Ok, S::Error> {
            match d {
                Some(d) => s.serialize_some(&(d.as_secs_f64() * 1e3)),
                None => s.serialize_none(),
            }
        }
    }
}

/// Why a module process ended.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ExitCause {
    /// It called `exit(code)`.
    Exited {
        /// Exit status.
        code: i32,
    },
    /// A signal killed it (that the supervisor did not send for a hang, a
    /// limit or a stop; `kill()` fault injection shows up here).
    Signaled {
        /// `SIGSEGV`, `SIGKILL`, ...
        signal: String,
        /// Signal number.
        number: i32,
        /// A core dump was written.
        core_dumped: bool,
    },
    /// The kernel OOM killer (as reported by [`SupervisorHooks::oom_killed`]).
    OomKilled,
    /// No heartbeat within the timeout; the supervisor sent SIGKILL.
    Hang {
        /// Time since the last heartbeat (or since spawn) when detected.
        #[serde(rename = "silent_for_ms", with = "ms")]
        silent_for: Duration,
    },
    /// Killed at the caller's request for exceeding a resource limit.
    OverLimit {
        /// The caller's reason, e.g. "memory 600 MiB > 512 MiB".
        reason: String,
    },
    /// Did not exit within `stop_timeout` after SIGTERM; SIGKILLed.
    StopTimeout,
    /// The process could not be started.
    SpawnFailed {
        /// The OS error.
        error: String,
    },
    /// The exit status could not be collected.
    Unknown {
        /// Why.
        error: String,
    },
}

impl ExitCause {
    /// Everything except `exit(0)` is a failure (for `on-failure`).
    pub fn is_failure(&self) -> bool {
        !matches!(self, Self::Exited { code: 0 })
    }

    pub(crate) fn from_status(status: ExitStatus) -> Self {
        if let Some(code) = status.code() {
            return Self::Exited { code };
        }
        if let Some(number) = status.signal() {
            return Self::Signaled {
                signal: signal_name(number),
                number,
                core_dumped: status.core_dumped(),
            };
        }
        Self::Unknown {
            error: format!("unrecognised wait status {status:?}"),
        }
    }
}

/// `SIGSEGV` for 11, `SIG42` for an unnamed (real-time) signal.
pub fn signal_name(number: i32) -> String {
    Signal::try_from(number).map_or_else(|_| format!("SIG{number}"), |s| s.as_str().to_owned())
}

impl fmt::Display for ExitCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Exited { code } => write!(f, "exited with code {code}"),
            Self::Signaled {
                signal,
                core_dumped,
                ..
            } => write!(
                f,
                "killed by {signal}{}",
                if *core_dumped { " (core dumped)" } else { "" }
            ),
            Self::OomKilled => write!(f, "killed by the OOM killer"),
            Self::Hang { silent_for } => write!(
                f,
                "hang: no heartbeat for {:.0} ms, SIGKILLed",
                silent_for.as_secs_f64() * 1e3
            ),
            Self::OverLimit { reason } => write!(f, "killed over limit: {reason}"),
            Self::StopTimeout => write!(f, "ignored SIGTERM, SIGKILLed after the stop timeout"),
            Self::SpawnFailed { error } => write!(f, "could not start: {error}"),
            Self::Unknown { error } => write!(f, "unknown exit: {error}"),
        }
    }
}

/// Lifecycle state of a module.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ModuleState {
    /// Spawned, no heartbeat yet (only with heartbeats configured).
    Starting,
    /// Alive (and heartbeating, if configured).
    Running,
    /// SIGTERM sent, waiting for exit (then SIGKILL).
    Stopping,
    /// Dead, waiting for its restart delay.
    BackingOff,
    /// Gave up: too many failures within the window. `start`/`restart` revive it.
    Deactivated,
    /// Not running and not going to be restarted.
    Stopped,
}

impl fmt::Display for ModuleState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Starting => "starting",
            Self::Running => "running",
            Self::Stopping => "stopping",
            Self::BackingOff => "backing-off",
            Self::Deactivated => "deactivated",
            Self::Stopped => "stopped",
        })
    }
}

/// Something that happened to a module.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum EventKind {
    /// A process was spawned.
    Started {
        /// Its pid.
        pid: u32,
        /// Restarts of this module before this start.
        restarts: u32,
    },
    /// First heartbeat after a start.
    Running {
        /// Its pid.
        pid: u32,
    },
    /// Spawning failed (the failure then goes through the restart policy).
    SpawnFailed {
        /// The OS error.
        error: String,
    },
    /// No heartbeat within the timeout: SIGKILL sent.
    HangDetected {
        /// Its pid.
        pid: u32,
        /// Time since the last heartbeat (or since spawn).
        #[serde(rename = "silent_for_ms", with = "ms")]
        silent_for: Duration,
    },
    /// SIGTERM sent (stop, restart or shutdown).
    StopRequested {
        /// Its pid.
        pid: u32,
    },
    /// `stop_timeout` elapsed after SIGTERM: SIGKILL sent.
    StopTimedOut {
        /// Its pid.
        pid: u32,
    },
    /// The process ended.
    Exited {
        /// Its pid.
        pid: u32,
        /// Why.
        cause: ExitCause,
        /// How long it ran.
        #[serde(rename = "uptime_ms", with = "ms")]
        uptime: Duration,
    },
    /// A restart is scheduled.
    Restarting {
        /// Delay before the spawn (zero: immediately).
        #[serde(rename = "delay_ms", with = "ms")]
        delay: Duration,
        /// Which restart this will be (1 for the first).
        attempt: u32,
    },
    /// The give-up rule fired: more than `give_up_failures` restarts within
    /// `give_up_window`. The module stays down until `start`/`restart`.
    Deactivated {
        /// Restarts counted in the window.
        failures: u32,
        /// The window.
        #[serde(rename = "window_ms", with = "ms")]
        window: Duration,
    },
    /// The module is down for good (policy, stop or shutdown).
    Stopped,
}

/// An [`EventKind`] with its module and monotonic time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Event {
    /// When the supervisor saw it (`Instant::now()` right after waking).
    #[serde(skip)]
    pub at: Instant,
    /// The module.
    pub module: String,
    /// What happened.
    #[serde(flatten)]
    pub kind: EventKind,
}

impl fmt::Display for Event {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = &self.module;
        match &self.kind {
            EventKind::Started { pid, restarts } => {
                write!(f, "{m}: started, pid {pid} (restarts so far: {restarts})")
            }
            EventKind::Running { pid } => write!(f, "{m}: running (first heartbeat), pid {pid}"),
            EventKind::SpawnFailed { error } => write!(f, "{m}: spawn failed: {error}"),
            EventKind::HangDetected { pid, silent_for } => write!(
                f,
                "{m}: hang detected, pid {pid} silent for {:.0} ms, sending SIGKILL",
                silent_for.as_secs_f64() * 1e3
            ),
            EventKind::StopRequested { pid } => write!(f, "{m}: SIGTERM sent to pid {pid}"),
            EventKind::StopTimedOut { pid } => {
                write!(f, "{m}: pid {pid} ignored SIGTERM, sending SIGKILL")
            }
            EventKind::Exited { pid, cause, uptime } => write!(
                f,
                "{m}: pid {pid} {cause} after {:.3} s",
                uptime.as_secs_f64()
            ),
            EventKind::Restarting { delay, attempt } => write!(
                f,
                "{m}: restart #{attempt} in {:.0} ms",
                delay.as_secs_f64() * 1e3
            ),
            EventKind::Deactivated { failures, window } => write!(
                f,
                "{m}: deactivated after {failures} failures within {:.1} s",
                window.as_secs_f64()
            ),
            EventKind::Stopped => write!(f, "{m}: stopped"),
        }
    }
}

/// One row of `hng ps`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModuleStatus {
    /// Module name.
    pub name: String,
    /// Lifecycle state.
    pub state: ModuleState,
    /// Current pid.
    pub pid: Option<u32>,
    /// Time since the current process started.
    #[serde(rename = "uptime_ms", with = "ms::opt")]
    pub uptime: Option<Duration>,
    /// Restarts since the module was (re)started by the user.
    pub restarts: u32,
    /// Why the previous process ended.
    pub last_exit: Option<ExitCause>,
    /// Age of the last heartbeat.
    #[serde(rename = "heartbeat_age_ms", with = "ms::opt")]
    pub heartbeat_age: Option<Duration>,
    /// Time left before a scheduled restart.
    #[serde(rename = "restart_in_ms", with = "ms::opt")]
    pub restart_in: Option<Duration>,
    /// The Manager module.
    pub manager: bool,
}
