//! Launch files: which modules a system runs and how they are supervised.
//!
//! Two stages, as in ripgrep's CLI: a serde mirror of what the user wrote
//! (`deny_unknown_fields`, every value [`Spanned`] so it keeps its position),
//! then a validated [`LaunchPlan`] the [`Supervisor`](crate::Supervisor)
//! consumes. Every problem found is reported with file, line, column and
//! field, all at once, before anything starts.
//!
//! Durations are seconds, as numbers, in keys ending in `_s` (as in every configuration of
//! hng): not negative, not NaN or infinite. A key of the old spelling (`heartbeat_period =
//! "100ms"`) is reported with its new name and the value to write.
//!
//! # Format
//!
//! ```toml
//! system = "explorer"                 # required: name of the system
//! clock = "wall"                      # optional: "wall" (default) or "sim" (modules follow hng/clock)
//! checkpoint_dir = "/var/lib/hng/explorer" # optional: where modules keep checkpoints
//!                                     # (relative to this file; default: the run directory)
//!
//! [defaults]                          # optional: applies to every module
//! restart = "on-failure"              # always | on-failure | never
//! backoff_initial_s = 0.1             # 2nd consecutive restart waits this (1st is immediate)
//! backoff_max_s = 10.0                # doubling stops here
//! backoff_reset_after_s = 30.0        # a run this long resets the backoff
//! give_up_failures = 5                # more than 5 restarts ...
//! give_up_window_s = 60.0             # ... within 60 s => module Deactivated
//! heartbeat_period_s = 0.1            # or "off" (default): no hang detection
//! heartbeat_timeout_s = 0.3           # default: 3 heartbeat periods
//! start_timeout_s = 5.0               # spawn -> first heartbeat
//! checkpoint_period_s = 1.0           # or "off" (default)
//! stop_timeout_s = 5.0                # SIGTERM -> SIGKILL
//! cpu_quota = 0.5                     # fraction of one CPU (or "50%")
//! memory_max = "512MiB"               # bytes, K/M/G/T (1024) or kB/MB/GB (1000); "max" = none
//! pids_max = 64
//! env = { RUST_LOG = "info" }
//!
//! [[module]]
//! name = "slam"                       # required: [A-Za-z0-9_-], unique
//! command = ["hng", "module", "slam"] # required: program + args
//! manager = false                     # at most one module has manager = true
//! needs = ["scan", "odom"]            # optional: start after the providers of these
//! provides = ["map", "pose"]
//! restart = "always"                  # any [defaults] key can be overridden here
//! memory_max = "1GiB"
//! env = { SLAM_THREADS = "2" }        # merged over [defaults].env
//!
//! [module.config]                     # optional: the module's own typed configuration,
//! resolution_m = 0.05                 # passed to it as TOML in HNG_MODULE_CONFIG
//! ```
//!
//! # Programs
//!
//! `command[0]` is resolved when the file is loaded:
//! - `"hng"` or `"@hng"` is the running `hng` executable
//!   ([`LoadOptions::self_exe`], by default [`std::env::current_exe`]), so
//!   `["hng", "module", "slam"]` runs the built-in module with the same binary
//!   as the supervisor. To run some other `hng` from `PATH`, give its path.
//! - A name containing `/` is a path; relative paths are relative to the
//!   launch file's directory.
//! - Any other name is looked up in `PATH` ([`LoadOptions::path`]).
//!
//! The resolved file must exist and be executable.
//!
//! # Start order
//!
//! Modules start in file order, except that a module that `needs` something
//! starts after every module that `provides` it. A cycle is an error. Stop
//! order is the reverse of start order.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use toml::Spanned;

pub use self::check::{ModuleCheck, ModuleProblem};
pub use self::error::{LaunchError, LaunchErrorKind, LaunchErrors};
use self::parse::{Cx, key_at};
pub use self::parse::{line_col, load, parse};
use self::raw::RawModule;

