//! The recorder: subscribes to the channels of a running system and writes every message to
//! an MCAP file and/or a Foxglove live view.
//!
//! It polls its subscribers every millisecond instead of sleeping on them, so a module
//! publishing never pays a wake-up for the recorder (a publisher notifies only blocked
//! subscribers). Channels are discovered as they appear (every 20 ms for the first seconds,
//! then every 500 ms). A message lost before the recorder read it (its buffer overflowed) is
//! counted per channel from the sequence gaps, printed at the end and stored in the file's
//! metadata (`hng.drops`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use hng_runtime::channel::{Node, NodeOptions};
use hng_runtime::wait::{WaitMode, Waiter, Wake};
use serde::Serialize;

use crate::Error;
use crate::codec::SchemaDesc;
use crate::internal::{InternalOptions, InternalReport};
use crate::live::Live;
use crate::lockstep::Participant;
use crate::registry::{Tap, TypeEntry, lookup, registry};
use crate::writer::{QueueLimits, Writer};

/// What to record and where.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// The system's prefix.
    pub prefix: String,
    /// Channels to record (exact names, or a prefix ending in `*`); empty: every channel.
    pub channels: Vec<String>,
    /// The MCAP file.
    pub output: Option<PathBuf>,
    /// Address of the Foxglove live view (`ws://HOST:PORT` or `HOST:PORT`).
    pub live: Option<String>,
    /// Metadata records written at the start (name, key-value pairs).
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Keep only messages published by this module id (replay of one module).
    pub only_source: Option<u32>,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Period of the subscriber polls.
    pub poll: Duration,
    /// Stop on SIGINT/SIGTERM (a foreground `hng record`); off in a thread of a process that
    /// handles signals itself.
    pub catch_signals: bool,
    /// zstd level of the chunks (1 fastest; 0: zstd's default).
    pub compression_level: u32,
    /// Take part in the simulator's lockstep under this name (one of its `lockstep` list):
    /// the world then waits every round until the recorder has read it, so nothing is
    /// dropped in a simulated run ([`crate::lockstep`]).
    pub lockstep: Option<String>,
    /// The queue between the thread that reads the channels and the one that writes the
    /// file ([`crate::writer`]).
    pub queue: QueueLimits,
    /// The modules' logs and checkpoints to record ([`crate::internal`]).
    pub internal: InternalOptions,
}

impl RecordOptions {
    /// Every channel of `prefix`, nowhere yet.
    pub fn new(prefix: &str) -> RecordOptions {
        RecordOptions {
            prefix: prefix.to_string(),
            channels: Vec::new(),
            output: None,
            live: None,
            metadata: Vec::new(),
            only_source: None,
            duration: None,
            poll: Duration::from_millis(1),
            catch_signals: false,
            compression_level: 1,
            lockstep: None,
            queue: QueueLimits::default(),
            internal: InternalOptions {
                checkpoint_period: Duration::from_secs(2),
                ..InternalOptions::default()
            },
        }
    }
}

/// What was recorded on one channel.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelSummary {
    /// The channel.
    pub channel: String,
    /// The hng type.
    pub r#type: String,
    /// The schema written.
    pub schema: String,
    /// Messages recorded.
    pub messages: u64,
    /// Messages lost: before the recorder read them, or at its writer's full queue.
    pub dropped: u64,
    /// Of `dropped`, those lost at the writer's full queue.
    pub queue_dropped: u64,
    /// Encoded bytes.
    pub bytes: u64,
}

/// What a recording holds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RecordSummary {
    /// The file (if any).
    pub output: Option<PathBuf>,
    /// Recorded channels.
    pub channels: Vec<ChannelSummary>,
    /// Channels seen but not recorded: name and type (a type this recorder does not know).
    pub skipped: BTreeMap<String, String>,
    /// Wall time recorded, s.
    pub wall_s: f64,
    /// Messages recorded.
    pub messages: u64,
    /// Messages lost.
    pub dropped: u64,
    /// Encoded bytes.
    pub bytes: u64,
    /// Why recording stopped early (a write error such as a full disk), if it did.
    pub error: Option<String>,
    /// The module logs and checkpoints recorded.
    pub internal: InternalReport,
}

