//! The modules' "internal data" (the paper's words) beside their interfaces: each module's
//! log lines and its checkpoints, recorded from the files the supervisor and the modules
//! write (`RUN_DIR/logs/<module>.log`, `CHECKPOINT_DIR/<module>.ckpt`).
//!
//! - **Logs**: every line a module writes after the recorder started goes to the MCAP channel
//!   `hng/log/<module>` in Foxglove's well-known `foxglove.Log` schema (protobuf), so the Log
//!   panel shows them without configuration; the level is read from the line (tracing's
//!   `INFO`, `WARN`, ...; `UNKNOWN` when none), the time is when the recorder read it. A file
//!   that rotates (`<module>.log` moved to `.log.1`) is read to its end before the new one.
//!   Lines already in a file when the recorder started (an earlier run's) are not recorded.
//! - **Checkpoints**: each new version of a module's checkpoint file (a change of its size,
//!   modification time and content) is stored as an MCAP attachment named
//!   `checkpoint/<module>`, media type [`CHECKPOINT_MEDIA_TYPE`], its creation time the
//!   file's modification time; at most one per module every
//!   [`InternalOptions::checkpoint_period`], and the last one when the recording ends.
//!
//! These channels carry no `hng.type`: they are not bus channels and are never replayed.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use foxglove::messages as fg;
use prost::Message as _;
use serde::Serialize;

use crate::Error;
use crate::codec::SchemaDesc;
use crate::record::now_unix_ns;
use crate::writer::McapOut;

/// The MCAP channel of a module's log lines.
pub fn log_channel(module: &str) -> String {
    format!("hng/log/{module}")
}

/// The attachment name of a module's checkpoints.
pub fn checkpoint_attachment(module: &str) -> String {
    format!("checkpoint/{module}")
}

/// Media type of a checkpoint attachment (the file as `hng_runtime::checkpoint` writes it).
pub const CHECKPOINT_MEDIA_TYPE: &str = "application/vnd.hng.checkpoint";

/// Where the internal data is, and how often to look.
#[derive(Debug, Clone, Default)]
pub struct InternalOptions {
    /// The directory of the module logs (`RUN_DIR/logs`).
    pub logs: Option<PathBuf>,
    /// The checkpoint directory.
    pub checkpoints: Option<PathBuf>,
    /// At most one checkpoint per module this often (zero: every new version seen).
    pub checkpoint_period: Duration,
}

/// What was recorded of the internal data.
#[derive(Debug, Clone, Default, Serialize)]
pub struct InternalReport {
    /// Log lines per module.
    pub log_lines: BTreeMap<String, u64>,
    /// Checkpoints stored per module.
    pub checkpoints: BTreeMap<String, u64>,
    /// Bytes of checkpoints stored.
    pub checkpoint_bytes: u64,
    /// Log bytes not recorded because a file rotated twice between two reads.
    pub log_bytes_lost: u64,
}

/// How often log files are read.
const LOG_POLL: Duration = Duration::from_millis(100);

/// A log line longer than this is cut (a runaway module).
const MAX_LINE: usize = 64 << 10;

struct Tail {
    file: File,
    ino: u64,
    partial: Vec<u8>,
    channel: Option<u16>,
}

struct Ckpt {
    /// (size, mtime ns, CRC) of the last version stored.
    stored: Option<(u64, i128, u32)>,
    /// (size, mtime ns) of the last version looked at.
    seen: Option<(u64, i128)>,
    last_store: Option<Instant>,
}

/// The internal data's poller (in the writer thread).
pub(crate) struct Internal {
    opts: InternalOptions,
    next_logs: Instant,
    tails: BTreeMap<String, Tail>,
    ckpts: BTreeMap<String, Ckpt>,
    report: InternalReport,
    schema: Option<u16>,
}

fn log_schema() -> SchemaDesc {
    let mut s = crate::codec::wkt_schema::<fg::Log>();
    if s.name.is_empty() {
        s.name = "foxglove.Log".into();
    }
    s
}

/// The level of a log line: the first of tracing's level words among its first tokens.
pub(crate) fn level_of(line: &str) -> fg::log::Level {
    use fg::log::Level;
    for tok in line.split_whitespace().take(4) {
        match tok.trim_matches(|c: char| !c.is_ascii_alphabetic()) {
            "TRACE" | "DEBUG" => return Level::Debug,
            "INFO" => return Level::Info,
            "WARN" | "WARNING" => return Level::Warning,
            "ERROR" => return Level::Error,
            "FATAL" => return Level::Fatal,
            _ => {}
        }
    }
    Level::Unknown
}

