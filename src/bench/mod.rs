//! Benchmark drivers behind `hng bench NAME [--json]`.
//!
//! Every bench prints one JSON object per case with at least `bench`, `case`, `p50_ns`,
//! `p99_ns`, `p999_ns`, `max_ns`, `samples`, plus its own fields; without `--json` a table.

use anyhow::Result;
use clap::Subcommand;
use hng_runtime::stats::{BenchRow, table};

pub mod ipc;

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Two-process ping-pong latency: hng channels vs raw iceoryx2 vs Unix sockets.
    Ipc(ipc::IpcArgs),
}

/// Prints rows as JSON lines or as a table.
pub fn print_rows(rows: &[BenchRow], json: bool) {
    if json {
        for r in rows {
            println!("{}", r.to_json());
        }
    } else {
        print!("{}", table(rows));
    }
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Ipc(args) => ipc::run(&args),
    }
}
