//! hng's flight recorder (the paper's "record and save online their internal data and their
//! interfaces"): every channel of a running system to an MCAP file, a Foxglove live view of
//! the same channels, replay of a recording (the whole bus, or the inputs of one module
//! tested alone), and the tools to read and compare recordings.
//!
//! - [`codec`]: how each hng type is written (Foxglove well-known schemas where one fits,
//!   JSON with a JSON Schema otherwise) and read back.
//! - [`record`]: the recorder (`hng record`, `hng run --record`, `hng foxglove`): the
//!   thread that reads the channels.
//! - [`writer`]: the thread that compresses and writes the file, behind a bounded queue.
//! - [`internal`]: the modules' log lines and checkpoints (their "internal data").
//! - [`live`]: the Foxglove WebSocket server.
//! - [`lockstep`]: the recorder as a lockstep participant (nothing dropped in simulated runs).
//! - [`read`]: reading a file, damaged or not, with offsets in the errors.
//! - [`info`]: what a file holds (`hng info`).
//! - [`replay`]: republishing a file (`hng replay`).
//! - [`compare`]: comparing the poses of two recordings (`hng eval replay`).
//!
//! The recorder and the live view run in processes of their own (or in the supervisor's),
//! never in a module: the Foxglove SDK brings a tokio runtime.

pub mod codec;
pub mod compare;
pub mod info;
pub mod internal;
pub mod live;
pub mod lockstep;
pub mod read;
pub mod record;
pub mod registry;
pub mod replay;
mod replay_lockstep;
pub mod writer;

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

pub use record::{RecordOptions, RecordSummary, RecorderThread, record};
pub use writer::QueueLimits;

/// An error of the recorder, the reader or the replay.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The data plane.
    #[error(transparent)]
    Runtime(#[from] hng_runtime::Error),
    /// A file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The MCAP library refused to write or read.
    #[error("{path}: {detail}")]
    Mcap {
        /// The file.
        path: String,
        /// What failed.
        detail: String,
    },
    /// The file is damaged at a known place.
    #[error("{path}: damaged at byte offset {offset}: {detail}")]
    Damaged {
        /// The file.
        path: String,
        /// Where the damaged record starts.
        offset: u64,
        /// What is wrong.
        detail: String,
    },
    /// A message could not be encoded or decoded.
    #[error("channel {channel:?}: {detail}")]
    Codec {
        /// The channel.
        channel: String,
        /// What failed.
        detail: String,
    },
    /// Anything else, said in words.
    #[error("{0}")]
    Other(String),
}

impl Error {
    /// An error of the `mcap` crate, with its causes (the OS error of a failed write: a full
    /// disk, a file too large).
    pub(crate) fn mcap(path: &Path, e: impl std::error::Error) -> Error {
        let mut detail = e.to_string();
        let mut cause = e.source();
        while let Some(c) = cause {
            detail.push_str(": ");
            detail.push_str(&c.to_string());
            cause = c.source();
        }
        Error::Mcap {
            path: path.display().to_string(),
            detail,
        }
    }
}

/// A number unique within this process (node names).
pub(crate) fn unique() -> u64 {
    static N: AtomicU64 = AtomicU64::new(0);
    N.fetch_add(1, Ordering::Relaxed)
}
