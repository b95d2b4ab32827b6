//! Shared-memory housekeeping: what a prefix leaves on the machine, and removing it.
//!
//! Everything of a system lives in `/dev/shm` (a tmpfs) and is named with its prefix: iceoryx2's
//! data segments and management files, hng's wake segments ([`crate::wake`]) and CPU register
//! ([`crate::cpus`]), and the system's own iceoryx2 root folder `/dev/shm/<prefix>iox`
//! ([`iox_root`]) with iceoryx2's service, node and event files. A clean stop of every process
//! removes almost all of it; what a crash leaves behind is reclaimed by iceoryx2's dead-node
//! cleanup when a node of the same prefix starts, and what is left at the very end (the
//! prefix's global management file, the root folder) by [`remove_prefix_files`], which the
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

/// The folder where iceoryx2 and hng put a system's files (a tmpfs).
pub const SHM_DIR: &str = "/dev/shm";
/// The name of a system's iceoryx2 root folder after its prefix ([`iox_root`]).
pub const IOX_ROOT_TAG: &str = "iox";
/// iceoryx2's folders of service and node files inside a root (its `global.service.directory`
/// and `global.node.directory`): they outlive a clean stop of every node, as the root does.
const IOX_DIRS: [&str; 2] = ["services", "nodes"];

/// The longest unix socket path the kernel takes: `sun_path` holds 108 bytes with the NUL.
pub const SUN_PATH_MAX: usize = 107;
/// The longest name iceoryx2 gives an event socket after the prefix: the listener's id (a
/// `u128` in decimal, up to 39 digits; about 31 seen) and `.event`.
const EVENT_NAME_MAX: usize = 39 + ".event".len();
/// The longest prefix hng accepts: iceoryx2 names an event socket
/// `/dev/shm/<prefix>iox/<prefix><id>.event`, and that path must fit [`SUN_PATH_MAX`]:
/// `9 + P + 3 + 1 + P + 45 <= 107`, so 24 bytes.
pub const MAX_PREFIX_LEN: usize =
    (SUN_PATH_MAX - SHM_DIR.len() - 1 - IOX_ROOT_TAG.len() - 1 - EVENT_NAME_MAX) / 2;

/// Refuses a prefix too long for the socket paths iceoryx2 makes of it ([`MAX_PREFIX_LEN`]).
pub fn check_prefix(prefix: &str) -> Result<(), Error> {
    if prefix.len() > MAX_PREFIX_LEN {
        return Err(Error::Config(format!(
            "prefix {prefix:?} is {} bytes, longer than the {MAX_PREFIX_LEN} allowed: iceoryx2's \
             event sockets are named {SHM_DIR}/<prefix>{IOX_ROOT_TAG}/<prefix><up to \
             {EVENT_NAME_MAX} characters>, and a unix socket path is limited to 108 bytes \
             (sun_path)",
            prefix.len()
        )));
    }
    Ok(())
}

/// The system's iceoryx2 root folder, `/dev/shm/<prefix>iox`: iceoryx2's service, node and
/// event files of the prefix, removed with the prefix's other files.
pub fn iox_root(prefix: &str) -> PathBuf {
    Path::new(SHM_DIR).join(format!("{prefix}{IOX_ROOT_TAG}"))
}

/// [`iox_root`] as iceoryx2's root path (with its closing `/`), once the prefix is checked
/// ([`check_prefix`]).
pub(crate) fn iox_root_path(prefix: &str) -> Result<iceoryx2::prelude::Path, Error> {
    check_prefix(prefix)?;
    let root = format!("{}/", iox_root(prefix).display());
    use iceoryx2::prelude::SemanticString as _;
    iceoryx2::prelude::Path::new(root.as_bytes())
        .map_err(|e| Error::Config(format!("iceoryx2 root {root:?}: {e:?}")))
}