impl std::fmt::Display for RecordSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let file = self
            .output
            .as_ref()
            .map_or("live view".to_string(), |p| p.display().to_string());
        writeln!(
            f,
            "recorded {} message(s) on {} channel(s) in {:.1} s to {file}; {} dropped",
            self.messages,
            self.channels.len(),
            self.wall_s,
            self.dropped
        )?;
        for c in self.channels.iter().filter(|c| c.dropped > 0) {
            write!(f, "  dropped {:>6} on {}", c.dropped, c.channel)?;
            if c.queue_dropped > 0 {
                write!(f, " ({} at the writer's full queue)", c.queue_dropped)?;
            }
            writeln!(f)?;
        }
        let lines: u64 = self.internal.log_lines.values().sum();
        let ckpts: u64 = self.internal.checkpoints.values().sum();
        if lines + ckpts > 0 {
            writeln!(
                f,
                "  internal data: {lines} log line(s) of {} module(s), {ckpts} checkpoint(s) of {} module(s)",
                self.internal.log_lines.len(),
                self.internal.checkpoints.len()
            )?;
        }
        if !self.skipped.is_empty() {
            let mut names: Vec<String> = self
                .skipped
                .iter()
                .take(6)
                .map(|(c, t)| format!("{c} ({t})"))
                .collect();
            if self.skipped.len() > 6 {
                names.push("...".into());
            }
            writeln!(
                f,
                "  not recorded: {} channel(s) of types hng record does not know: {}",
                self.skipped.len(),
                names.join(", ")
            )?;
        }
        if let Some(e) = &self.error {
            writeln!(f, "  recording stopped early: {e}")?;
        }
        Ok(())
    }
}

/// What the recorder has done so far (for callers that must wait for it).
#[derive(Debug, Clone, Default)]
pub struct Progress(Arc<ProgressInner>);

#[derive(Debug, Default)]
struct ProgressInner {
    channels: Mutex<BTreeSet<String>>,
    messages: std::sync::atomic::AtomicU64,
}

impl Progress {
    /// True when `channel` is being recorded.
    pub fn has(&self, channel: &str) -> bool {
        self.0
            .channels
            .lock()
            .map(|s| s.contains(channel))
            .unwrap_or(false)
    }

    /// Messages taken off the bus so far (recorded, or dropped at the writer's full queue).
    pub fn messages(&self) -> u64 {
        self.0.messages.load(Ordering::Acquire)
    }

    /// Waits until no message was recorded for `quiet`, or `limit` passed.
    pub fn wait_quiet(&self, quiet: Duration, limit: Duration) {
        let t0 = Instant::now();
        let mut last = self.messages();
        let mut since = Instant::now();
        while t0.elapsed() < limit {
            std::thread::sleep(Duration::from_millis(20));
            let n = self.messages();
            if n != last {
                last = n;
                since = Instant::now();
            } else if since.elapsed() >= quiet {
                return;
            }
        }
    }

    fn add(&self, channel: &str) {
        if let Ok(mut s) = self.0.channels.lock() {
            s.insert(channel.to_string());
        }
    }

    fn count(&self, n: u64) {
        self.0.messages.fetch_add(n, Ordering::AcqRel);
    }
}

fn wanted(filters: &[String], channel: &str) -> bool {
    filters.is_empty()
        || filters.iter().any(|f| match f.strip_suffix('*') {
            Some(p) => channel.starts_with(p),
            None => f == channel,
        })
}

/// Nanoseconds since the Unix epoch.
pub(crate) fn now_unix_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

struct Chan {
    name: String,
    type_name: String,
    schema: SchemaDesc,
    tap: Box<dyn Tap>,
    /// Its index at the writer.
    file_id: Option<usize>,
    live: Option<Arc<foxglove::RawChannel>>,
    messages: u64,
    bytes: u64,
    queue_dropped: u64,
}

/// Records until `stop` is set (or a signal / the duration ends); returns what was recorded.
/// `progress` lists the channels subscribed so far.
pub fn record(
    opts: &RecordOptions,
    stop: &AtomicBool,
    progress: &Progress,
) -> Result<RecordSummary, Error> {
    record_impl(opts, stop, progress, &mut || {})
}

