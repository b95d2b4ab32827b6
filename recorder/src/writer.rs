//! The recorder's writer: a thread of its own that owns the MCAP file, so chunk compression
//! and disk writes never run in the thread that reads the channels (and, in lockstep,
//! acknowledges the simulator's rounds).
//!
//! The reading thread hands each encoded message over through a bounded queue (a number of
//! messages and a number of bytes, [`QueueLimits`]). When the queue is full, a recorder on the
//! wall clock drops the message and counts the drop on its channel (it must never fall so far
//! behind that the publishers' buffers overflow, nor grow without bound); a recorder in
//! lockstep waits instead, so the simulated world waits with it and nothing is lost (the
//! price lockstep already documents). The writer also polls the run's module logs and
//! checkpoints ([`crate::internal`]).
//!
//! A write error (a full disk) stops the writer: it keeps the error for the reading thread,
//! which stops recording cleanly; what was written stays readable up to its last complete
//! record.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::Error;
use crate::codec::SchemaDesc;
use crate::internal::{Internal, InternalOptions, InternalReport};

/// How much the queue between the reading thread and the writer holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueLimits {
    /// Messages at most.
    pub messages: usize,
    /// Bytes of encoded messages at most (one message larger than this is still admitted
    /// into an empty queue).
    pub bytes: usize,
}

impl Default for QueueLimits {
    fn default() -> Self {
        QueueLimits {
            messages: 65_536,
            bytes: 256 << 20,
        }
    }
}

/// The MCAP side of the recorder.
pub(crate) struct McapOut {
    pub(crate) writer: mcap::Writer<BufWriter<File>>,
    pub(crate) path: PathBuf,
}