/// True for a system's iceoryx2 root folder ([`iox_root`]) and iceoryx2's service and node
/// folders inside it, which stay (empty) after a clean stop of every node.
fn is_iox_folder(path: &Path) -> bool {
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    let is_root = |p: &Path| {
        p.parent() == Some(Path::new(SHM_DIR))
            && name(p).is_some_and(|n| n.ends_with(IOX_ROOT_TAG))
            && p.is_dir()
    };
    is_root(path)
        || (path.parent().is_some_and(is_root)
            && name(path).is_some_and(|n| IOX_DIRS.contains(&n.as_str()))
            && path.is_dir())
}

/// Every file and folder below `dir` (all of it belongs to the root's prefix).
fn walk_all(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        out.push(path.clone());
        if is_dir {
            walk_all(&path, out);
        }
    }
}

/// Every file of `prefix`: the files in `/dev/shm` whose name starts with it, and its iceoryx2
/// root folder ([`iox_root`]) with everything in it. Sorted, so a folder comes before what it
/// holds. The files of another system whose prefix starts with this one (`hng_x_` when this
/// one is `hng_`), known by its root folder, are not listed: stopping one system must not
/// remove a running neighbour's files.
pub fn prefix_files(prefix: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if prefix.is_empty() {
        return out;
    }
    let root = iox_root(prefix);
    let Ok(entries) = std::fs::read_dir(SHM_DIR) else {
        return out;
    };
    let entries: Vec<_> = entries
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
        .collect();
    // Systems whose prefix starts with this one (`hng_x_` when this one is `hng_`), known by
    // their iceoryx2 root folder: their files are theirs.
    let others: Vec<String> = entries
        .iter()
        .filter(|e| e.path() != root && e.file_type().is_ok_and(|t| t.is_dir()))
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_suffix(IOX_ROOT_TAG).map(str::to_owned)
        })
        .filter(|other| other.len() > prefix.len())
        .collect();
    for e in entries {
        let path = e.path();
        let name = e.file_name().to_string_lossy().into_owned();
        if others.iter().any(|o| name.starts_with(o.as_str())) {
            continue;
        }
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            // hng's only folders in /dev/shm are iceoryx2 roots: another one is another
            // system's (`hng_x_iox` for prefix `hng_x_` when this prefix is `hng_`).
            if path == root {
                out.push(path);
                walk_all(&root, &mut out);
            }
        } else {
            out.push(path);
        }
    }
    out.sort();
    out
}

/// Files that belong to the system as a whole rather than to one process, and so outlive a
/// clean stop of every module until [`remove_prefix_files`]: iceoryx2's management file of
/// the prefix, hng's wake segments and CPU register, the system's iceoryx2 root folder and
/// iceoryx2's service and node folders in it (not what they hold).
pub fn is_system_file(path: &Path) -> bool {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    name.ends_with(".global_mgmt")
        || name.contains(crate::wake::WAKE_TAG)
        || name.contains(crate::cpus::CPUS_TAG)
        || is_iox_folder(path)
}

/// What a prefix leaves behind that no clean stop should: [`prefix_files`] less
/// [`is_system_file`]s.
pub fn leftovers(prefix: &str) -> Vec<PathBuf> {
    prefix_files(prefix)
        .into_iter()
        .filter(|p| !is_system_file(p))
        .collect()
}

/// Removes every file or folder that [`prefix_files`] lists but `keep`; returns how many were
/// removed. Call only when no process of the prefix runs any more.
pub fn remove_prefix_files_but(prefix: &str, keep: Option<&Path>) -> usize {
    let mut n = 0;
    // Deepest first: a folder's files go before the folder itself.
    for p in prefix_files(prefix).iter().rev() {
        if Some(p.as_path()) == keep {
            continue;
        }
        let ok = if p.is_dir() {
            std::fs::remove_dir_all(p).is_ok()
        } else {
            std::fs::remove_file(p).is_ok()
        };
        n += usize::from(ok);
    }
    n
}

