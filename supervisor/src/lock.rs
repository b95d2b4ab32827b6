//! One system per prefix: `hng run` holds a write lock on `/dev/shm/<prefix>supervisor.lock`.
//!
//! The lock is a POSIX record lock (`fcntl(F_SETLK)`) on the whole file: the kernel releases
//! it when the supervisor dies, however it dies, and `F_GETLK` tells anyone the holder's pid
//! without taking the lock, so that tools can ask "does a system run here?" without getting
//! in the way of a supervisor that is starting. The file also holds the supervisor's pid as
//! text. An orderly stop removes the file last, after every other file of the prefix; a file
//! found unlocked at start is the mark of a supervisor that died without its orderly stop
//! (SIGKILL, power loss): the new supervisor says so (iceoryx2's dead-node clean-up reclaims
//! what the dead processes left as the new nodes start).

use std::fs::{File, OpenOptions};
use std::io::{Read as _, Write as _};
use std::os::fd::AsRawFd;
use std::os::unix::fs::{MetadataExt as _, OpenOptionsExt as _};
use std::path::{Path, PathBuf};

use crate::error::{Context as _, Result, bail};
use hng_runtime::shm;
use nix::libc;

/// The lock file's name after the prefix.
pub const LOCK_NAME: &str = "supervisor.lock";

/// `/dev/shm/<prefix>supervisor.lock`.
pub fn lock_path(prefix: &str) -> PathBuf {
    Path::new(shm::SHM_DIR).join(format!("{prefix}{LOCK_NAME}"))
}

/// A whole-file write lock request (or query) for `fcntl`.
fn whole_file(kind: libc::c_short) -> libc::flock {
    // SAFETY: flock is plain data; zero is a valid value for each field.
    let mut fl: libc::flock = unsafe { std::mem::zeroed() };
    fl.l_type = kind;
    fl.l_whence = libc::SEEK_SET as libc::c_short;
    fl.l_start = 0;
    fl.l_len = 0;
    fl
}

/// The pid holding a write lock on `file`, if any (`F_GETLK`, which takes no lock).
fn lock_holder(file: &File) -> std::io::Result<Option<u32>> {
    let mut fl = whole_file(libc::F_WRLCK as libc::c_short);
    // SAFETY: F_GETLK with a valid, writable flock struct.
    let r = unsafe { libc::fcntl(file.as_raw_fd(), libc::F_GETLK, &mut fl) };
    if r < 0 {
        return Err(std::io::Error::last_os_error());
    }
    if fl.l_type == libc::F_UNLCK as libc::c_short {
        Ok(None)
    } else {
        Ok(Some(u32::try_from(fl.l_pid).unwrap_or(0)))
    }
}

/// Takes the write lock without waiting; false if another process holds it.
fn try_lock(file: &File) -> std::io::Result<bool> {
    let fl = whole_file(libc::F_WRLCK as libc::c_short);
    // SAFETY: F_SETLK with a valid flock struct.
    let r = unsafe { libc::fcntl(file.as_raw_fd(), libc::F_SETLK, &fl) };
    if r == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EAGAIN | libc::EACCES) => Ok(false),
        _ => Err(e),
    }
}

/// The pid of the supervisor running under `prefix`, if one runs (checked without creating
/// any file). `Some(0)` if the holder's pid cannot be told.
pub fn running_supervisor(prefix: &str) -> Option<u32> {
    let file = File::open(lock_path(prefix)).ok()?;
    lock_holder(&file).ok().flatten()
}

/// The lock of a running system; [`SystemLock::release`] removes the file.
#[derive(Debug)]
pub struct SystemLock {
    file: File,
    path: PathBuf,
}

/// What [`SystemLock::acquire`] found.
#[derive(Debug)]
pub struct Acquired {
    /// The lock, held until it is released or this process ends.
    pub lock: SystemLock,
    /// The pid in a lock file nobody held: a supervisor that died without an orderly stop.
    pub stale_pid: Option<u32>,
}

