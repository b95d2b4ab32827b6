//! `hng`: run, inspect and benchmark an hng robot system.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// `println!` that returns the write's error (a closed pipe) instead of panicking.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*)
    }};
}

/// `print!` that returns the write's error instead of panicking.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        write!(std::io::stdout().lock(), $($arg)*)
    }};
}

use hng::bench;
mod behaviours;
mod contracts;
mod contracts_follow;
mod ctl;
mod eval;
mod eval_nav;
mod gui;
mod logs;
mod mission;
mod modules;
mod order;
mod probe;
mod recording;
mod run;
mod sim;
mod teleop;
mod tool;
mod top;
mod topic;
mod topic_pub;
mod validate;

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
    /// Evaluate an algorithm on recorded data (planner: MovingAI; SLAM: CARMEN log).
    Eval {
        #[command(subcommand)]
        command: eval::EvalCommand,
    },
    /// Show or change the running Manager's mission (goals).
    Mission {
        #[command(subcommand)]
        command: mission::MissionCommand,
    },
    /// Give the operator's order to the running Interface (stop, teleop, release, goal,
    /// waypoints, reach-beacon, follow-wall) and wait for its answer; `show` the order in force.
    Order {
        #[command(subcommand)]
        command: order::OrderCommand,
    },
    /// Drive the robot from the keyboard (arrows/WASD, space stops, q quits), with a deadman.
    Teleop(teleop::TeleopArgs),
    /// The behaviours attention offers now (follows the list; --json, --once).
    Behaviours(behaviours::BehavioursArgs),
    /// Run a built-in module as this process (what launch files start).
    Module {
        /// The module's name.
        name: String,
    },
    /// Start a system from a launch file (or the built-in default) and supervise it.
    Run(run::RunArgs),
    /// Show the modules of the running system: state, pid, uptime, restarts, last exit.
    Ps {
        /// One JSON document (the supervisor's status).
        #[arg(long)]
        json: bool,
    },
    /// Send a signal to a module (fault injection); the supervisor handles the outcome.
    Kill {
        /// The module.
        module: String,
        /// Signal name (KILL, SEGV, STOP, TERM, ...) or number.
        #[arg(long, short, default_value = "KILL")]
        signal: String,
    },
    /// Restart a module (maintenance: stop, start again; not counted as a failure).
    Restart {
        /// The module.
        module: String,
    },
    /// Start a stopped or deactivated module.
    Start {
        /// The module.
        module: String,
    },
    /// Stop one module, or without MODULE the whole system (orderly, reverse start order).
    Stop {
        /// The module (default: the whole system).
        module: Option<String>,
    },
    /// Live view of every module: state, CPU %, memory, caps, restarts, V, contracts,
    /// degraded mode and C_R (JSON snapshots when stdout is not a terminal; --text for text).
    Top(top::TopArgs),
    /// The live contract tree (client, provider, service, priority, V) and data network.
    Contracts(contracts::ContractsArgs),
    /// A module's log file from the last `hng run` on this prefix (`-f` follows); without a
    /// module, the list of log files.
    Logs(logs::LogsArgs),
    /// Print the iceoryx2 configuration (TOML) that reaches this prefix's channels, for
    /// iceoryx2's own tools: `hng iox2-config > config/iceoryx2.toml && iox2 service list`.
    #[command(name = "iox2-config")]
    Iox2Config,
    /// Simulator tools (ground-truth maps of worlds).
    Sim {
        #[command(subcommand)]
        command: sim::SimCommand,
    },
    /// Record channels of a running system to an MCAP file (`--all`: every channel).
    Record(recording::RecordArgs),
    /// What a recording holds: channels, schemas, counts, rates, duration, drops.
    Info(recording::InfoArgs),
    /// Republish a recording (or run one module alone against it: --module).
    Replay(recording::ReplayArgs),
    /// Live view of a running system for Foxglove / Lichtblick (WebSocket).
    Foxglove(recording::FoxgloveArgs),
    /// Serve the operator page (http://127.0.0.1:8080) for the running system.
    Gui(gui::GuiArgs),
    /// The peer side of a two-process benchmark (started by `hng bench`).
    #[command(hide = true, name = "__bench-peer")]
    BenchPeer(bench::ipc::PeerArgs),
}

