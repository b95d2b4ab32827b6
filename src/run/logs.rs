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

/// Options of `hng logs`.
#[derive(Debug, clap::Args)]
pub struct LogsArgs {
    /// The module (`hng` for `hng run` itself); without it, the list of log files.
    pub module: Option<String>,
    /// Keep printing lines as they are written (Ctrl-C ends).
    #[arg(short, long)]
    pub follow: bool,
    /// Only the last N lines (default: all).
    #[arg(short = 'n', long)]
    pub lines: Option<usize>,
    /// The run directory (default: the prefix's, as `hng run` picks it).
    #[arg(long, env = "HNG_RUN_DIR")]
    pub run_dir: Option<PathBuf>,
}

/// `hng logs`: lists the run's log files, or prints (and follows) one module's.
pub fn show(prefix: &str, args: &LogsArgs) -> anyhow::Result<()> {
    use anyhow::Context as _;
    let run_dir = args
        .run_dir
        .clone()
        .unwrap_or_else(|| super::default_run_dir(prefix));
    let dir = log_dir(&run_dir);
    let Some(module) = &args.module else {
        let mut names: Vec<(String, u64)> = std::fs::read_dir(&dir)
            .with_context(|| format!("no logs in {} (has `hng run` run here?)", dir.display()))?
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let module = name.strip_suffix(".log")?.to_owned();
                Some((module, e.metadata().ok()?.len()))
            })
            .collect();
        names.sort();
        let mut out = io::stdout().lock();
        for (m, len) in names {
            writeln!(
                out,
                "{m:<16} {len:>10} B  {}",
                dir.join(format!("{m}.log")).display()
            )?;
        }
        return Ok(());
    };
    let path = hng_watchdog::logs::log_path(&dir, module);
    let rotated = RotatingFile::rotated(&path);
    let mut text = std::fs::read(&rotated).unwrap_or_default();
    let current = std::fs::read(&path).with_context(|| {
        format!(
            "no log for module {module:?}: {} (`hng logs` lists them)",
            path.display()
        )
    })?;
    text.extend_from_slice(&current);
    let start = match args.lines {
        Some(n) => tail_start(&text, n),
        None => 0,
    };
    let mut out = io::stdout().lock();
    out.write_all(&text[start..])?;
    out.flush()?;
    if args.follow {
        follow(&path, current.len() as u64, &mut out)?;
    }
    Ok(())
}

/// Where the last `n` lines of `text` start.
fn tail_start(text: &[u8], n: usize) -> usize {
    if n == 0 {
        return text.len();
    }
    let body = text.strip_suffix(b"\n").unwrap_or(text);
    body.iter()
        .enumerate()
        .rev()
        .filter(|(_, b)| **b == b'\n')
        .nth(n - 1)
        .map_or(0, |(i, _)| i + 1)
}

/// Prints what is appended to `path` from `offset` on, across rotations, until the reader
/// goes away or the process is interrupted. Polls the file's size every 200 ms (a log viewer's
/// pace; inotify would save the wake-ups).
fn follow(path: &Path, mut offset: u64, out: &mut impl Write) -> io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    loop {
        std::thread::sleep(std::time::Duration::from_millis(200));
        let Ok(mut f) = std::fs::File::open(path) else {
            continue;
        };
        let len = f.metadata()?.len();
        if len < offset {
            offset = 0; // rotated: the new file starts over
        }
        if len > offset {
            f.seek(SeekFrom::Start(offset))?;
            let mut buf = Vec::new();
            f.take(len - offset).read_to_end(&mut buf)?;
            out.write_all(&buf)?;
            out.flush()?;
            offset = len;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::tail_start;

    #[test]
    fn tail_keeps_the_last_lines() {
        let t = b"a\nb\nc\n";
        assert_eq!(&t[tail_start(t, 2)..], b"b\nc\n");
        assert_eq!(&t[tail_start(t, 5)..], t);
        assert_eq!(&t[tail_start(t, 0)..], b"");
        let u = b"a\nb";
        assert_eq!(&u[tail_start(u, 1)..], b"b");
    }
}
