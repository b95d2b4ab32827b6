//! Shared-memory housekeeping: what a prefix leaves on the machine, and removing it.
//!
//! iceoryx2 keeps data segments and management files in `/dev/shm` and service, node and
//! event files under `/tmp/iceoryx2`, all named with the system's prefix; hng's wake segments
//! ([`crate::wake`]) and CPU register ([`crate::cpus`]) live in `/dev/shm` too. A clean stop
//! of every process removes almost all of it; what a crash leaves behind is reclaimed by
//! iceoryx2's dead-node cleanup when a node starts, and what is left at the very end (for
//! example the prefix's global management file) by [`remove_prefix_files`], which the
//! supervisor calls after its last module has stopped.

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::ptr::NonNull;

use nix::fcntl::OFlag;
use nix::sys::mman::{MapFlags, ProtFlags, mmap, munmap, shm_open};
use nix::sys::stat::Mode;

use crate::error::Error;

/// A small segment in `/dev/shm` shared by the processes of a system, mapped read-write (a
/// new one reads as zeros); unmapped on drop, removed with the prefix.
pub(crate) struct Segment {
    ptr: NonNull<std::ffi::c_void>,
    len: NonZeroUsize,
}

impl Segment {
    /// Opens segment `name` (`/` and the system's prefix first), creating it `len` bytes
    /// long if it is new or shorter; `what` names it in errors.
    pub(crate) fn open(name: &str, len: usize, what: &str) -> Result<Segment, Error> {
        let ctx = || format!("{what}: shared segment {name}");
        let len =
            NonZeroUsize::new(len).ok_or_else(|| Error::Config(format!("{}: empty", ctx())))?;
        let fd = shm_open(
            name,
            OFlag::O_CREAT | OFlag::O_RDWR,
            Mode::S_IRUSR | Mode::S_IWUSR,
        )
        .map_err(|e| Error::io(ctx(), e))?;
        let st = nix::sys::stat::fstat(&fd).map_err(|e| Error::io(ctx(), e))?;
        let want = i64::try_from(len.get()).map_err(|_| Error::Config(ctx()))?;
        if st.st_size < want {
            nix::unistd::ftruncate(&fd, want).map_err(|e| Error::io(ctx(), e))?;
        }
        // SAFETY: a shared mapping of a file at least `len` long; the callers access it only
        // through atomics.
        let ptr = unsafe {
            mmap(
                None,
                len,
                ProtFlags::PROT_READ | ProtFlags::PROT_WRITE,
                MapFlags::MAP_SHARED,
                &fd,
                0,
            )
        }
        .map_err(|e| Error::io(ctx(), e))?;
        Ok(Segment { ptr, len })
    }

    /// The mapping as a `T` (page-aligned).
    ///
    /// # Safety
    /// `T` must fit the segment's length, be valid for any bit pattern another process may
    /// write (atomics), and only be used while `self` lives.
    pub(crate) unsafe fn get<T>(&self) -> &T {
        debug_assert!(std::mem::size_of::<T>() <= self.len.get());
        // SAFETY: forwarded to the caller; the mapping is page-aligned and at least `len`.
        unsafe { self.ptr.cast::<T>().as_ref() }
    }
}

impl Drop for Segment {
    fn drop(&mut self) {
        // SAFETY: mapped in `open` with this length; no reference outlives self.
        let _ = unsafe { munmap(self.ptr, self.len.get()) };
    }
}

/// Folders where iceoryx2 and hng put files.
pub const SHM_DIR: &str = "/dev/shm";
/// iceoryx2's root folder for service, node and event files.
pub const IOX_ROOT: &str = "/tmp/iceoryx2";

/// iceoryx2's folder of per-node folders (under [`IOX_ROOT`]): each is named by the node's id
/// (not by the prefix) and holds only that node's files, which are named with the prefix.
fn node_dir() -> PathBuf {
    Path::new(IOX_ROOT).join("nodes")
}

fn walk(dir: &Path, prefix: &str, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let in_node_dir = dir == node_dir();
    for e in entries.flatten() {
        let path = e.path();
        let name = e.file_name();
        let name = name.to_string_lossy();
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            if name.starts_with(prefix) {
                out.push(path);
            } else if in_node_dir && holds_only(&path, prefix) {
                // A node of this prefix that died: the folder goes with its files, or an
                // empty folder would stay behind.
                out.push(path);
            } else {
                walk(&path, prefix, out);
            }
        } else if name.starts_with(prefix) {
            out.push(path);
        }
    }
}

/// True if `dir` is not empty and every entry in it is named with `prefix`.
fn holds_only(dir: &Path, prefix: &str) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    let mut any = false;
    for e in entries.flatten() {
        if !e.file_name().to_string_lossy().starts_with(prefix) {
            return false;
        }
        any = true;
    }
    any
}

