//! hng runtime: the module SDK, the zero-copy data plane, the common clock, contracts and
//! checkpoints. A module author needs only this crate.
//!
//! - [`msg`]: fixed-size robotics messages (REP-103 units and frames) and slice headers.
//! - [`channel`]: typed publish/subscribe over iceoryx2 shared memory.
//! - [`wait`]: waiting on many inputs without polling (adaptive spin, then sleep).
//! - [`cpus`]: sharing the CPUs between the spinning waiters of one system.
//! - [`module`]: the [`Module`] trait and [`run_module`].
//! - [`clock`]: the common clock (wall or simulated).
//! - [`contract`]: the Contract-Net protocol logic.
//! - [`control`]: contracts between processes: the control channels, provider inputs.
//! - [`checkpoint`]: atomic, checksummed checkpoint files.
//! - [`map`]: occupancy grids and map_server map files.
//! - [`fatal`]: SIGSEGV and SIGBUS sent by `kill` end the process on the first delivery.

pub mod channel;
pub mod checkpoint;
pub mod clock;
pub mod contract;
pub mod control;
pub mod cpus;
mod error;
pub mod fatal;
pub mod harness;
pub mod map;
pub mod module;
pub mod msg;
pub mod qos;
pub mod shm;
pub mod stats;
pub mod system;
pub mod wait;
mod wake;

pub use channel::{Node, NodeOptions, Publisher, SlicePublisher, SliceSubscriber, Subscriber};
pub use error::Error;
pub use module::{
    Context, Module, ModuleResult, RunOptions, TimerId, run_module, run_module_on_wall_clock,
    run_module_with,
};

/// The README's module example, compiled as a doc test (`cargo test -p hng-runtime --doc`).
#[cfg(doctest)]
#[doc = include_str!("../../README.md")]
pub struct ReadmeExamples;

/// docs/writing-a-module.md's complete module, compiled as a doc test.
#[cfg(doctest)]
#[doc = include_str!("../../docs/writing-a-module.md")]
pub struct WritingAModuleExamples;
