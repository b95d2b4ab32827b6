//! How a supervisor is set up: options, hooks, errors and its waker.

use std::collections::BTreeMap;
use std::io;
use std::process::Command;
use std::sync::Arc;

use crate::launch::ModuleSpec;
use crate::logs::LogOptions;
use crate::sys::EventFd;

use super::ModuleState;

/// Supervisor errors; each names the module concerned.
#[derive(Debug, thiserror::Error)]
pub enum SupervisorError {
    /// No module of that name.
    #[error("no module named {name:?} in this system")]
    UnknownModule {
        /// The name asked for.
        name: String,
    },
    /// Two specs with the same name.
    #[error("module {name:?} is defined twice")]
    DuplicateModule {
        /// The name.
        name: String,
    },
    /// The module has no live process.
    #[error("module {name:?} has no running process (state: {state})")]
    NotRunning {
        /// The module.
        name: String,
        /// Its state.
        state: ModuleState,
    },
    /// Sending a signal failed.
    #[error("sending {signal} to module {name:?} (pid {pid}) failed: {source}")]
    Signal {
        /// The module.
        name: String,
        /// Its pid.
        pid: u32,
        /// The signal.
        signal: String,
        /// The OS error.
        #[source]
        source: io::Error,
    },
    /// An OS call of the event loop failed.
    #[error("supervisor {op} failed: {source}")]
    Io {
        /// The call.
        op: &'static str,
        /// The OS error.
        #[source]
        source: io::Error,
    },
}

/// Caller hooks. Every method has a default that does nothing.
pub trait SupervisorHooks {
    /// Called before every spawn with the ready-to-spawn command: add
    /// environment variables or a `pre_exec` step (e.g. writing `0` to an
    /// already opened `cgroup.procs` so the child is charged to its cgroup
    /// from its first page). An error counts as a spawn failure.
    fn before_spawn(&mut self, module: &ModuleSpec, command: &mut Command) -> io::Result<()> {
        let _ = (module, command);
        Ok(())
    }

    /// Called right before a module is spawned again, with the pid of its
    /// previous (dead, reaped) process: the place to clean stale iceoryx2
    /// resources of that pid.
    fn before_restart(&mut self, module: &ModuleSpec, dead_pid: u32) {
        let _ = (module, dead_pid);
    }

    /// Called when a process died of a SIGKILL the supervisor did not send:
    /// return true if it was the OOM killer (e.g. `memory.events` `oom_kill`
    /// went up in the module's cgroup).
    fn oom_killed(&mut self, module: &ModuleSpec, pid: u32) -> bool {
        let _ = (module, pid);
        false
    }
}

/// Hooks that do nothing.
#[derive(Debug, Default, Clone, Copy)]
pub struct NoHooks;

impl SupervisorHooks for NoHooks {}

/// Process-level settings for all modules.
#[derive(Debug, Clone)]
pub struct SupervisorOptions {
    /// Extra environment for every module (e.g. `HNG_PREFIX`).
    pub env: BTreeMap<String, String>,
    /// Put each module in its own process group (default true): terminal
    /// signals (Ctrl-C) reach only the supervisor, which stops modules in
    /// order, and after a module's main process dies, leftovers in its group
    /// are SIGKILLed.
    pub process_group: bool,
    /// `PR_SET_PDEATHSIG(SIGKILL)` in each child (default true): modules die
    /// if the thread that spawned them dies, so a crashed supervisor leaves
    /// no orphans. Drive the supervisor from a thread that lives as long as it.
    pub kill_on_supervisor_exit: bool,
    /// Where modules' stdout and stderr go: per-module, size-bounded files
    /// ([`crate::logs`]); `None` (the default): inherited from the supervisor.
    pub logs: Option<LogOptions>,
}

impl Default for SupervisorOptions {
    fn default() -> Self {
        Self {
            env: BTreeMap::new(),
            process_group: true,
            kill_on_supervisor_exit: true,
            logs: None,
        }
    }
}

/// Wakes a blocked [`Supervisor::poll`] from another thread.
#[derive(Debug, Clone)]
pub struct Waker(pub(crate) Arc<EventFd>);

impl Waker {
    /// Make the current or next `poll` return promptly.
    pub fn wake(&self) -> io::Result<()> {
        self.0.signal()
    }
}