/// Removes every file or folder that [`prefix_files`] lists (the iceoryx2 root folder with
/// everything in it); returns how many were removed. Call only when no process of the prefix
/// runs any more.
pub fn remove_prefix_files(prefix: &str) -> usize {
    remove_prefix_files_but(prefix, None)
}

/// Removes the prefix's system files ([`is_system_file`]: iceoryx2's management file, hng's
/// wake segments and CPU register, the empty iceoryx2 root folder) when nothing else of the
/// prefix is left, that is, when no other node lives on it (a living node keeps its files, a
/// dead one's stay until cleaned): what a standalone module, started without a supervisor,
/// and every `hng` command do at exit. Returns how many were removed (0 while anything else
/// of the prefix remains).
pub fn remove_system_files_if_alone(prefix: &str) -> usize {
    let files = prefix_files(prefix);
    if files.iter().any(|p| !is_system_file(p)) {
        return 0;
    }
    // Deepest first; a folder only if it is empty (a node starting meanwhile keeps it).
    files
        .iter()
        .rev()
        .filter(|p| {
            if p.is_dir() {
                std::fs::remove_dir(p).is_ok()
            } else {
                std::fs::remove_file(p).is_ok()
            }
        })
        .count()
}

/// A prefix unique to this process and call, for tests and tools that must not collide:
/// `hng<tag>_<pid>_<n>_`, the tag shortened to keep it within [`MAX_PREFIX_LEN`].
pub fn unique_prefix(tag: &str) -> String {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let rest = format!("_{}_{n}_", std::process::id());
    let room = MAX_PREFIX_LEN.saturating_sub("hng".len() + rest.len());
    let tag: String = tag
        .chars()
        .scan(0, |len, c| {
            *len += c.len_utf8();
            (*len <= room).then_some(c)
        })
        .collect();
    format!("hng{tag}{rest}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_root_folder_is_listed_with_what_it_holds_and_removed_with_the_prefix() {
        let prefix = unique_prefix("shmroot");
        // A system whose prefix starts with this one: its root is not this prefix's.
        let other = format!("{prefix}x_");
        let root = iox_root(&prefix);
        let node = root.join("nodes").join("123");
        let services = root.join("services");
        for d in [&node, &services, &iox_root(&other)] {
            std::fs::create_dir_all(d).expect("folder");
        }
        let files = [
            node.join(format!("{prefix}a.node_monitor")),
            services.join(format!("{prefix}b.service")),
            root.join(format!("{prefix}123.event")),
            Path::new(SHM_DIR).join(format!("{prefix}c.data")),
        ];
        // The other system's files beside its root (its wake segment, a data segment).
        let others = [
            Path::new(SHM_DIR).join(format!("{other}hngwake_1")),
            Path::new(SHM_DIR).join(format!("{other}d.data")),
        ];
        for f in files.iter().chain(&others) {
            std::fs::write(f, b"").expect("file");
        }
        let listed = prefix_files(&prefix);
        let mut want = vec![
            root.clone(),
            root.join("nodes"),
            node.clone(),
            services.clone(),
        ];
        want.extend(files.iter().cloned());
        want.sort();
        assert_eq!(
            listed, want,
            "the root, its folders and files; not the other system's root nor files"
        );
        // The root and iceoryx2's two folders stay after a clean stop; what they hold does not.
        let left = leftovers(&prefix);
        assert!(
            left.contains(&node) && files.iter().all(|f| left.contains(f)),
            "{left:?}"
        );
        assert!(
            !left.contains(&root) && !left.contains(&services),
            "{left:?}"
        );
        assert_eq!(remove_prefix_files(&prefix), want.len());
        assert!(!root.exists() && prefix_files(&prefix).is_empty());
        assert!(
            iox_root(&other).exists() && others.iter().all(|f| f.exists()),
            "another system's root and files are left alone"
        );
        assert_eq!(remove_prefix_files(&other), 1 + others.len());
    }

    #[test]
    fn prefixes_longer_than_the_socket_paths_allow_are_refused() {
        assert_eq!(MAX_PREFIX_LEN, 24);
        let long = "hng_".repeat(7);
        let e = check_prefix(&long).expect_err("28 bytes").to_string();
        assert!(
            e.contains("28 bytes") && e.contains("24") && e.contains("108 bytes"),
            "{e}"
        );
        check_prefix(&long[..MAX_PREFIX_LEN]).expect("24 bytes");
        let e = crate::channel::iceoryx_config(&long)
            .expect_err("refused")
            .to_string();
        assert!(e.contains("sun_path"), "{e}");
        // Unique prefixes keep within the limit, however long their tag.
        let p = unique_prefix("a_tag_much_longer_than_a_prefix_can_hold");
        assert_eq!(p.len(), MAX_PREFIX_LEN, "{p}");
        assert!(p.starts_with("hnga_tag") && p.ends_with('_'), "{p}");
        assert!(unique_prefix("t").starts_with("hngt_"));
    }

    /// A node's service, node and event files go to its system's root in /dev/shm (the event
    /// socket of the longest prefix fits), none to iceoryx2's default `/tmp/iceoryx2`; a clean
    /// stop leaves only the system files.
    #[test]
    fn a_nodes_files_live_in_its_systems_root() {
        use crate::channel::{Node, NodeOptions};
        use crate::wait::{WaitMode, Waiter};
        let prefix = unique_prefix("shmnode_with_a_long_tag");
        assert_eq!(prefix.len(), MAX_PREFIX_LEN);
        let root = iox_root(&prefix);
        {
            let node = Node::new(NodeOptions::new("a").prefix(&prefix)).expect("node");
            let publisher = node
                .publisher::<crate::msg::Twist>("t/cmd")
                .expect("publisher");
            let subscriber = node
                .subscriber::<crate::msg::Twist>("t/cmd")
                .expect("subscriber");
            let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
            waiter.attach(&subscriber).expect("attach");
            publisher
                .publish(crate::msg::Twist::default())
                .expect("publish");
            let listed = prefix_files(&prefix);
            let under = |dir: &Path, end: &str| {
                listed
                    .iter()
                    .any(|p| p.starts_with(dir) && p.to_string_lossy().ends_with(end))
            };
            assert!(under(&root.join("services"), ".service"), "{listed:?}");
            assert!(under(&root.join("nodes"), ".details"), "{listed:?}");
            assert!(under(&root, ".event"), "{listed:?}");
            let default_root = Path::new("/tmp/iceoryx2");
            let mut stray = Vec::new();
            for dir in [default_root.to_path_buf(), default_root.join("services")] {
                for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                    if e.file_name().to_string_lossy().starts_with(&prefix) {
                        stray.push(e.path());
                    }
                }
            }
            assert!(
                stray.is_empty(),
                "files in iceoryx2's default root: {stray:?}"
            );
            drop((waiter, subscriber, publisher, node));
        }
        assert_eq!(
            leftovers(&prefix),
            Vec::<PathBuf>::new(),
            "after a clean stop"
        );
        assert!(root.exists(), "the root stays until the prefix is removed");
        assert!(remove_system_files_if_alone(&prefix) > 0);
        assert_eq!(prefix_files(&prefix), Vec::<PathBuf>::new());
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
        // The root with iceoryx2's empty folders is the system's too, but not a node's file.
        let root = iox_root(&prefix);
        let node = root.join("nodes").join("9");
        std::fs::create_dir_all(&node).expect("node folder");
        std::fs::create_dir_all(root.join("services")).expect("service folder");
        std::fs::remove_file(&data).expect("remove data file");
        assert_eq!(remove_system_files_if_alone(&prefix), 0, "a node's folder");
        std::fs::remove_dir(&node).expect("remove the node's folder");
        assert_eq!(remove_system_files_if_alone(&prefix), 6);
        assert!(prefix_files(&prefix).is_empty());
    }
}