/// Whether the command runs until it is stopped and reads SIGINT, SIGTERM and SIGHUP from a
/// signalfd (a clean stop): those are blocked first thing in `main`, before any thread exists,
/// so that no thread a library starts can die of them. The other commands keep the default
/// actions (Ctrl-C ends them).
fn reads_termination_signals(command: &Command) -> bool {
    use topic::TopicCommand as T;
    matches!(
        command,
        Command::Run(_)
            | Command::Module { .. }
            | Command::Record(_)
            | Command::Replay(_)
            | Command::Foxglove(_)
            | Command::Gui(_)
            | Command::Topic {
                command: T::Echo { .. } | T::Hz { .. } | T::Pub { .. }
            }
    )
}

fn main() -> ExitCode {
    // Before any thread exists (docs/supervision.md): `hng run` reads SIGINT, SIGTERM and
    // SIGHUP from a signalfd, so they must be blocked in every thread it will start.
    let cli = Cli::parse();
    if reads_termination_signals(&cli.command) {
        hng_supervisor::block_termination_signals();
    }
    // A SIGSEGV or SIGBUS sent by `kill` ends the process at once (hng_runtime::fatal).
    if let Err(e) = hng_runtime::fatal::install() {
        eprintln!("hng: warning: fatal-signal handler not installed: {e}");
    }
    if !matches!(cli.command, Command::Run(_)) {
        // `hng run` installs its own: quiet terminal, log files (hng_supervisor::logs).
        hng_runtime::module::init_tracing();
    }
    let result = match cli.command {
        Command::Module { name } => return modules::run(&name),
        Command::Run(args) => return run::run(&cli.prefix, &args),
        Command::Ps { json } => ctl::ps(&cli.prefix, json),
        Command::Kill { module, signal } => ctl::kill(&cli.prefix, &module, &signal),
        Command::Restart { module } => ctl::restart(&cli.prefix, &module),
        Command::Start { module } => ctl::start(&cli.prefix, &module),
        Command::Stop { module } => ctl::stop(&cli.prefix, module.as_deref()),
        Command::Topic { command } => topic::run(&cli.prefix, command),
        Command::Mission { command } => mission::run(&cli.prefix, command),
        Command::Order { command } => order::run(&cli.prefix, command),
        Command::Teleop(args) => teleop::run(&cli.prefix, &args),
        Command::Behaviours(args) => behaviours::run(&cli.prefix, &args),
        Command::Top(args) => top::run(&cli.prefix, &args),
        Command::Contracts(args) => contracts::run(&cli.prefix, &args),
        Command::Logs(args) => logs::show(&cli.prefix, &args),
        Command::Bench { bench } => bench::run(bench),
        Command::Eval { command } => eval::run(command),
        Command::Sim { command } => sim::run(command),
        Command::Iox2Config => topic::iox2_config(&cli.prefix),
        Command::BenchPeer(args) => bench::ipc::peer(&args),
        Command::Record(args) => recording::record(&cli.prefix, &args),
        Command::Info(args) => recording::info(&args),
        Command::Replay(args) => recording::replay(&cli.prefix, &args),
        Command::Foxglove(args) => recording::foxglove(&cli.prefix, &args),
        Command::Gui(args) => gui::run(&cli.prefix, &args),
    };
    // A client of a system that stopped meanwhile (`hng kill` during the supervisor's clean-up)
    // may have opened a channel after the prefix was cleaned: its wake segment would outlive
    // everything. When nothing but such system files is left of the prefix, they go with us.
    hng_runtime::shm::remove_system_files_if_alone(&cli.prefix);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // The reader went away (`hng topic list | head -2`): nothing more to say.
        Err(e) if is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hng: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Whether `e` comes from writing to a pipe whose reader has gone.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}
