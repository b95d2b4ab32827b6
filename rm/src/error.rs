//! Errors of the resource manager crate.

use std::path::PathBuf;

/// Everything that can go wrong in `hng-rm`. Each variant names what it was
/// working on (file, module, pid) so the message is useful on its own.
#[derive(Debug, thiserror::Error)]
pub enum RmError {
    /// A file under /proc or a cgroup file system could not be read or written.
    #[error("{op} {path}: {source}")]
    Io {
        /// What was attempted ("read", "write", "create directory", ...).
        op: &'static str,
        /// The file or directory.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// A file had content we could not understand.
    #[error("cannot parse {path}: {what}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What was wrong with it.
        what: String,
    },
    /// The process to sample does not exist (anymore).
    #[error("process {pid} of module '{module}' does not exist")]
    NoSuchProcess {
        /// Module name.
        module: String,
        /// Its pid.
        pid: i32,
    },
    /// The pid now belongs to another process than the one expected.
    #[error(
        "pid {pid} of module '{module}' was reused: start time {found} ticks, expected {expected}"
    )]
    PidReused {
        /// Module name.
        module: String,
        /// The pid.
        pid: i32,
        /// Expected start time (clock ticks after boot).
        expected: u64,
        /// Start time found in /proc.
        found: u64,
    },
    /// A module with this name is already sampled or already has a cgroup.
    #[error("module '{0}' is already registered")]
    Duplicate(String),
    /// A name that cannot be used as a cgroup directory name.
    #[error("invalid name '{name}' for a cgroup: {why}")]
    InvalidName {
        /// The name.
        name: String,
        /// Why it was rejected.
        why: &'static str,
    },
    /// No writable cgroup hierarchy: limits are enforced in software.
    #[error(
        "no writable cgroup controller ({0}); measuring only; limits enforced by stopping a module over its limit"
    )]
    NoCgroups(String),
    /// The kernel refused a cap (too small a quota, EINVAL, EACCES, ...).
    #[error(
        "kernel refused {cap} for module '{module}': {why}; falling back to stopping the module over its limit"
    )]
    CapRefused {
        /// Module.
        module: String,
        /// Which cap ("cpu quota 0.05%", "memory limit 1 KiB", ...).
        cap: String,
        /// Why.
        why: String,
    },
    /// A cgroup could not be removed because it still holds processes.
    #[error("cgroup {path} still holds processes: kill them and wait for them before removing it")]
    CgroupBusy {
        /// The cgroup directory.
        path: PathBuf,
    },
    /// A module's provider is not in the contract graph.
    #[error("module '{module}' lists provider '{provider}', which is not in the contract graph")]
    UnknownProvider {
        /// The client module.
        module: String,
        /// The missing provider.
        provider: String,
    },
    /// The contract graph has a cycle (it must be a tree / DAG).
    #[error("contract graph has a cycle: {}", .0.join(" -> "))]
    Cycle(Vec<String>),
    /// The same module appears twice in the contract graph.
    #[error("module '{0}' appears twice in the contract graph")]
    DuplicateModule(String),
    /// A configuration value is out of range.
    #[error("invalid configuration: {0}")]
    Config(String),
}

impl RmError {
    pub(crate) fn io(op: &'static str, path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        RmError::Io {
            op,
            path: path.into(),
            source,
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = RmError> = std::result::Result<T, E>;
