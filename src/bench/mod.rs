//! Benchmark drivers behind `hng bench NAME [--json]`.
//!
//! Every bench prints one JSON object per case with at least `bench`, `case`, `p50_ns`,
//! `p99_ns`, `p999_ns`, `max_ns`, `samples`, plus its own fields; without `--json` a table.

use anyhow::Result;
use clap::Subcommand;
use hng_runtime::stats::{BenchRow, table};

pub mod affinity;
pub mod browsers;
pub mod contracts;
pub mod gui;
pub mod idle;
pub mod ipc;
pub mod loop_;
pub mod record;
pub mod recovery;
pub mod rm;
pub mod sim;
pub mod vision;
pub mod walls;

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Two-process ping-pong latency: hng channels vs raw iceoryx2 vs Unix sockets.
    Ipc(ipc::IpcArgs),
    /// Contracts: 15-module tree set-up, switch after SIGKILL, one query among N candidates.
    Contracts(contracts::ContractsArgs),
    /// Simulator: one 360-beam lidar scan among 100 walls, and headless simulation speed.
    Sim(sim::SimArgs),
    /// Resource manager: CPU cost of sampling N = 10, 50, 200 processes at 10 Hz.
    Rm(rm::RmArgs),
    /// Watchdog: SIGKILL/SIGSTOP of a module to detection, restart and first message.
    Recovery(recovery::RecoveryArgs),
    /// Control loop across processes: lidar scan -> Security decision -> command out of Robot.
    Loop(loop_::LoopArgs),
    /// Flight recorder: 64 B and 1 MiB messages to an MCAP file, MB/s and drops.
    Record(record::BenchRecordArgs),
    /// Camera images and trackers: render per frame, each tracker per frame, 230 KB image hop.
    Vision(vision::VisionArgs),
    /// Idle cost: wake-ups and CPU of a module with no input, and of the default system at 1x.
    Idle(idle::IdleArgs),
    /// Wall detection per 360-beam scan (split-and-merge).
    Walls(walls::WallsArgs),
    /// Operator page: scan-to-WebSocket-send latency at 10 Hz with 1 and 3 clients.
    Gui(gui::GuiBenchArgs),
}

/// The hng executable `exe` as a bench starts it: no input, no output, its log at `HNG_LOG`'s
/// level (`warn` when unset).
pub(crate) fn quiet_hng(exe: &std::path::Path) -> std::process::Command {
    let mut cmd = std::process::Command::new(exe);
    cmd.env(
        "HNG_LOG",
        std::env::var("HNG_LOG").unwrap_or_else(|_| "warn".into()),
    )
    .stdin(std::process::Stdio::null())
    .stdout(std::process::Stdio::null());
    cmd
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
        BenchCommand::Contracts(args) => contracts::run(&args),
        BenchCommand::Sim(args) => sim::run(&args),
        BenchCommand::Rm(args) => rm::run(&args),
        BenchCommand::Recovery(args) => recovery::run(&args),
        BenchCommand::Loop(args) => loop_::run(&args),
        BenchCommand::Record(args) => record::run(&args),
        BenchCommand::Vision(args) => vision::run(&args),
        BenchCommand::Idle(args) => idle::run(&args),
        BenchCommand::Walls(args) => walls::run(&args),
        BenchCommand::Gui(args) => gui::run(&args),
    }
}
