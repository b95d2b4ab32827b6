//! Logging of a module process.

/// Sets up `tracing` for a process: `HNG_LOG` (else `RUST_LOG`) is the filter (default `info`), output to
/// stderr, with colours only when stderr is a terminal (a log file or a pipe gets plain text).
/// Safe to call more than once.
pub fn init_tracing() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_env("HNG_LOG")
        .or_else(|_| tracing_subscriber::EnvFilter::try_from_env("RUST_LOG"))
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .try_init();
}