/// The module whose log file `path` is (`<module>.log`), `None` for any other file.
pub fn log_module(path: &Path) -> Option<&str> {
    path.file_name()?.to_str()?.strip_suffix(".log")
}

/// `line` without terminal colour codes (ESC [ ... letter).
pub fn strip_ansi(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

fn io_err(path: &Path, e: std::io::Error) -> Error {
    Error::Io {
        path: path.display().to_string(),
        source: e,
    }
}

impl Internal {
    /// Notes what exists now (an earlier run's lines and checkpoints: not recorded).
    pub(crate) fn new(opts: InternalOptions) -> Internal {
        let mut i = Internal {
            opts,
            next_logs: Instant::now(),
            tails: BTreeMap::new(),
            ckpts: BTreeMap::new(),
            report: InternalReport::default(),
            schema: None,
        };
        if let Err(e) = i.discover_logs(true) {
            tracing::warn!("module logs: {e}");
        }
        i.mark_existing_checkpoints();
        i
    }

    pub(crate) fn report(&self) -> InternalReport {
        self.report.clone()
    }

    /// Reads what is new (logs every [`LOG_POLL`], checkpoints at their period); `last`:
    /// everything now, whatever the period (the recording ends).
    pub(crate) fn poll(&mut self, out: &mut McapOut, last: bool) -> Result<(), Error> {
        let now = Instant::now();
        if now < self.next_logs && !last {
            return Ok(());
        }
        self.next_logs = now + LOG_POLL;
        self.discover_logs(false)?;
        let names: Vec<String> = self.tails.keys().cloned().collect();
        for m in names {
            self.read_log(out, &m, last)?;
        }
        self.look_at_checkpoints(out, last)
    }

    fn discover_logs(&mut self, at_start: bool) -> Result<(), Error> {
        let Some(dir) = self.opts.logs.clone() else {
            return Ok(());
        };
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return Ok(()); // not created yet
        };
        for e in entries.flatten() {
            let path = e.path();
            let Some(module) = log_module(&path) else {
                continue;
            };
            if self.tails.contains_key(module) {
                continue;
            }
            let Ok(mut file) = File::open(&path) else {
                continue;
            };
            let meta = file.metadata().map_err(|e| io_err(&path, e))?;
            if at_start {
                file.seek(SeekFrom::End(0)).map_err(|e| io_err(&path, e))?;
            }
            self.tails.insert(
                module.to_string(),
                Tail {
                    file,
                    ino: meta.ino(),
                    partial: Vec::new(),
                    channel: None,
                },
            );
        }
        Ok(())
    }

    fn read_log(&mut self, out: &mut McapOut, module: &str, last: bool) -> Result<(), Error> {
        let Some(dir) = self.opts.logs.clone() else {
            return Ok(());
        };
        let path = dir.join(format!("{module}.log"));
        let mut buf = Vec::new();
        loop {
            let Some(t) = self.tails.get_mut(module) else {
                return Ok(());
            };
            t.file.read_to_end(&mut buf).map_err(|e| io_err(&path, e))?;
            // Rotated: the old file (now `.log.1`) was read to its end; go on with the new.
            match std::fs::metadata(&path) {
                Ok(m) if m.ino() != t.ino => {
                    let Ok(f) = File::open(&path) else { break };
                    // Rotated twice since the last read: the middle file's bytes are lost.
                    let rotated = hng_rotated(&path);
                    if std::fs::metadata(&rotated).is_ok_and(|r| r.ino() != t.ino) {
                        self.report.log_bytes_lost +=
                            std::fs::metadata(&rotated).map(|r| r.len()).unwrap_or(0);
                    }
                    t.file = f;
                    t.ino = m.ino();
                }
                _ => break,
            }
        }
        let mut lines = Vec::new();
        if let Some(t) = self.tails.get_mut(module) {
            t.partial.extend_from_slice(&buf);
            let mut start = 0;
            while let Some(i) = t.partial[start..].iter().position(|b| *b == b'\n') {
                lines.push(t.partial[start..start + i].to_vec());
                start += i + 1;
            }
            t.partial.drain(..start);
            if t.partial.len() > MAX_LINE || (last && !t.partial.is_empty()) {
                lines.push(std::mem::take(&mut t.partial));
            }
        }
        for l in lines {
            self.write_line(out, module, &l)?;
        }
        Ok(())
    }

    fn write_line(&mut self, out: &mut McapOut, module: &str, line: &[u8]) -> Result<(), Error> {
        let text = strip_ansi(String::from_utf8_lossy(&line[..line.len().min(MAX_LINE)]).trim());
        if text.is_empty() {
            return Ok(());
        }
        let schema = match self.schema {
            Some(s) => s,
            None => {
                let s = log_schema();
                let id = out
                    .writer
                    .add_schema(&s.name, s.encoding, &s.data)
                    .map_err(|e| Error::mcap(&out.path, e))?;
                self.schema = Some(id);
                id
            }
        };
        let Some(t) = self.tails.get_mut(module) else {
            return Ok(());
        };
        let ch = match t.channel {
            Some(c) => c,
            None => {
                let mut meta = BTreeMap::new();
                meta.insert("hng.module".to_string(), module.to_string());
                meta.insert("hng.kind".to_string(), "log".to_string());
                let c = out
                    .writer
                    .add_channel(schema, &log_channel(module), "protobuf", &meta)
                    .map_err(|e| Error::mcap(&out.path, e))?;
                t.channel = Some(c);
                c
            }
        };
        let now = now_unix_ns();
        let msg = fg::Log {
            timestamp: Some(fg::Timestamp::new(
                u32::try_from(now / 1_000_000_000).unwrap_or(u32::MAX),
                (now % 1_000_000_000) as u32,
            )),
            level: level_of(&text) as i32,
            message: text,
            name: module.to_string(),
            file: String::new(),
            line: 0,
        };
        let n = self.report.log_lines.entry(module.to_string()).or_insert(0);
        *n += 1;
        out.write(ch, *n as u32, now, now, &msg.encode_to_vec())
    }

    fn mark_existing_checkpoints(&mut self) {
        let Some(dir) = self.opts.checkpoints.clone() else {
            return;
        };
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return;
        };
        for e in entries.flatten() {
            if let (Some(module), Ok(meta)) = (ckpt_module(&e.path()), e.metadata()) {
                let key = (meta.len(), mtime_ns(&meta));
                self.ckpts.insert(
                    module,
                    Ckpt {
                        seen: Some(key),
                        stored: Some((key.0, key.1, 0)),
                        last_store: None,
                    },
                );
            }
        }
    }

    fn look_at_checkpoints(&mut self, out: &mut McapOut, last: bool) -> Result<(), Error> {
        let Some(dir) = self.opts.checkpoints.clone() else {
            return Ok(());
        };
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return Ok(());
        };
        let now = Instant::now();
        for e in entries.flatten() {
            let path = e.path();
            let Some(module) = ckpt_module(&path) else {
                continue;
            };
            let Ok(meta) = std::fs::metadata(&path) else {
                continue;
            };
            let mtime = mtime_ns(&meta);
            let key = (meta.len(), mtime);
            let c = self.ckpts.entry(module.clone()).or_insert(Ckpt {
                stored: None,
                seen: None,
                last_store: None,
            });
            if c.seen == Some(key) && c.stored.is_some_and(|s| (s.0, s.1) == key) {
                continue;
            }
            c.seen = Some(key);
            let due = last
                || c.last_store
                    .is_none_or(|t| now.duration_since(t) >= self.opts.checkpoint_period);
            if !due {
                continue;
            }
            let Ok(data) = std::fs::read(&path) else {
                continue; // replaced meanwhile: the next look takes the new one
            };
            let crc = crc32fast::hash(&data);
            if c.stored
                .is_some_and(|s| s.2 == crc && s.0 == data.len() as u64)
            {
                c.stored = Some((key.0, key.1, crc));
                continue;
            }
            c.stored = Some((data.len() as u64, mtime, crc));
            c.last_store = Some(now);
            let create_time = u64::try_from(mtime).unwrap_or(0);
            out.attach(&mcap::Attachment {
                log_time: now_unix_ns(),
                create_time,
                name: checkpoint_attachment(&module),
                media_type: CHECKPOINT_MEDIA_TYPE.to_string(),
                data: std::borrow::Cow::Owned(data),
            })?;
            *self.report.checkpoints.entry(module).or_insert(0) += 1;
            self.report.checkpoint_bytes += meta.len();
        }
        Ok(())
    }

    /// The metadata record `hng.internal`: what was recorded of the logs and checkpoints.
    pub(crate) fn write_summary(&self, out: &mut McapOut) -> Result<(), Error> {
        if self.opts.logs.is_none() && self.opts.checkpoints.is_none() {
            return Ok(());
        }
        let mut m = BTreeMap::new();
        for (k, v) in &self.report.log_lines {
            m.insert(format!("log_lines.{k}"), v.to_string());
        }
        for (k, v) in &self.report.checkpoints {
            m.insert(format!("checkpoints.{k}"), v.to_string());
        }
        if let Some(d) = &self.opts.logs {
            m.insert("logs_dir".into(), d.display().to_string());
        }
        if let Some(d) = &self.opts.checkpoints {
            m.insert("checkpoints_dir".into(), d.display().to_string());
        }
        m.insert(
            "log_bytes_lost".into(),
            self.report.log_bytes_lost.to_string(),
        );
        out.metadata("hng.internal", m)
    }
}

