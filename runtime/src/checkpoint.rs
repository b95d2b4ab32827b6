//! Checkpoint files: atomic, versioned, checksummed.
//!
//! HNG paper, section 5.4: "Periodically each module writes in a file all the
//! data concerning its state of running. If the process is stopped (killed)
//! and restarted it can detect the presence of this file and thus it is able
//! to come back at a previous state before the failure."
//!
//! The payload is opaque bytes chosen by the module (usually postcard). This
//! file only makes sure that what is read back is exactly what was written by
//! a compatible version of the module, or a typed error otherwise. The caller
//! turns any error into "warning + clean start".
//!
//! # Atomicity
//!
//! [`CheckpointStore::save`] writes a temporary file in the same directory,
//! `fsync`s it, `rename`s it over `<dir>/<module>.ckpt` and `fsync`s the
//! directory. A crash at any point leaves either the old or the new complete
//! checkpoint (plus possibly a stale `.<module>.ckpt.tmp-*` file, which the
//! next successful save of the same module removes).
//!
//! # File format (version 1, all integers little-endian)
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0  | 8 | magic `b"HNGCKPT\0"` |
//! | 8  | 2 | format version (`1`) |
//! | 10 | 2 | reserved, `0` |
//! | 12 | 4 | module-declared state version |
//! | 16 | 8 | payload length `n` |
//! | 24 | n | payload |
//! | 24 + n | 4 | CRC-32 (IEEE, `crc32fast`) of bytes `0 .. 24 + n` |
//!
//! The file must be exactly `28 + n` bytes long. Checks run in this order:
//! size of the header, magic, declared length against the file size,
//! checksum, format version, state version. Because the checksum is checked
//! before the versions, a corrupted version field is reported as a checksum
//! error, and an "incompatible version" error always means a genuine file
//! written by another version of the module.
//!
//! ```no_run
//! use hng_runtime::checkpoint::CheckpointStore;
//! # fn main() -> Result<(), hng_runtime::checkpoint::CheckpointError> {
//! let store = CheckpointStore::new("/var/lib/hng/checkpoints", "slam")?;
//! store.save(3, b"module state")?;
//! match store.load(3) {
//!     Ok(Some(bytes)) => { /* restore from bytes */ }
//!     Ok(None) => { /* first start: no checkpoint */ }
//!     Err(e) => tracing::warn!("{e}; starting clean"),
//! }
//! # Ok(()) }
//! ```

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// First eight bytes of every checkpoint file.
pub const MAGIC: [u8; 8] = *b"HNGCKPT\0";
/// Version of the container format written by this code.
pub const FORMAT_VERSION: u16 = 1;
/// Size of the fixed header before the payload.
pub const HEADER_LEN: usize = 24;
/// Size of the trailing checksum.
pub const TRAILER_LEN: usize = 4;