/// [`record`], calling `started` once after the first pass over the channels.
fn record_impl(
    opts: &RecordOptions,
    stop: &AtomicBool,
    progress: &Progress,
    started_hook: &mut dyn FnMut(),
) -> Result<RecordSummary, Error> {
    let reg = registry();
    let node = Node::new(
        NodeOptions::new(&format!(
            "hng-recorder-{}-{}",
            std::process::id(),
            crate::unique()
        ))
        .prefix(&opts.prefix),
    )?;
    // Signals first: the writer's and the live view's threads inherit the blocked mask, so
    // SIGTERM reaches the signalfd and not a thread that would die of it.
    let mut waiter = if opts.catch_signals {
        let mut w = Waiter::new(WaitMode::SLEEP)?;
        w.catch_termination_signals()?;
        Some(w)
    } else {
        None
    };
    let mut mcap = match &opts.output {
        Some(p) => Some(Writer::start(
            p,
            opts.compression_level,
            opts.queue,
            opts.lockstep.is_some(),
            opts.internal.clone(),
        )?),
        None => None,
    };
    if let Some(m) = mcap.as_mut() {
        for (name, kv) in &opts.metadata {
            m.metadata(name, kv.clone())?;
        }
    }
    let live = match &opts.live {
        Some(addr) => Some(Live::start(addr)?),
        None => None,
    };
    let mut lockstep = match &opts.lockstep {
        Some(name) => Some(Participant::new(&opts.prefix, name)?),
        None => None,
    };

    let started = Instant::now();
    let mut chans: Vec<Chan> = Vec::new();
    let mut skipped = BTreeMap::new();
    let mut next_discovery = started;
    let mut error = None;
    let mut stopping = false;
    let mut first_pass = true;
    loop {
        let now = Instant::now();
        if now >= next_discovery && !stopping {
            discover(
                opts,
                &node,
                &reg,
                &mut chans,
                &mut skipped,
                &mut mcap,
                &live,
                progress,
            )?;
            if first_pass {
                first_pass = false;
                started_hook();
            }
            let early = now.duration_since(started) < Duration::from_secs(3);
            next_discovery = now
                + if early {
                    Duration::from_millis(20)
                } else {
                    Duration::from_millis(500)
                };
        }
        let log_time = now_unix_ns();
        for c in chans.iter_mut() {
            // Messages taken off the bus, kept or dropped at the writer's queue.
            let before = c.messages + c.queue_dropped;
            let r = drain(c, opts.only_source, log_time, &mut mcap);
            progress.count(c.messages + c.queue_dropped - before);
            let failed = mcap.as_ref().and_then(Writer::error);
            if let Some(e) = failed.or(r.err().map(|e| e.to_string())) {
                // A write error (a full disk): stop cleanly, keep what was written.
                tracing::error!("recording stopped: {e}");
                error = Some(e);
                if let Some(w) = mcap.take() {
                    let _ = w.finish();
                }
                stopping = true;
                break;
            }
        }
        if stopping {
            break;
        }
        if let Some(p) = lockstep.as_mut() {
            // Everything the round brought was read: the world may step on.
            p.ack()?;
        }
        if stop.load(Ordering::Acquire) || opts.duration.is_some_and(|d| started.elapsed() >= d) {
            // One more pass to take what arrived meanwhile.
            stopping = true;
            continue;
        }
        match waiter.as_mut() {
            _ if lockstep.is_some() => {
                if let Some(p) = lockstep.as_mut() {
                    p.wait(opts.poll)?;
                }
            }
            Some(w) => {
                if let Wake::Signal(_) = w.wait(Some(opts.poll))? {
                    stop_flag_signal(stop);
                }
            }
            None => std::thread::sleep(opts.poll),
        }
    }
    let mut summary = RecordSummary {
        output: opts.output.clone(),
        channels: chans
            .iter()
            .map(|c| ChannelSummary {
                channel: c.name.clone(),
                r#type: c.type_name.clone(),
                schema: c.schema.name.clone(),
                messages: c.messages,
                dropped: c.tap.stats().dropped + c.queue_dropped,
                queue_dropped: c.queue_dropped,
                bytes: c.bytes,
            })
            .collect(),
        skipped,
        wall_s: started.elapsed().as_secs_f64(),
        messages: chans.iter().map(|c| c.messages).sum(),
        dropped: chans
            .iter()
            .map(|c| c.tap.stats().dropped + c.queue_dropped)
            .sum(),
        bytes: chans.iter().map(|c| c.bytes).sum(),
        error,
        internal: InternalReport::default(),
    };
    // Out of the barrier before closing the file (the world does not wait for the close).
    drop(lockstep);
    if let Some(mut m) = mcap {
        let drops: BTreeMap<String, String> = summary
            .channels
            .iter()
            .map(|c| (c.channel.clone(), c.dropped.to_string()))
            .collect();
        let wrote = m.metadata("hng.drops", drops);
        let mut rec = BTreeMap::new();
        rec.insert("messages".into(), summary.messages.to_string());
        rec.insert("dropped".into(), summary.dropped.to_string());
        rec.insert("wall_s".into(), format!("{:.3}", summary.wall_s));
        rec.insert(
            "skipped".into(),
            serde_json::to_string(&summary.skipped).unwrap_or_default(),
        );
        rec.insert(
            "queue_dropped".into(),
            summary
                .channels
                .iter()
                .map(|c| c.queue_dropped)
                .sum::<u64>()
                .to_string(),
        );
        let wrote = wrote.and_then(|()| m.metadata("hng.recorder", rec));
        let failed = m.error();
        let finished = m.finish();
        match (failed, wrote.and(finished)) {
            // The writer failed at the end (a full disk): said like a failure on the way.
            (Some(e), _) => summary.error = Some(e),
            (None, Err(e)) => summary.error = Some(e.to_string()),
            (None, Ok(report)) => summary.internal = report.internal,
        }
    }
    drop(chans);
    if let Some(l) = live {
        l.stop();
    }
    Ok(summary)
}