/// The module of a checkpoint file `<module>.ckpt` (not the previous one kept beside it,
/// `<module>.prev.ckpt`, nor a save in progress, `.<module>.ckpt.tmp-*`).
fn ckpt_module(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    let module = name.strip_suffix(".ckpt")?;
    if module.ends_with(".prev") || name.starts_with('.') {
        return None;
    }
    Some(module.to_string())
}

fn mtime_ns(meta: &std::fs::Metadata) -> i128 {
    i128::from(meta.mtime()) * 1_000_000_000 + i128::from(meta.mtime_nsec())
}

/// `<path>.1`, where the supervisor moves a full log file.
fn hng_rotated(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".1");
    PathBuf::from(name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn levels_are_read_from_tracing_lines() {
        use fg::log::Level;
        assert_eq!(
            level_of("2026-11-28T12:00:00.1Z  WARN slam: lost"),
            Level::Warning
        );
        assert_eq!(level_of("  INFO hng: x"), Level::Info);
        assert_eq!(level_of("ERROR boom"), Level::Error);
        assert_eq!(level_of("a line that says nothing"), Level::Unknown);
        assert_eq!(strip_ansi("\u{1b}[32m INFO\u{1b}[0m x"), " INFO x");
    }

    fn temp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("hng-internal-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn new_log_lines_and_checkpoints_are_recorded_and_old_ones_not() {
        let dir = temp("rec");
        let logs = dir.join("logs");
        let ckpts = dir.join("ckpt");
        std::fs::create_dir_all(&logs).unwrap();
        std::fs::create_dir_all(&ckpts).unwrap();
        std::fs::write(logs.join("old.log"), "  INFO old: before the recorder\n").unwrap();
        std::fs::write(ckpts.join("old.ckpt"), b"old state").unwrap();
        let file = dir.join("out.mcap");
        let mut out = McapOut::create(&file, 1).unwrap();
        let mut i = Internal::new(InternalOptions {
            logs: Some(logs.clone()),
            checkpoints: Some(ckpts.clone()),
            checkpoint_period: Duration::ZERO,
        });
        i.poll(&mut out, false).unwrap();
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .open(logs.join("old.log"))
            .unwrap();
        writeln!(f, "  WARN old: after").unwrap();
        // A rotation: the rest of the old file, then the new one.
        writeln!(f, "  INFO old: just before the rotation").unwrap();
        std::fs::rename(logs.join("old.log"), logs.join("old.log.1")).unwrap();
        std::fs::write(
            logs.join("old.log"),
            "  ERROR old: after the rotation\npartial",
        )
        .unwrap();
        std::fs::write(logs.join("new.log"), "hello\n").unwrap();
        std::fs::write(ckpts.join("slam.ckpt"), b"state 1").unwrap();
        std::fs::write(ckpts.join("slam.prev.ckpt"), b"state 0").unwrap();
        i.poll(&mut out, true).unwrap();
        i.write_summary(&mut out).unwrap();
        out.finish().unwrap();
        let r = i.report();
        assert_eq!(r.log_lines.get("old"), Some(&4), "{r:?}");
        assert_eq!(r.log_lines.get("new"), Some(&1), "{r:?}");
        assert_eq!(r.checkpoints.get("slam"), Some(&1), "{r:?}");
        assert_eq!(r.checkpoints.get("old"), None, "{r:?}");
        // Read back with the mcap crate.
        let bytes = std::fs::read(&file).unwrap();
        let mut texts = Vec::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            assert_eq!(m.channel.schema.as_ref().unwrap().name, "foxglove.Log");
            let l = fg::Log::decode(&m.data[..]).unwrap();
            texts.push((m.channel.topic.clone(), l.level, l.message));
        }
        assert!(texts.contains(&(
            "hng/log/old".into(),
            fg::log::Level::Warning as i32,
            "WARN old: after".into()
        )));
        assert!(texts.iter().any(|t| t.2 == "ERROR old: after the rotation"));
        assert!(texts.iter().any(|t| t.2 == "partial"));
        assert!(!texts.iter().any(|t| t.2.contains("before the recorder")));
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert_eq!(summary.attachment_indexes.len(), 1);
        assert_eq!(summary.attachment_indexes[0].name, "checkpoint/slam");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