/// Why a checkpoint could not be saved or loaded. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The module name cannot be used as a file name.
    #[error(
        "invalid module name {name:?} for a checkpoint file: use a non-empty name without '/' or NUL, not '.' or '..'"
    )]
    InvalidModuleName {
        /// The rejected name.
        name: String,
    },
    /// An I/O operation failed.
    #[error("checkpoint {}: {op} failed: {source}", path.display())]
    Io {
        /// File or directory the operation was on.
        path: PathBuf,
        /// What was being done ("write", "fsync", "rename", ...).
        op: &'static str,
        /// The OS error.
        #[source]
        source: io::Error,
    },
    /// The file is shorter than its header or than its declared length.
    #[error(
        "checkpoint {} is truncated: {actual} bytes, expected {expected} (interrupted write or disk corruption)",
        path.display()
    )]
    Truncated {
        /// The checkpoint file.
        path: PathBuf,
        /// Actual file size.
        actual: u64,
        /// Size implied by the header (or the header size if that is missing).
        expected: u64,
    },
    /// The file is longer than its declared length.
    #[error(
        "checkpoint {} has {extra} trailing bytes after the declared payload (corrupted length field?)",
        path.display()
    )]
    TrailingData {
        /// The checkpoint file.
        path: PathBuf,
        /// Number of bytes beyond the expected end.
        extra: u64,
    },
    /// The file does not start with [`MAGIC`].
    #[error("checkpoint {} is not an hng checkpoint (bad magic)", path.display())]
    BadMagic {
        /// The checkpoint file.
        path: PathBuf,
    },
    /// The stored checksum does not match the contents.
    #[error(
        "checkpoint {} is corrupted: checksum {stored:#010x} stored, {computed:#010x} computed",
        path.display()
    )]
    BadChecksum {
        /// The checkpoint file.
        path: PathBuf,
        /// CRC-32 found in the file.
        stored: u32,
        /// CRC-32 of the contents.
        computed: u32,
    },
    /// The container format is newer (or older) than this code understands.
    #[error(
        "checkpoint {} uses container format {found}, this build reads format {supported}",
        path.display()
    )]
    UnsupportedFormat {
        /// The checkpoint file.
        path: PathBuf,
        /// Format version in the file.
        found: u16,
        /// Format version this code reads.
        supported: u16,
    },
    /// The module's own state version differs from the one it expects.
    #[error(
        "checkpoint {} holds state version {found}, the module expects {expected}",
        path.display()
    )]
    IncompatibleStateVersion {
        /// The checkpoint file.
        path: PathBuf,
        /// State version in the file.
        found: u32,
        /// State version the module asked for.
        expected: u32,
    },
}

/// Where one module's checkpoint lives: `<dir>/<module_name>.ckpt`.
#[derive(Debug, Clone)]
pub struct CheckpointStore {
    dir: PathBuf,
    module: String,
    path: PathBuf,
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl CheckpointStore {
    /// A store for `module_name`'s checkpoint in `dir`. The directory is
    /// created on the first [`save`](Self::save) if it does not exist.
    pub fn new(dir: impl Into<PathBuf>, module_name: &str) -> Result<Self, CheckpointError> {
        if module_name.is_empty()
            || module_name == "."
            || module_name == ".."
            || module_name.contains(['/', '\0'])
        {
            return Err(CheckpointError::InvalidModuleName {
                name: module_name.to_owned(),
            });
        }
        let dir = dir.into();
        let path = dir.join(format!("{module_name}.ckpt"));
        Ok(Self {
            dir,
            module: module_name.to_owned(),
            path,
        })
    }

    /// The checkpoint file this store reads and writes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Atomically replace the checkpoint with `bytes`, tagged with the
    /// module's `state_version`. When this returns `Ok`, the new checkpoint
    /// survives a power cut.
    pub fn save(&self, state_version: u32, bytes: &[u8]) -> Result<(), CheckpointError> {
        let io_err = |path: &Path, op: &'static str| {
            let path = path.to_owned();
            move |source| CheckpointError::Io { path, op, source }
        };
        fs::create_dir_all(&self.dir).map_err(io_err(&self.dir, "create directory"))?;
        let encoded = encode(state_version, bytes);
        let tmp = self.dir.join(format!(
            ".{}.ckpt.tmp-{}-{}",
            self.module,
            std::process::id(),
            TMP_COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let written = (|| {
            let mut file = OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&tmp)
                .map_err(io_err(&tmp, "create temporary file"))?;
            file.write_all(&encoded).map_err(io_err(&tmp, "write"))?;
            file.sync_all().map_err(io_err(&tmp, "fsync"))?;
            fs::rename(&tmp, &self.path).map_err(io_err(&self.path, "rename"))
        })();
        if written.is_err() {
            // Best effort: the original error is the one worth reporting.
            let _ = fs::remove_file(&tmp);
            return written;
        }
        File::open(&self.dir)
            .and_then(|d| d.sync_all())
            .map_err(io_err(&self.dir, "fsync directory"))?;
        self.remove_stale_temporaries();
        Ok(())
    }

    /// Read the checkpoint back. `Ok(None)` means there is no checkpoint (first
    /// start); any other problem is an error the caller should log before
    /// starting clean.
    pub fn load(&self, expected_state_version: u32) -> Result<Option<Vec<u8>>, CheckpointError> {
        let data = match fs::read(&self.path) {
            Ok(data) => data,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(source) => {
                return Err(CheckpointError::Io {
                    path: self.path.clone(),
                    op: "read",
                    source,
                });
            }
        };
        decode(&self.path, &data, expected_state_version).map(Some)
    }

    /// Delete the checkpoint, if any (e.g. after an intentional reset).
    pub fn remove(&self) -> Result<(), CheckpointError> {
        match fs::remove_file(&self.path) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
            Err(source) => Err(CheckpointError::Io {
                path: self.path.clone(),
                op: "remove",
                source,
            }),
        }
    }