impl McapOut {
    pub(crate) fn create(path: &Path, level: u32) -> Result<McapOut, Error> {
        let file = File::create(path).map_err(|e| Error::Io {
            path: path.display().to_string(),
            source: e,
        })?;
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(level)
            .chunk_size(Some(1 << 20))
            .profile("")
            .library(format!("hng-recorder {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| Error::mcap(path, e))?;
        Ok(McapOut {
            writer,
            path: path.to_path_buf(),
        })
    }

    /// A channel with its schema; `meta` is the channel's metadata.
    pub(crate) fn add_channel(
        &mut self,
        name: &str,
        schema: &SchemaDesc,
        meta: &BTreeMap<String, String>,
    ) -> Result<u16, Error> {
        let sid = self
            .writer
            .add_schema(&schema.name, schema.encoding, &schema.data)
            .map_err(|e| Error::mcap(&self.path, e))?;
        self.writer
            .add_channel(sid, name, schema.message_encoding, meta)
            .map_err(|e| Error::mcap(&self.path, e))
    }

    pub(crate) fn write(
        &mut self,
        id: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> Result<(), Error> {
        self.writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: id,
                    sequence,
                    log_time,
                    publish_time,
                },
                data,
            )
            .map_err(|e| Error::mcap(&self.path, e))
    }

    pub(crate) fn metadata(
        &mut self,
        name: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<(), Error> {
        self.writer
            .write_metadata(&mcap::records::Metadata {
                name: name.to_string(),
                metadata,
            })
            .map_err(|e| Error::mcap(&self.path, e))
    }

    pub(crate) fn attach(&mut self, a: &mcap::Attachment<'_>) -> Result<(), Error> {
        self.writer
            .attach(a)
            .map_err(|e| Error::mcap(&self.path, e))
    }

    pub(crate) fn finish(mut self) -> Result<(), Error> {
        self.writer
            .finish()
            .map_err(|e| Error::mcap(&self.path, e))?;
        Ok(())
    }
}

/// What the reading thread hands the writer.
enum Job {
    /// A recorded channel (its index: the order of these jobs).
    Channel {
        name: String,
        type_name: String,
        schema: SchemaDesc,
    },
    /// A message of channel `chan`.
    Message {
        chan: usize,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: Vec<u8>,
    },
    /// A metadata record.
    Metadata(String, BTreeMap<String, String>),
}

#[derive(Default)]
struct Shared {
    queued_bytes: AtomicUsize,
    failed: AtomicBool,
    error: Mutex<Option<String>>,
}

/// What the writer did.
#[derive(Debug, Default)]
pub(crate) struct WriterReport {
    /// The module logs and checkpoints recorded.
    pub(crate) internal: InternalReport,
}

/// The reading thread's handle on the writer.
pub(crate) struct Writer {
    tx: Option<SyncSender<Job>>,
    shared: Arc<Shared>,
    limits: QueueLimits,
    /// Wait for room instead of dropping (lockstep).
    block: bool,
    channels: usize,
    thread: Option<JoinHandle<Result<WriterReport, Error>>>,
}

impl Writer {
    /// Creates the file (an error here, e.g. a directory that does not exist, is the
    /// caller's) and starts the writer thread.
    pub(crate) fn start(
        path: &Path,
        level: u32,
        limits: QueueLimits,
        block: bool,
        internal: InternalOptions,
    ) -> Result<Writer, Error> {
        let out = McapOut::create(path, level)?;
        let (tx, rx) = std::sync::mpsc::sync_channel::<Job>(limits.messages.max(1));
        let shared = Arc::new(Shared::default());
        let s2 = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("hng-rec-writer".into())
            .spawn(move || writer_thread(out, rx, &s2, internal))
            .map_err(|e| Error::Other(format!("starting the recorder's writer thread: {e}")))?;
        Ok(Writer {
            tx: Some(tx),
            shared,
            limits,
            block,
            channels: 0,
            thread: Some(thread),
        })
    }

    /// The write error that stopped the writer, if any.
    pub(crate) fn error(&self) -> Option<String> {
        if !self.shared.failed.load(Ordering::Acquire) {
            return None;
        }
        self.shared.error.lock().ok().and_then(|e| e.clone())
    }

    fn send_control(&mut self, job: Job) -> Result<(), Error> {
        let tx = self.tx.as_ref().ok_or_else(stopped)?;
        tx.send(job).map_err(|_| stopped())
    }

    /// Adds a channel; returns its index for [`Writer::message`].
    pub(crate) fn add_channel(
        &mut self,
        name: &str,
        type_name: &str,
        schema: &SchemaDesc,
    ) -> Result<usize, Error> {
        self.send_control(Job::Channel {
            name: name.to_string(),
            type_name: type_name.to_string(),
            schema: schema.clone(),
        })?;
        self.channels += 1;
        Ok(self.channels - 1)
    }

    /// Queues a metadata record.
    pub(crate) fn metadata(
        &mut self,
        name: &str,
        kv: BTreeMap<String, String>,
    ) -> Result<(), Error> {
        self.send_control(Job::Metadata(name.to_string(), kv))
    }

    /// Queues a message; false when it was dropped because the queue is full (counted by the
    /// caller on its channel). Fails when the writer stopped (see [`Writer::error`]).
    pub(crate) fn message(
        &mut self,
        chan: usize,
        h: &hng_runtime::msg::Header,
        log_time: u64,
        data: &[u8],
    ) -> Result<bool, Error> {
        let tx = self.tx.as_ref().ok_or_else(stopped)?;
        let len = data.len();
        let queued = self.shared.queued_bytes.load(Ordering::Acquire);
        if !self.block && queued > 0 && queued + len > self.limits.bytes {
            return Ok(false);
        }
        if self.block {
            // Lockstep: wait for room in bytes too (the writer frees it as it writes).
            let t0 = Instant::now();
            while self.shared.queued_bytes.load(Ordering::Acquire) > 0
                && self.shared.queued_bytes.load(Ordering::Acquire) + len > self.limits.bytes
            {
                if self.shared.failed.load(Ordering::Acquire) {
                    return Err(stopped());
                }
                // Waiting for the writer to free room: it runs on another thread.
                std::thread::sleep(Duration::from_micros(200));
                if t0.elapsed() > Duration::from_secs(60) {
                    return Err(Error::Other(
                        "the recorder's writer made no progress for 60 s".into(),
                    ));
                }
            }
        }
        self.shared.queued_bytes.fetch_add(len, Ordering::AcqRel);
        let job = Job::Message {
            chan,
            sequence: h.seq as u32,
            log_time,
            publish_time: h.stamp_ns,
            data: data.to_vec(),
        };
        let sent = if self.block {
            tx.send(job).map_err(|_| ())
        } else {
            match tx.try_send(job) {
                Ok(()) => Ok(()),
                Err(TrySendError::Full(_)) => {
                    self.shared.queued_bytes.fetch_sub(len, Ordering::AcqRel);
                    return Ok(false);
                }
                Err(TrySendError::Disconnected(_)) => Err(()),
            }
        };
        match sent {
            Ok(()) => Ok(true),
            Err(()) => Err(stopped()),
        }
    }

    /// Closes the queue, waits for the writer to write what it holds, the module logs and
    /// checkpoints left, and the file's summary.
    pub(crate) fn finish(mut self) -> Result<WriterReport, Error> {
        drop(self.tx.take());
        match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| Error::Other("the recorder's writer thread panicked".into()))?,
            None => Ok(WriterReport::default()),
        }
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        drop(self.tx.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn stopped() -> Error {
    Error::Other("the recorder's writer stopped".into())
}

/// How often the writer looks at the module logs when no message comes.
const IDLE_POLL: Duration = Duration::from_millis(100);

fn writer_thread(
    out: McapOut,
    rx: Receiver<Job>,
    shared: &Shared,
    internal: InternalOptions,
) -> Result<WriterReport, Error> {
    let mut out = Some(out);
    let mut ids: Vec<u16> = Vec::new();
    let mut internal = Internal::new(internal);
    let fail = |e: Error, out: &mut Option<McapOut>| {
        tracing::error!("recording stopped: {e}");
        if let Ok(mut slot) = shared.error.lock() {
            slot.get_or_insert_with(|| e.to_string());
        }
        shared.failed.store(true, Ordering::Release);
        // Dropping the writer tries to close the file; on a full disk that fails quietly and
        // what was written stays readable up to its last complete record.
        *out = None;
    };
    loop {
        let job = match rx.recv_timeout(IDLE_POLL) {
            Ok(j) => Some(j),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        if let Some(job) = job {
            let r = match (&job, out.as_mut()) {
                (_, None) => Ok(()),
                (
                    Job::Channel {
                        name,
                        type_name,
                        schema,
                    },
                    Some(o),
                ) => {
                    let mut meta = BTreeMap::new();
                    meta.insert("hng.type".to_string(), type_name.clone());
                    o.add_channel(name, schema, &meta).map(|id| ids.push(id))
                }
                (
                    Job::Message {
                        chan,
                        sequence,
                        log_time,
                        publish_time,
                        data,
                    },
                    Some(o),
                ) => match ids.get(*chan) {
                    Some(id) => o.write(*id, *sequence, *log_time, *publish_time, data),
                    None => Err(Error::Other(format!("no channel of index {chan}"))),
                },
                (Job::Metadata(name, kv), Some(o)) => o.metadata(name, kv.clone()),
            };
            if let Job::Message { data, .. } = &job {
                shared.queued_bytes.fetch_sub(data.len(), Ordering::AcqRel);
            }
            if let Err(e) = r {
                fail(e, &mut out);
            }
        }
        if let Some(o) = out.as_mut()
            && let Err(e) = internal.poll(o, false)
        {
            fail(e, &mut out);
        }
    }
    if let Some(mut o) = out.take() {
        internal.poll(&mut o, true)?;
        internal.write_summary(&mut o)?;
        o.finish()?;
    }
    Ok(WriterReport {
        internal: internal.report(),
    })
}
