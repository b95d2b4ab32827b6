//! Per-module log files: each module's stdout and stderr go through a pipe to a thread of the
//! supervisor that writes them, line by line, to `DIR/<module>.log`, size-bounded (the file
//! rotates to `<module>.log.1` when it reaches the bound), and echoes them to the supervisor's
//! stderr, prefixed with the module's name, when asked (`hng run -v`).
//!
//! A module that logs faster than the disk takes blocks on its own pipe, never the supervisor:
//! the writer thread is the only reader, one per running process, ending when the process and
//! everything it started have closed the pipe.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::thread::{self, JoinHandle};

/// Default bound of one log file, bytes (the rotated `.1` file holds as much again).
pub const DEFAULT_MAX_BYTES: u64 = 8 * 1024 * 1024;

/// Where modules' output goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogOptions {
    /// Directory of the log files (created if missing).
    pub dir: PathBuf,
    /// Bound of one file, bytes.
    pub max_bytes: u64,
    /// Also copy every line to the supervisor's stderr, as `[module] line`.
    pub echo: bool,
}

impl LogOptions {
    /// Logs in `dir`, bounded at [`DEFAULT_MAX_BYTES`], not echoed.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        LogOptions {
            dir: dir.into(),
            max_bytes: DEFAULT_MAX_BYTES,
            echo: false,
        }
    }

    /// The log file of `module`.
    #[must_use]
    pub fn path(&self, module: &str) -> PathBuf {
        log_path(&self.dir, module)
    }

    /// Points `cmd`'s stdout and stderr at a new pipe and starts the thread that writes what
    /// comes out of it to the module's file. Call right before spawning `cmd`; drop `cmd`
    /// after the spawn (it holds the pipe's write end, and the thread ends only when every
    /// write end is closed). The returned handle may be dropped (the thread runs on).
    pub fn capture(&self, module: &str, cmd: &mut Command) -> io::Result<JoinHandle<()>> {
        let mut file = RotatingFile::open(self.path(module), self.max_bytes)?;
        let (reader, writer) = io::pipe()?;
        cmd.stdout(Stdio::from(writer.try_clone()?))
            .stderr(Stdio::from(writer));
        let echo = self.echo.then(|| format!("[{module}] "));
        thread::Builder::new()
            .name(format!("log-{module}"))
            .spawn(move || {
                let mut lines = BufReader::new(reader);
                let mut line = Vec::new();
                loop {
                    line.clear();
                    match lines.read_until(b'\n', &mut line) {
                        Ok(0) | Err(_) => break,
                        Ok(_) => {}
                    }
                    // A full disk loses log lines, never the module: the write error is
                    // dropped here (the module keeps running).
                    let _ = file.write_all(&line);
                    if let Some(tag) = &echo {
                        let mut err = io::stderr().lock();
                        let _ = err.write_all(tag.as_bytes());
                        let _ = err.write_all(&line);
                    }
                }
                let _ = file.flush();
            })
    }
}

/// The log file of `module` in `dir`.
#[must_use]
pub fn log_path(dir: &Path, module: &str) -> PathBuf {
    dir.join(format!("{module}.log"))
}

/// An append-only file that moves itself to `<name>.1` when it reaches its bound, so one log
/// never holds more than twice the bound on disk.
#[derive(Debug)]
pub struct RotatingFile {
    path: PathBuf,
    file: File,
    len: u64,
    max_bytes: u64,
}

impl RotatingFile {
    /// Opens (appends to) `path`, creating its directory.
    pub fn open(path: impl Into<PathBuf>, max_bytes: u64) -> io::Result<Self> {
        let path = path.into();
        if let Some(dir) = path.parent() {
            fs::create_dir_all(dir)?;
        }
        let file = OpenOptions::new().create(true).append(true).open(&path)?;
        let len = file.metadata()?.len();
        Ok(RotatingFile {
            path,
            file,
            len,
            max_bytes: max_bytes.max(1),
        })
    }

    /// The rotated file beside `path`.
    #[must_use]
    pub fn rotated(path: &Path) -> PathBuf {
        let mut name = path.as_os_str().to_owned();
        name.push(".1");
        PathBuf::from(name)
    }

    fn rotate(&mut self) -> io::Result<()> {
        self.file.flush()?;
        fs::rename(&self.path, Self::rotated(&self.path))?;
        self.file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)?;
        self.len = 0;
        Ok(())
    }
}

impl Write for RotatingFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.len > 0 && self.len + buf.len() as u64 > self.max_bytes {
            self.rotate()?;
        }
        let n = self.file.write(buf)?;
        self.len += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.file.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("hng-logs-{tag}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn a_file_rotates_at_its_bound_and_keeps_one_old_file() {
        let dir = temp_dir("rotate");
        let path = dir.join("m.log");
        let mut f = RotatingFile::open(&path, 100).expect("opens");
        for i in 0..30 {
            writeln!(f, "line {i:04}").expect("writes"); // 10 bytes each
        }
        let now = fs::read_to_string(&path).expect("current");
        let old = fs::read_to_string(RotatingFile::rotated(&path)).expect("rotated");
        assert!(
            now.len() <= 100 && old.len() <= 100,
            "{} {}",
            now.len(),
            old.len()
        );
        assert!(now.ends_with("line 0029\n"), "{now}");
        assert!(old.ends_with("line 0019\n"), "{old}");
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_process_output_lands_in_its_log_file() {
        let dir = temp_dir("capture");
        let opts = LogOptions::new(&dir);
        let mut cmd = Command::new("sh");
        cmd.args(["-c", "echo out; echo err >&2"]);
        let writer = opts.capture("shell", &mut cmd).expect("captures");
        let mut child = cmd.spawn().expect("spawns");
        drop(cmd);
        assert!(child.wait().expect("waits").success());
        writer.join().expect("the writer ends with the pipe");
        let text = fs::read_to_string(opts.path("shell")).expect("log file");
        assert!(text.contains("out\n") && text.contains("err\n"), "{text:?}");
        let _ = fs::remove_dir_all(&dir);
    }
}
