//! `hng`: run, inspect and benchmark an hng robot system.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod bench;
mod modules;
mod topic;

/// hng: a runtime for robot control architectures (HNG: processes, zero-copy channels,
/// contracts).
#[derive(Debug, Parser)]
#[command(name = "hng", version, about, long_about = None)]
struct Cli {
    /// Prefix of the system to talk to (isolates systems and tests from each other).
    #[arg(long, global = true, env = "HNG_PREFIX", default_value = hng_runtime::channel::DEFAULT_PREFIX)]
    prefix: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Inspect channels of a running system.
    Topic {
        #[command(subcommand)]
        command: topic::TopicCommand,
    },
    /// Run a benchmark and print one JSON object per case (with --json) or a table.
    Bench {
        #[command(subcommand)]
        bench: bench::BenchCommand,
    },
    /// Run a built-in module as this process (what launch files start).
    Module {
        /// The module's name.
        name: String,
    },
    /// The peer side of a two-process benchmark (started by `hng bench`).
    #[command(hide = true, name = "__bench-peer")]
    BenchPeer(bench::ipc::PeerArgs),
}

fn main() -> ExitCode {
    hng_runtime::module::init_tracing();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Module { name } => return modules::run(&name),
        Command::Topic { command } => topic::run(&cli.prefix, command),
        Command::Bench { bench } => bench::run(bench),
        Command::BenchPeer(args) => bench::ipc::peer(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hng: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