// ---------------------------------------------------------------------------
// Validated plan
// ---------------------------------------------------------------------------

/// What to do when a module's process ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// Restart after every exit, even `exit(0)`.
    Always,
    /// Restart unless the process exited with status 0.
    OnFailure,
    /// Never restart.
    Never,
}

/// Resource caps for the resource manager to apply (cgroups). The supervisor
/// itself does not enforce them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ResourceCaps {
    /// Fraction of one CPU (`0.5` = half a core, `2.0` = two cores).
    pub cpu_quota: Option<f64>,
    /// Hard memory limit in bytes.
    pub memory_max: Option<u64>,
    /// Maximum number of tasks (processes and threads).
    pub pids_max: Option<u64>,
}

/// Hang detection parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct HeartbeatSpec {
    /// How often the module sends a heartbeat.
    #[serde(rename = "period_s", serialize_with = "seconds")]
    pub period: Duration,
    /// A module silent for longer than this is killed (cause `Hang`).
    #[serde(rename = "timeout_s", serialize_with = "seconds")]
    pub timeout: Duration,
}

/// One module, validated and ready for the supervisor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModuleSpec {
    /// Unique name, `[A-Za-z0-9_-]+`.
    pub name: String,
    /// Resolved absolute path of the executable.
    pub program: PathBuf,
    /// Arguments after the program.
    pub args: Vec<String>,
    /// Extra environment (defaults merged with the module's own).
    pub env: BTreeMap<String, String>,
    /// Is this the system's Manager module?
    pub manager: bool,
    /// Restart policy.
    pub restart: RestartPolicy,
    /// Delay before the second consecutive restart; doubles each time after.
    #[serde(rename = "backoff_initial_s", serialize_with = "seconds")]
    pub backoff_initial: Duration,
    /// Cap of the restart delay.
    #[serde(rename = "backoff_max_s", serialize_with = "seconds")]
    pub backoff_max: Duration,
    /// A process that ran at least this long resets the backoff.
    #[serde(rename = "backoff_reset_after_s", serialize_with = "seconds")]
    pub backoff_reset_after: Duration,
    /// More than this many automatic restarts within `give_up_window` deactivates the module.
    pub give_up_failures: u32,
    /// Window of the give-up rule.
    #[serde(rename = "give_up_window_s", serialize_with = "seconds")]
    pub give_up_window: Duration,
    /// `None`: no hang detection.
    pub heartbeat: Option<HeartbeatSpec>,
    /// Spawn to first heartbeat, when heartbeats are on.
    #[serde(rename = "start_timeout_s", serialize_with = "seconds")]
    pub start_timeout: Duration,
    /// How often the module should checkpoint (passed to it in `HNG_CHECKPOINT_PERIOD_MS`).
    #[serde(rename = "checkpoint_period_s", serialize_with = "seconds_or_off")]
    pub checkpoint_period: Option<Duration>,
    /// SIGTERM to SIGKILL.
    #[serde(rename = "stop_timeout_s", serialize_with = "seconds")]
    pub stop_timeout: Duration,
    /// Caps for the resource manager.
    pub resources: ResourceCaps,
    /// Names this module needs (start ordering).
    pub needs: Vec<String>,
    /// Names this module provides.
    pub provides: Vec<String>,
    /// The module's `config` table as TOML text (empty: none); passed in `HNG_MODULE_CONFIG`.
    pub config: String,
}

