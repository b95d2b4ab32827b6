//! hng's integration tests: real processes, each test under its own shared-memory prefix.

mod common;
mod dataplane;
mod sdk;
