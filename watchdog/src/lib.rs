//! hng-watchdog: the supervision core of hng (HNG paper, section 5.4).
//!
//! - [`launch`]: launch files (TOML) parsed into a validated [`LaunchPlan`].
//! - [`Supervisor`]: spawns module processes, detects their exits through
//!   pidfds without polling delay, classifies the cause, detects hangs from
//!   heartbeats the caller feeds, restarts with exponential backoff and
//!   deactivates modules that fail too often. It is an event loop the caller
//!   drives with [`Supervisor::poll`].
//! - [`systemd`]: `sd_notify` readiness, watchdog and stopping messages.
//!
//! Linux only (pidfd_open needs Linux 5.3).

pub mod launch;
pub mod logs;
mod supervisor;
mod sys;
pub mod systemd;
pub mod units;

pub use launch::{
    HeartbeatSpec, LaunchError, LaunchErrorKind, LaunchErrors, LaunchPlan, LoadOptions, ModuleSpec,
    ResourceCaps, RestartPolicy,
};
pub use nix::sys::signal::Signal;
pub use supervisor::{
    Event, EventKind, ExitCause, ModuleState, ModuleStatus, NoHooks, Supervisor, SupervisorError,
    SupervisorHooks, SupervisorOptions, Waker,
};
