//! The supervisor host of hng (paper 5.4) as a library: what `hng run` is once its arguments
//! are parsed.
//!
//! - [`host`]: starts the modules of a launch plan under the watchdog's [`hng_watchdog::Supervisor`]
//!   (cgroups from the resource manager's crate, the run's log files), publishes supervisor
//!   events and the status document, executes the commands of `hng kill/restart/start/stop`
//!   and stops the system in order;
//! - [`status`]: the status document, typed (the schema is the runtime's
//!   [`hng_runtime::system::status`], which the resource manager, `hng ps`/`hng top` and the
//!   operator page read), and its reader;
//! - [`mission`] and [`monitor`]: the built-in mission (its launch plan, world, goals) and the
//!   monitor that follows it and writes its summary;
//! - [`lock`]: one system per prefix; [`logs`]: the run's quiet terminal and its log files;
//!   [`doc`]: reading JSON documents from state channels.
//!
//! The `hng` binary parses arguments, calls this crate and prints what it returns.

pub mod control;
pub mod doc;
pub mod error;
mod hooks;
pub mod host;
pub mod lock;
pub mod logs;
pub mod mission;
pub mod monitor;
mod nav_watch;
mod receiver;
pub mod status;
pub mod stdout;

pub use error::{HostError, Result};
pub use host::{Companion, HostOptions, RunPaths, default_run_dir, supervise};
pub use receiver::block_termination_signals;