    /// Remove `.<module>.ckpt.tmp-*` files left by a crash in the middle of a
    /// save. Runs after a successful save, when this store's own temporary is
    /// already renamed; two live writers of one module name would be a
    /// configuration error anyway.
    fn remove_stale_temporaries(&self) {
        let prefix = format!(".{}.ckpt.tmp-", self.module);
        let Ok(entries) = fs::read_dir(&self.dir) else {
            return;
        };
        for entry in entries.flatten() {
            if entry
                .file_name()
                .to_str()
                .is_some_and(|n| n.starts_with(&prefix))
            {
                let _ = fs::remove_file(entry.path());
            }
        }
    }
}

/// Serialize one checkpoint file image.
fn encode(state_version: u32, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len() + TRAILER_LEN);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&state_version.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

fn le_u16(b: &[u8], at: usize) -> u16 {
    let mut a = [0u8; 2];
    a.copy_from_slice(&b[at..at + 2]);
    u16::from_le_bytes(a)
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(a)
}

fn le_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// Validate a file image and return its payload. All slicing below is
/// guarded by the length checks that precede it.
fn decode(
    path: &Path,
    data: &[u8],
    expected_state_version: u32,
) -> Result<Vec<u8>, CheckpointError> {
    let actual = data.len() as u64;
    let min = (HEADER_LEN + TRAILER_LEN) as u64;
    if data.len() >= MAGIC.len() && data[..MAGIC.len()] != MAGIC {
        return Err(CheckpointError::BadMagic {
            path: path.to_owned(),
        });
    }
    if actual < min {
        return Err(CheckpointError::Truncated {
            path: path.to_owned(),
            actual,
            expected: min,
        });
    }
    let declared = le_u64(data, 16);
    let expected = declared.saturating_add(min);
    if actual < expected {
        return Err(CheckpointError::Truncated {
            path: path.to_owned(),
            actual,
            expected,
        });
    }
    if actual > expected {
        return Err(CheckpointError::TrailingData {
            path: path.to_owned(),
            extra: actual - expected,
        });
    }
    // `declared` fits in usize: it is smaller than `data.len()`.
    let body_end = HEADER_LEN + declared as usize;
    let stored = le_u32(data, body_end);
    let computed = crc32fast::hash(&data[..body_end]);
    if stored != computed {
        return Err(CheckpointError::BadChecksum {
            path: path.to_owned(),
            stored,
            computed,
        });
    }
    let format = le_u16(data, 8);
    if format != FORMAT_VERSION {
        return Err(CheckpointError::UnsupportedFormat {
            path: path.to_owned(),
            found: format,
            supported: FORMAT_VERSION,
        });
    }
    let found = le_u32(data, 12);
    if found != expected_state_version {
        return Err(CheckpointError::IncompatibleStateVersion {
            path: path.to_owned(),
            found,
            expected: expected_state_version,
        });
    }
    Ok(data[HEADER_LEN..body_end].to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A fresh directory under the system temp dir, removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> Self {
            let path = std::env::temp_dir().join(format!(
                "hng-ckpt-test-{tag}-{}-{}",
                std::process::id(),
                TMP_COUNTER.fetch_add(1, Ordering::Relaxed)
            ));
            let _ = fs::remove_dir_all(&path);
            Self(path)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = fs::remove_dir_all(&self.0);
        }
    }

    fn store(dir: &TempDir) -> CheckpointStore {
        match CheckpointStore::new(&dir.0, "slam") {
            Ok(s) => s,
            Err(e) => panic!("valid name rejected: {e}"),
        }
    }

    #[test]
    fn round_trip_and_missing() -> Result<(), CheckpointError> {
        let dir = TempDir::new("rt");
        let s = store(&dir);
        assert!(s.load(1)?.is_none(), "no file yet means None");
        s.save(1, b"hello")?;
        assert_eq!(s.load(1)?.as_deref(), Some(&b"hello"[..]));
        s.save(1, b"")?;
        assert_eq!(s.load(1)?.as_deref(), Some(&b""[..]));
        s.save(2, &[7u8; 100_000])?;
        assert_eq!(s.load(2)?.map(|v| v.len()), Some(100_000));
        // No temporaries left behind.
        let names: Vec<_> = fs::read_dir(&dir.0)
            .map_err(|source| CheckpointError::Io {
                path: dir.0.clone(),
                op: "read_dir",
                source,
            })?
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("slam.ckpt")]);
        s.remove()?;
        assert!(s.load(2)?.is_none());
        Ok(())
    }

    #[test]
    fn stale_temporary_is_cleaned_and_ignored() -> Result<(), CheckpointError> {
        let dir = TempDir::new("stale");
        let s = store(&dir);
        s.save(1, b"old")?;
        let stale = dir.0.join(".slam.ckpt.tmp-999999-0");
        fs::write(&stale, b"half a write").map_err(|source| CheckpointError::Io {
            path: stale.clone(),
            op: "write",
            source,
        })?;
        assert_eq!(s.load(1)?.as_deref(), Some(&b"old"[..]));
        s.save(1, b"new")?;
        assert!(!stale.exists());
        assert_eq!(s.load(1)?.as_deref(), Some(&b"new"[..]));
        Ok(())
    }

    #[test]
    fn invalid_names_rejected() {
        for bad in ["", ".", "..", "a/b", "a\0b"] {
            assert!(
                matches!(
                    CheckpointStore::new("/tmp", bad),
                    Err(CheckpointError::InvalidModuleName { .. })
                ),
                "{bad:?} accepted"
            );
        }
    }

    #[test]
    fn version_mismatches_are_typed() {
        let p = Path::new("x.ckpt");
        let img = encode(3, b"abc");
        assert!(matches!(
            decode(p, &img, 4),
            Err(CheckpointError::IncompatibleStateVersion {
                found: 3,
                expected: 4,
                ..
            })
        ));
        // A genuine file of a future container format (valid checksum).
        let mut future = img[..HEADER_LEN + 3].to_vec();
        future[8] = 2;
        let crc = crc32fast::hash(&future);
        future.extend_from_slice(&crc.to_le_bytes());
        assert!(matches!(
            decode(p, &future, 3),
            Err(CheckpointError::UnsupportedFormat { found: 2, .. })
        ));
        let mut magic = img.clone();
        magic[0] = b'X';
        assert!(matches!(
            decode(p, &magic, 3),
            Err(CheckpointError::BadMagic { .. })
        ));
        let mut long = img;
        long.push(0);
        assert!(matches!(
            decode(p, &long, 3),
            Err(CheckpointError::TrailingData { extra: 1, .. })
        ));
    }

    #[test]
    fn every_truncation_and_every_bit_flip_is_detected() {
        let p = Path::new("x.ckpt");
        for payload in [&b""[..], b"x", b"some module state \x00\xff"] {
            let img = encode(9, payload);
            for cut in 0..img.len() {
                let r = decode(p, &img[..cut], 9);
                assert!(
                    matches!(
                        r,
                        Err(CheckpointError::Truncated { .. } | CheckpointError::BadMagic { .. })
                    ),
                    "cut at {cut}: {r:?}"
                );
            }
            for bit in 0..img.len() * 8 {
                let mut bad = img.clone();
                bad[bit / 8] ^= 1 << (bit % 8);
                let r = decode(p, &bad, 9);
                assert!(r.is_err(), "flip of bit {bit} went undetected");
                assert!(
                    !matches!(
                        r,
                        Err(CheckpointError::IncompatibleStateVersion { .. }
                            | CheckpointError::UnsupportedFormat { .. })
                    ),
                    "flip of bit {bit} misreported as a version problem: {r:?}"
                );
            }
        }
    }

    #[test]
    fn corrupted_file_on_disk_is_an_error_not_a_panic() -> Result<(), CheckpointError> {
        let dir = TempDir::new("disk");
        let s = store(&dir);
        s.save(1, b"0123456789")?;
        let img = fs::read(s.path()).map_err(|source| CheckpointError::Io {
            path: s.path().to_owned(),
            op: "read",
            source,
        })?;
        let write = |bytes: &[u8]| {
            fs::write(s.path(), bytes).map_err(|source| CheckpointError::Io {
                path: s.path().to_owned(),
                op: "write",
                source,
            })
        };
        write(&img[..img.len() - 1])?;
        assert!(matches!(s.load(1), Err(CheckpointError::Truncated { .. })));
        let mut flipped = img.clone();
        flipped[HEADER_LEN + 2] ^= 0x10;
        write(&flipped)?;
        assert!(matches!(
            s.load(1),
            Err(CheckpointError::BadChecksum { .. })
        ));
        write(b"")?;
        assert!(matches!(s.load(1), Err(CheckpointError::Truncated { .. })));
        Ok(())
    }

    proptest! {
        #[test]
        fn prop_round_trip(version: u32, payload in proptest::collection::vec(any::<u8>(), 0..512)) {
            let img = encode(version, &payload);
            let back = decode(Path::new("p"), &img, version);
            prop_assert_eq!(back.ok(), Some(payload));
        }

        #[test]
        fn prop_truncation_detected(
            payload in proptest::collection::vec(any::<u8>(), 0..256),
            cut_frac in 0.0f64..1.0,
        ) {
            let img = encode(1, &payload);
            let cut = ((img.len() as f64) * cut_frac) as usize;
            prop_assert!(cut < img.len());
            prop_assert!(decode(Path::new("p"), &img[..cut], 1).is_err());
        }

        /// Up to three flipped bits in a file under 2974 bits: CRC-32 (IEEE)
        /// has Hamming distance 4 at that length, so detection is guaranteed,
        /// not probabilistic.
        #[test]
        fn prop_bit_flips_detected(
            payload in proptest::collection::vec(any::<u8>(), 0..300),
            flips in proptest::collection::vec(any::<proptest::sample::Index>(), 1..=3),
        ) {
            let img = encode(5, &payload);
            let bits = img.len() * 8;
            let positions: std::collections::BTreeSet<usize> =
                flips.iter().map(|i| i.index(bits)).collect();
            let mut bad = img.clone();
            for bit in &positions {
                bad[bit / 8] ^= 1 << (bit % 8);
            }
            prop_assert!(decode(Path::new("p"), &bad, 5).is_err(), "flips {:?} undetected", positions);
        }

        #[test]
        fn prop_arbitrary_bytes_never_panic(data in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = decode(Path::new("p"), &data, 0);
            let mut with_magic = MAGIC.to_vec();
            with_magic.extend_from_slice(&data);
            let _ = decode(Path::new("p"), &with_magic, 0);
        }
    }
}
