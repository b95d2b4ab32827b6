//! hng runtime: the module SDK, zero-copy data plane, clock, contracts and checkpoints.

pub mod checkpoint;
pub mod contract;
