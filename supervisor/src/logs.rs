//! Quiet by default: what `hng run` shows on the terminal and what goes to the run's log files.
//!
//! - The terminal gets the progress lines and the summary (stdout) and, on stderr, only
//!   warnings and errors of `hng run` itself.
//! - Every module's output goes to `RUN_DIR/logs/<module>.log` (size-bounded, see
//!   [`hng_watchdog::logs`]); `hng run`'s own log (info and up) to `RUN_DIR/logs/hng.log`.
//!   `hng logs MODULE [-f]` shows them.
//! - `-v` raises the terminal to info and echoes every module's lines (`[module] ...`), `-vv`
//!   to debug; `HNG_LOG` or `RUST_LOG` set the terminal's filter and echo modules too.
//!
//! Colours only when stderr is a terminal.

use std::io::{self, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use hng_watchdog::logs::{DEFAULT_MAX_BYTES, LogOptions, RotatingFile};
use tracing_subscriber::EnvFilter;
use tracing_subscriber::Layer as _;
use tracing_subscriber::fmt::MakeWriter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

/// The log of `hng run` itself, in the log directory.
pub const SUPERVISOR_LOG: &str = "hng";

/// How loud the terminal is.
#[derive(Debug, Clone, Copy)]
pub struct Verbosity {
    /// `-v` count.
    pub level: u8,
    /// `HNG_LOG` or `RUST_LOG` is set.
    pub from_env: bool,
}

impl Verbosity {
    /// From the `-v` count and the environment.
    pub fn new(level: u8) -> Self {
        let set = |k| std::env::var_os(k).is_some_and(|v| !v.is_empty());
        Verbosity {
            level,
            from_env: set("HNG_LOG") || set("RUST_LOG"),
        }
    }

    /// Whether modules' lines are echoed on the terminal.
    pub fn echo_modules(self) -> bool {
        self.level > 0 || self.from_env
    }

    fn terminal_filter(self) -> EnvFilter {
        if self.from_env {
            for k in ["HNG_LOG", "RUST_LOG"] {
                if let Ok(f) = EnvFilter::try_from_env(k) {
                    return f;
                }
            }
        }
        EnvFilter::new(match self.level {
            0 => "warn",
            1 => "info",
            _ => "debug",
        })
    }
}

/// The run's log files: `hng run`'s own file opens once the run owns its prefix (a refused
/// second run must not touch the first one's logs); lines logged before go to the terminal
/// only.
#[derive(Debug, Clone, Default)]
pub struct RunLog {
    verbosity: Option<Verbosity>,
    file: Arc<Mutex<Option<RotatingFile>>>,
}

impl RunLog {
    /// Installs the process's tracing: the terminal at `v`'s level, the log file at info (debug
    /// with `-vv`).
    pub fn init(v: Verbosity) -> RunLog {
        let log = RunLog {
            verbosity: Some(v),
            ..RunLog::default()
        };
        let file_filter = EnvFilter::new(if v.level >= 2 { "debug" } else { "info" });
        let terminal = tracing_subscriber::fmt::layer()
            .with_writer(io::stderr)
            .with_ansi(io::stderr().is_terminal())
            .with_target(false)
            .with_filter(v.terminal_filter());
        let file = tracing_subscriber::fmt::layer()
            .with_writer(log.clone())
            .with_ansi(false)
            .with_target(false)
            .with_filter(file_filter);
        let _ = tracing_subscriber::registry()
            .with(terminal)
            .with(file)
            .try_init();
        log
    }

    /// Clears the previous run's logs in `dir` and opens `hng run`'s own log there; returns
    /// the options that send each module's output to its file.
    pub fn open(&self, dir: &Path) -> LogOptions {
        let v = self.verbosity.unwrap_or(Verbosity::new(0));
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                let p = e.path();
                if p.extension().is_some_and(|x| x == "log" || x == "1") {
                    let _ = std::fs::remove_file(p);
                }
            }
        }
        let opts = LogOptions {
            dir: dir.to_owned(),
            max_bytes: DEFAULT_MAX_BYTES,
            echo: v.echo_modules(),
        };
        match RotatingFile::open(opts.path(SUPERVISOR_LOG), opts.max_bytes) {
            Ok(f) => {
                if let Ok(mut slot) = self.file.lock() {
                    *slot = Some(f);
                }
            }
            Err(e) => tracing::warn!(
                dir = %dir.display(),
                "cannot write the run's log files ({e}); logs go to the terminal only"
            ),
        }
        opts
    }
}

/// Writes one formatted event to the file, if it is open.
#[derive(Debug)]
pub struct RunLogWriter(Arc<Mutex<Option<RotatingFile>>>);

impl Write for RunLogWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if let Ok(mut slot) = self.0.lock()
            && let Some(f) = slot.as_mut()
        {
            // A full disk loses log lines, never the run.
            let _ = f.write_all(buf);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        if let Ok(mut slot) = self.0.lock()
            && let Some(f) = slot.as_mut()
        {
            let _ = f.flush();
        }
        Ok(())
    }
}

impl<'a> MakeWriter<'a> for RunLog {
    type Writer = RunLogWriter;

    fn make_writer(&'a self) -> RunLogWriter {
        RunLogWriter(Arc::clone(&self.file))
    }
}

/// The run's log, installed by `hng run` before anything is logged.
pub static RUN_LOG: std::sync::OnceLock<RunLog> = std::sync::OnceLock::new();

/// The log directory of a run directory.
pub fn log_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("logs")
}
