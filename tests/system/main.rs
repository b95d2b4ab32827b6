//! hng's integration tests: real processes, each test under its own shared-memory prefix.

mod chaos;
mod cli;
mod common;
mod contracts;
mod dataplane;
mod eval;
mod fault_matrix;
mod faults;
mod gui;
mod lockstep;
mod long_compute;
mod mission;
mod mission_cmd;
mod modules;
mod orders;
mod recording;
mod rm;
mod sdk;
mod signals;
mod sim;
mod slam_loop;
mod teleop;
mod topic;
mod vision;