/// Every file or folder in `/dev/shm` and `/tmp/iceoryx2` whose name starts with `prefix`.
pub fn prefix_files(prefix: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if prefix.is_empty() {
        return out;
    }
    walk(Path::new(SHM_DIR), prefix, &mut out);
    walk(Path::new(IOX_ROOT), prefix, &mut out);
    out.sort();
    out
}

/// Files that belong to the system as a whole rather than to one process, and so outlive a
/// clean stop of every module until [`remove_prefix_files`]: iceoryx2's management file of
/// the prefix, hng's wake segments and CPU register.
pub fn is_system_file(path: &Path) -> bool {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    name.ends_with(".global_mgmt")
        || name.contains(crate::wake::WAKE_TAG)
        || name.contains(crate::cpus::CPUS_TAG)
}

/// What a prefix leaves behind that no clean stop should: [`prefix_files`] less
/// [`is_system_file`]s.
pub fn leftovers(prefix: &str) -> Vec<PathBuf> {
    prefix_files(prefix)
        .into_iter()
        .filter(|p| !is_system_file(p))
        .collect()
}

/// Removes every file or folder that [`prefix_files`] lists; returns how many were removed.
/// Call only when no process of the prefix runs any more.
pub fn remove_prefix_files(prefix: &str) -> usize {
    let mut n = 0;
    for p in prefix_files(prefix) {
        let ok = if p.is_dir() {
            std::fs::remove_dir_all(&p).is_ok()
        } else {
            std::fs::remove_file(&p).is_ok()
        };
        n += usize::from(ok);
    }
    n
}

/// Removes the prefix's system files ([`is_system_file`]: iceoryx2's management file, hng's
/// wake segments and CPU register) when nothing else of the prefix is left, that is, when no
/// other node lives on it (a living node keeps its files, a dead one's stay until cleaned):
/// what a standalone module, started without a supervisor, does at exit. Returns how many
/// files were removed (0 while anything else of the prefix remains).
pub fn remove_system_files_if_alone(prefix: &str) -> usize {
    let files = prefix_files(prefix);
    if files.iter().any(|p| !is_system_file(p)) {
        return 0;
    }
    files
        .iter()
        .filter(|p| std::fs::remove_file(p).is_ok())
        .count()
}

/// A prefix unique to this process and call, for tests and tools that must not collide:
/// `hng<tag>_<pid>_<n>_`.
pub fn unique_prefix(tag: &str) -> String {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    format!("hng{tag}_{}_{n}_", std::process::id())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dead_node_folder_of_the_prefix_is_removed_with_its_files() {
        let prefix = unique_prefix("shm");
        let other = unique_prefix("shmother");
        let nodes = node_dir();
        std::fs::create_dir_all(&nodes).expect("node folder");
        let mine = nodes.join(format!("9{}", std::process::id()));
        let shared = nodes.join(format!("8{}", std::process::id()));
        for d in [&mine, &shared] {
            std::fs::create_dir_all(d).expect("node folder");
        }
        std::fs::write(mine.join(format!("{prefix}a.node_monitor")), b"").expect("file");
        std::fs::write(mine.join(format!("{prefix}b.details")), b"").expect("file");
        std::fs::write(shared.join(format!("{prefix}c.details")), b"").expect("file");
        std::fs::write(shared.join(format!("{other}d.details")), b"").expect("file");

        let listed = prefix_files(&prefix);
        assert!(listed.contains(&mine), "{listed:?}");
        assert!(
            !listed.contains(&shared),
            "a folder with another prefix's file is kept"
        );
        remove_prefix_files(&prefix);
        assert!(!mine.exists());
        assert!(shared.exists() && !shared.join(format!("{prefix}c.details")).exists());
        assert!(shared.join(format!("{other}d.details")).exists());
        let _ = std::fs::remove_dir_all(&shared);
    }

    #[test]
    fn system_files_go_only_when_nothing_else_of_the_prefix_is_left() {
        let prefix = unique_prefix("shmsys");
        let shm = Path::new(SHM_DIR);
        let system = [
            shm.join(format!("{prefix}{}", crate::cpus::CPUS_TAG)),
            shm.join(format!("{prefix}{}0123", crate::wake::WAKE_TAG)),
            shm.join(format!("{prefix}x.global_mgmt")),
        ];
        for f in &system {
            std::fs::write(f, b"").expect("system file");
        }
        // Another node's data segment: it stays, and so do the system files.
        let data = shm.join(format!("{prefix}svc.data"));
        std::fs::write(&data, b"").expect("data file");
        assert_eq!(remove_system_files_if_alone(&prefix), 0);
        assert!(system.iter().all(|f| f.exists()));
        std::fs::remove_file(&data).expect("remove data file");
        assert_eq!(remove_system_files_if_alone(&prefix), 3);
        assert!(prefix_files(&prefix).is_empty());
    }
}