impl ModuleSpec {
    /// A spec with the documented defaults, for programmatic use and tests.
    pub fn new(name: impl Into<String>, program: impl Into<PathBuf>, args: &[&str]) -> Self {
        Self {
            name: name.into(),
            program: program.into(),
            args: args.iter().map(|s| (*s).to_owned()).collect(),
            env: BTreeMap::new(),
            manager: false,
            restart: RestartPolicy::OnFailure,
            backoff_initial: DEFAULT_BACKOFF_INITIAL,
            backoff_max: DEFAULT_BACKOFF_MAX,
            backoff_reset_after: DEFAULT_BACKOFF_RESET_AFTER,
            give_up_failures: DEFAULT_GIVE_UP_FAILURES,
            give_up_window: DEFAULT_GIVE_UP_WINDOW,
            heartbeat: None,
            start_timeout: DEFAULT_START_TIMEOUT,
            checkpoint_period: None,
            stop_timeout: DEFAULT_STOP_TIMEOUT,
            resources: ResourceCaps::default(),
            needs: Vec::new(),
            provides: Vec::new(),
            config: String::new(),
        }
    }
}

/// A duration as seconds (the files' convention) in the plan `hng run --check` prints.
fn seconds<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// [`seconds`], or `"off"`.
fn seconds_or_off<S: serde::Serializer>(d: &Option<Duration>, s: S) -> Result<S::Ok, S::Error> {
    match d {
        Some(d) => seconds(d, s),
        None => s.serialize_str("off"),
    }
}

/// Default of `backoff_initial`.
pub const DEFAULT_BACKOFF_INITIAL: Duration = Duration::from_millis(100);
/// Default of `backoff_max`.
pub const DEFAULT_BACKOFF_MAX: Duration = Duration::from_secs(10);
/// Default of `backoff_reset_after`.
pub const DEFAULT_BACKOFF_RESET_AFTER: Duration = Duration::from_secs(30);
/// Default of `give_up_failures` (systemd's StartLimitBurst).
pub const DEFAULT_GIVE_UP_FAILURES: u32 = 5;
/// Default of `give_up_window`.
pub const DEFAULT_GIVE_UP_WINDOW: Duration = Duration::from_secs(60);
/// Default of `start_timeout`.
pub const DEFAULT_START_TIMEOUT: Duration = Duration::from_secs(5);
/// Default of `stop_timeout`.
pub const DEFAULT_STOP_TIMEOUT: Duration = Duration::from_secs(5);
/// `heartbeat_timeout` defaults to this many periods.
pub const DEFAULT_HEARTBEAT_TIMEOUT_PERIODS: u32 = 3;

/// A validated launch file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LaunchPlan {
    /// The file it came from.
    pub file: PathBuf,
    /// Name of the system.
    pub system: String,
    /// Modules in start order.
    pub modules: Vec<ModuleSpec>,
    /// The modules run on the simulated clock (`clock = "sim"`: `HNG_CLOCK=sim`).
    pub sim_clock: bool,
    /// Where checkpoints go (`checkpoint_dir`, resolved against the file's folder);
    /// `None`: the runner's default (its run directory).
    pub checkpoint_dir: Option<PathBuf>,
    /// Problems that do not prevent starting (e.g. a need nobody provides).
    pub warnings: Vec<String>,
}

/// How `command[0]` is resolved.
#[derive(Clone)]
pub struct LoadOptions {
    /// What `hng` / `@hng` means; `None`: [`std::env::current_exe`].
    pub self_exe: Option<PathBuf>,
    /// Search path for bare program names; `None`: the `PATH` variable.
    pub path: Option<OsString>,
    /// Check that programs exist and are executable.
    pub check_binaries: bool,
    /// Check every module whose program was resolved (see [`ModuleCheck`]).
    pub check_module: Option<ModuleCheck>,
}

impl fmt::Debug for LoadOptions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LoadOptions")
            .field("self_exe", &self.self_exe)
            .field("path", &self.path)
            .field("check_binaries", &self.check_binaries)
            .field("check_module", &self.check_module.is_some())
            .finish()
    }
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            self_exe: None,
            path: None,
            check_binaries: true,
            check_module: None,
        }
    }
}

mod check;
mod error;
mod parse;
mod raw;
mod renamed;
mod settings;
#[cfg(test)]
mod tests;
