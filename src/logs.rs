//! `hng logs [MODULE] [-f]`: the log files of the last `hng run` on a prefix
//! ([`hng_supervisor::logs`] writes them).

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use hng_supervisor::logs::log_dir;
use hng_watchdog::logs::RotatingFile;

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
        .unwrap_or_else(|| hng_supervisor::default_run_dir(prefix));
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