fn stop_flag_signal(stop: &AtomicBool) {
    stop.store(true, Ordering::Release);
}

fn drain(
    c: &mut Chan,
    only_source: Option<u32>,
    log_time: u64,
    mcap: &mut Option<Writer>,
) -> Result<(), Error> {
    let Chan {
        tap,
        file_id,
        live,
        messages,
        bytes,
        queue_dropped,
        ..
    } = c;
    tap.drain(&mut |h, data| {
        if only_source.is_some_and(|s| s != h.source) {
            return Ok(());
        }
        if let (Some(m), Some(id)) = (mcap.as_mut(), *file_id)
            && !m.message(id, h, log_time, data)?
        {
            // The writer's queue is full: lost, counted on its channel.
            *queue_dropped += 1;
            return Ok(());
        }
        *messages += 1;
        *bytes += data.len() as u64;
        if let Some(l) = live {
            l.log_with_meta(data, foxglove::PartialMetadata::with_log_time(log_time));
        }
        Ok(())
    })?;
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn discover(
    opts: &RecordOptions,
    node: &Node,
    reg: &[TypeEntry],
    chans: &mut Vec<Chan>,
    skipped: &mut BTreeMap<String, String>,
    mcap: &mut Option<Writer>,
    live: &Option<Live>,
    progress: &Progress,
) -> Result<(), Error> {
    for hng_runtime::channel::ChannelListing {
        name,
        type_name: ty,
        ..
    } in hng_runtime::channel::list_channels(&opts.prefix)?
    {
        if !wanted(&opts.channels, &name)
            || chans.iter().any(|c| c.name == name)
            || skipped.contains_key(&name)
        {
            continue;
        }
        let Some(entry) = lookup(reg, &ty) else {
            skipped.insert(name, ty);
            continue;
        };
        let tap = match (entry.tap)(node, &name) {
            Ok(t) => t,
            Err(e @ hng_runtime::Error::ChannelFull { .. }) => {
                // Say it once, record the rest.
                tracing::warn!("not recording {name}: {e}");
                skipped.insert(name, format!("{ty}: {e}"));
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let schema = (entry.schema)();
        let file_id = match mcap.as_mut() {
            Some(m) => Some(m.add_channel(&name, &ty, &schema)?),
            None => None,
        };
        let live = live
            .as_ref()
            .map(|l| l.channel(&name, &ty, &schema))
            .transpose()?;
        progress.add(&name);
        chans.push(Chan {
            name,
            type_name: ty,
            schema,
            tap,
            file_id,
            live,
            messages: 0,
            bytes: 0,
            queue_dropped: 0,
        });
    }
    Ok(())
}

/// A recorder running in a thread of its own (`hng run --record`, `hng replay --module`).
pub struct RecorderThread {
    stop: Arc<AtomicBool>,
    progress: Progress,
    thread: Option<std::thread::JoinHandle<Result<RecordSummary, Error>>>,
}

impl RecorderThread {
    /// Starts recording; returns once the recorder has made its first pass over the
    /// channels that exist (or failed to start).
    pub fn spawn(mut opts: RecordOptions) -> Result<RecorderThread, Error> {
        opts.catch_signals = false;
        let stop = Arc::new(AtomicBool::new(false));
        let progress = Progress::default();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
        let (s2, p2) = (Arc::clone(&stop), progress.clone());
        let thread = std::thread::Builder::new()
            .name("hng-recorder".into())
            .spawn(move || {
                let mut ready = Some(ready_tx);
                let r = record_impl(&opts, &s2, &p2, &mut || {
                    if let Some(tx) = ready.take() {
                        let _ = tx.send(());
                    }
                });
                if let Err(e) = &r {
                    tracing::error!("recorder: {e}");
                }
                r
            })
            .map_err(|e| Error::Other(format!("starting the recorder thread: {e}")))?;
        let mut t = RecorderThread {
            stop,
            progress,
            thread: Some(thread),
        };
        if ready_rx.recv().is_err() {
            // The thread ended before it was ready: its error.
            return Err(match t.finish() {
                Err(e) => e,
                Ok(_) => Error::Other("the recorder ended before it started".into()),
            });
        }
        Ok(t)
    }

    /// The channels subscribed so far.
    pub fn progress(&self) -> &Progress {
        &self.progress
    }

    /// Stops recording, closes the file, returns what was recorded.
    pub fn finish(&mut self) -> Result<RecordSummary, Error> {
        self.stop.store(true, Ordering::Release);
        match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| Error::Other("the recorder thread panicked".into()))?,
            None => Err(Error::Other("the recorder was already finished".into())),
        }
    }
}

impl Drop for RecorderThread {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.finish();
        }
    }
}