impl SystemLock {
    /// Takes the prefix's lock, or fails naming the prefix and the running supervisor's pid.
    pub fn acquire(prefix: &str) -> Result<Acquired> {
        let path = lock_path(prefix);
        // An orderly stop unlinks the file while holding its lock: a lock on a file that is
        // no longer at `path` is worth nothing, try again (a few times: each retry means
        // another supervisor just stopped or started).
        for _ in 0..5 {
            let file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .mode(0o600)
                .open(&path)
                .with_context(|| format!("opening the lock file {}", path.display()))?;
            if !try_lock(&file).with_context(|| format!("locking {}", path.display()))? {
                let pid = match lock_holder(&file) {
                    Ok(Some(p)) if p != 0 => p.to_string(),
                    _ => read_pid(&file).map_or("unknown".to_owned(), |p| p.to_string()),
                };
                bail!(
                    "a system already runs under prefix {prefix:?} (supervisor pid {pid}, lock {}): stop it with `hng stop --prefix {prefix}` or choose another --prefix",
                    path.display()
                );
            }
            let same = match (file.metadata(), std::fs::metadata(&path)) {
                (Ok(a), Ok(b)) => a.ino() == b.ino() && a.dev() == b.dev(),
                _ => false,
            };
            if !same {
                continue;
            }
            let stale_pid = read_pid(&file);
            let mut lock = SystemLock { file, path };
            lock.write_pid()
                .with_context(|| format!("writing {}", lock.path.display()))?;
            return Ok(Acquired { lock, stale_pid });
        }
        bail!(
            "could not take the lock {} (it kept being replaced)",
            path.display()
        )
    }

    fn write_pid(&mut self) -> std::io::Result<()> {
        self.file.set_len(0)?;
        use std::io::Seek as _;
        self.file.seek(std::io::SeekFrom::Start(0))?;
        writeln!(self.file, "{}", std::process::id())?;
        self.file.sync_data()
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Removes the lock file, then lets the lock go: the last step of an orderly stop.
    pub fn release(self) {
        let _ = std::fs::remove_file(&self.path);
        drop(self.file);
    }
}

fn read_pid(mut file: &File) -> Option<u32> {
    use std::io::Seek as _;
    let mut text = String::new();
    file.seek(std::io::SeekFrom::Start(0)).ok()?;
    file.read_to_string(&mut text).ok()?;
    text.trim().parse().ok()
}

/// Removes every file of `prefix` except its lock file (its iceoryx2 root folder with the
/// rest); returns how many were removed. Call only while holding the lock, when no process of
/// the prefix runs.
pub fn remove_prefix_files_but_lock(prefix: &str) -> usize {
    shm::remove_prefix_files_but(prefix, Some(&lock_path(prefix)))
}

/// Takes the prefix's lock (one system per prefix). When the last system on the prefix died
/// without its orderly stop, says so: what its processes left is reclaimed by iceoryx2's
/// dead-node clean-up as this system's nodes start (not by removing the prefix's files, which
/// a tool or a test may already have opened for this run), and the orderly stop removes the
/// rest (the iceoryx2 root folder with it). A prefix too long for iceoryx2's socket paths is
/// refused before anything is created.
pub fn lock_prefix(prefix: &str) -> Result<SystemLock> {
    shm::check_prefix(prefix)?;
    let got = SystemLock::acquire(prefix)?;
    if let Some(pid) = got.stale_pid {
        tracing::warn!(
            prefix,
            lock = %got.lock.path().display(),
            dead_supervisor = pid,
            files = hng_runtime::shm::prefix_files(prefix).len(),
            "the previous system on this prefix ended without an orderly stop; its dead processes' resources are reclaimed as modules start"
        );
    }
    Ok(got.lock)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_is_refused_and_a_released_one_is_gone() {
        let prefix = shm::unique_prefix("lock");
        assert_eq!(running_supervisor(&prefix), None, "no file, no system");
        let first = SystemLock::acquire(&prefix).expect("first lock");
        assert_eq!(first.stale_pid, None);
        // Record locks belong to the process: a second acquire from this process would
        // succeed, so the holder check is what this test can see.
        let text = std::fs::read_to_string(first.lock.path()).expect("lock file");
        assert_eq!(text.trim(), std::process::id().to_string());
        first.lock.release();
        assert!(!lock_path(&prefix).exists());
        assert_eq!(running_supervisor(&prefix), None);
    }

    #[test]
    fn an_unlocked_file_with_a_pid_is_stale() {
        let prefix = shm::unique_prefix("lockstale");
        std::fs::write(lock_path(&prefix), "4242\n").expect("stale lock file");
        assert_eq!(running_supervisor(&prefix), None, "nobody holds it");
        let got = SystemLock::acquire(&prefix).expect("lock");
        assert_eq!(got.stale_pid, Some(4242));
        got.lock.release();
    }
}
