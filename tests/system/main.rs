//! hng's integration tests: real processes, each test under its own shared-memory prefix.

mod common;
mod contracts;
mod dataplane;
mod eval;
mod faults;
mod mission;
mod mission_cmd;
mod modules;
mod recording;
mod rm;
mod sdk;
mod sim;
mod topic;
