//! One cgroup per module: detection of what is writable, creation, caps, placement from a
//! pre-exec hook, OOM read-back, group kill and removal.
//!
//! Layout: `<base>/hng/<system>-<run id>/<module>` in every hierarchy used, where
//! `<base>` is the cgroup this process is in (so a delegated subtree, e.g. a systemd
//! unit with `Delegate=yes`, is respected) under the hierarchy's mount point.
//! The shared `hng` directory is removed by the last run to leave.
//!
//! * cgroup v2 (one hierarchy): used when its root lists `cpu`, `memory` or `pids` in
//!   `cgroup.controllers`; the controllers are enabled down the path through
//!   `cgroup.subtree_control` (v2's "no internal processes" rule means `<base>` must be
//!   the root or hold no process for this to work).
//! * cgroup v1 (one hierarchy per controller): `cpu`, `cpuacct`, `memory`, `pids` and
//!   `freezer` (for a race-free group kill), each used if its directory is writable.
//! * nothing writable: a single `tracing::warn` ("measuring only; limits enforced by
//!   stopping a module over its limit"), and [`ModuleCgroup`]s without directories whose
//!   [`ModuleCgroup::apply_limits`] hands every cap to software (see
//!   [`crate::limits::SoftwareEnforcer`]).
//!
//! Placement: [`ModuleCgroup::placement`] opens every `cgroup.procs` in the parent;
//! [`Placement::place_self`] only calls `getpid` and `write`, so it is async-signal-safe
//! and can run in a `CommandExt::pre_exec` hook between fork and exec. Memory is charged
//! to the cgroup that faulted it in, so the child must be placed before it execs.

use std::collections::HashSet;
use std::ffi::OsStr;
use std::fs::{self, File, OpenOptions};
use std::io::{ErrorKind, Write};
use std::os::fd::{AsRawFd, OwnedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, Once, OnceLock};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::error::{Result, RmError};
use crate::limits::{AppliedLimits, Cap, ResourceLimits};
use crate::sampler::{find_kv, parse_u64};

#[allow(clippy::wildcard_imports)]
use self::detect::*;
pub use self::detect::{CgroupSupport, CgroupVersion};
pub use self::module::{ModuleCgroup, Placement, cpu_quota};

mod detect;
mod module;

/// The text of the one-time warning when no cgroup is writable.
pub const FALLBACK_WARNING: &str =
    "measuring only; limits enforced by stopping a module over its limit";

/// Smallest CFS quota the kernel accepts (1 ms), in µs.
pub const MIN_CPU_QUOTA_US: u64 = 1_000;
/// Largest CFS period the kernel accepts (1 s), in µs.
pub const MAX_CPU_PERIOD_US: u64 = 1_000_000;
/// Default CFS period (100 ms), in µs.
pub const DEFAULT_CPU_PERIOD_US: u64 = 100_000;

static NO_CGROUP_WARNING: Once = Once::new();
static WARNED: OnceLock<Mutex<HashSet<String>>> = OnceLock::new();

/// Logs `msg` as a warning the first time it is seen in this process (a module
/// restarted ten times with a cap the kernel refuses warns once).
fn warn_once(msg: String) {
    let set = WARNED.get_or_init(|| Mutex::new(HashSet::new()));
    let first = match set.lock() {
        Ok(mut s) => s.insert(msg.clone()),
        Err(poisoned) => poisoned.into_inner().insert(msg.clone()),
    };
    if first {
        tracing::warn!("{msg}");
    }
}

/// A cgroup controller hng uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Controller {
    /// CPU bandwidth (quota).
    Cpu,
    /// CPU accounting (v1 only; v2 accounts CPU in every cgroup).
    Cpuacct,
    /// Memory.
    Memory,
    /// Number of tasks.
    Pids,
    /// Freezer (v1 only; used to kill a group without races).
    Freezer,
}

impl Controller {
    const ALL: [Controller; 5] = [
        Controller::Cpu,
        Controller::Cpuacct,
        Controller::Memory,
        Controller::Pids,
        Controller::Freezer,
    ];

    /// Name as in `/proc/self/cgroup` and `cgroup.controllers`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Controller::Cpu => "cpu",
            Controller::Cpuacct => "cpuacct",
            Controller::Memory => "memory",
            Controller::Pids => "pids",
            Controller::Freezer => "freezer",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

fn check_name(name: &str) -> Result<()> {
    let why = if name.is_empty() {
        Some("empty")
    } else if name.len() > 200 {
        Some("longer than 200 bytes")
    } else if name.contains('/') || name.contains('\0') {
        Some("contains '/' or NUL")
    } else if name.starts_with('.') {
        Some("starts with '.'")
    } else {
        None
    };
    match why {
        Some(why) => Err(RmError::InvalidName {
            name: name.to_owned(),
            why,
        }),
        None => Ok(()),
    }
}

fn mkdir(path: &Path) -> Result<()> {
    match fs::create_dir(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == ErrorKind::AlreadyExists => Ok(()),
        Err(e) => Err(RmError::io("create directory", path, e)),
    }
}

/// Creates `<base>/hng/<run>`: the shared `hng` parent is removed by the last run to
/// leave, so it may vanish between our two mkdirs; retry then.
fn mkdir_run(run: &Path) -> Result<()> {
    let parent = run.parent().unwrap_or(run);
    let mut attempts = 0;
    loop {
        mkdir(parent)?;
        match fs::create_dir(run) {
            Ok(()) => return Ok(()),
            Err(e) if e.kind() == ErrorKind::AlreadyExists => return Ok(()),
            Err(e) if e.kind() == ErrorKind::NotFound && attempts < 10 => attempts += 1,
            Err(e) => return Err(RmError::io("create directory", run, e)),
        }
    }
}

/// The pid of the process that created run `name` (`<system>-<pid>-<ns>`, [`unique_run_id`]).
fn creator_pid(name: &str) -> Option<i32> {
    let mut parts = name.rsplitn(3, '-');
    let ns = parts.next()?;
    let pid = parts.next()?;
    parts.next().filter(|system| !system.is_empty())?;
    ns.parse::<u128>().ok()?;
    pid.parse::<i32>().ok().filter(|p| *p > 0)
}

/// Removes the runs under `hng` whose creator is dead (a supervisor killed by SIGKILL
/// removes nothing): each `<system>-<pid>-<ns>` directory whose pid no longer exists, its
/// module directories first. A cgroup that still holds a process is not removable
/// (`EBUSY`): such a run, a run of a live pid (or of a pid reused since) and anything not
/// named like a run are left alone, and so is `own` (the run being created). Returns the
/// runs removed.
fn remove_stale_runs(hng: &Path, own: &str) -> usize {
    let Ok(entries) = fs::read_dir(hng) else {
        return 0;
    };
    let mut removed = 0;
    for run in entries.flatten() {
        let name = run.file_name();
        let Some(pid) = name.to_str().filter(|n| *n != own).and_then(creator_pid) else {
            continue;
        };
        // ESRCH: no such process; 0 or EPERM: alive.
        // SAFETY: kill with signal 0 only checks that the pid exists.
        let dead = unsafe { libc::kill(pid, 0) } == -1
            && std::io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
        if !dead || !run.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        let path = run.path();
        if let Ok(modules) = fs::read_dir(&path) {
            for m in modules.flatten() {
                if m.file_type().is_ok_and(|t| t.is_dir()) {
                    let _ = fs::remove_dir(m.path());
                }
            }
        }
        if fs::remove_dir(&path).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Removes the shared `hng` parent if this was the last run in it.
fn rmdir_shared_parent(run: &Path) {
    if let Some(parent) = run.parent() {
        // ENOTEMPTY / EBUSY: another run is still there.
        let _ = fs::remove_dir(parent);
    }
}

fn write_file(path: &Path, value: &str) -> std::io::Result<()> {
    // One write() call: cgroup files act on each write.
    let mut f = OpenOptions::new().write(true).open(path)?;
    f.write_all(value.as_bytes())
}

fn enable_v2_controllers(dir: &Path, wanted: &[bool; 5]) -> [bool; 5] {
    let path = dir.join("cgroup.subtree_control");
    let current = fs::read_to_string(&path).unwrap_or_default();
    let mut enabled = [false; 5];
    for c in [Controller::Cpu, Controller::Memory, Controller::Pids] {
        if !wanted[c.index()] {
            continue;
        }
        if current.split_whitespace().any(|w| w == c.name()) {
            enabled[c.index()] = true;
            continue;
        }
        match write_file(&path, &format!("+{}", c.name())) {
            Ok(()) => enabled[c.index()] = true,
            Err(e) => warn_once(format!(
                "cannot enable the {} controller in {}: {e}; {}",
                c.name(),
                path.display(),
                FALLBACK_WARNING
            )),
        }
    }
    enabled
}

/// The cgroups of one run of one system: `hng/<system>-<run id>` in every hierarchy.
#[derive(Debug)]
pub struct CgroupRun {
    support: CgroupSupport,
    /// One directory per distinct hierarchy with the controllers it serves.
    dirs: Vec<(PathBuf, [bool; 5])>,
    name: String,
    /// Created by this process (removed on drop when empty); false for a run attached
    /// with [`CgroupRun::open`], which never removes anything.
    owned: bool,
}

/// A run id unique on this machine for this process: `<pid>-<ns since epoch>`.
#[must_use]
pub fn unique_run_id() -> String {
    let ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{}-{ns}", std::process::id())
}

impl CgroupRun {
    /// Creates `hng/<system>-<run_id>` in every usable hierarchy, after removing the runs
    /// dead processes left there (one log line says how many). Without cgroups this
    /// succeeds and creates nothing (every module cap then falls to software).
    pub fn create(support: &CgroupSupport, system: &str, run_id: &str) -> Result<Self> {
        let name = format!("{system}-{run_id}");
        check_name(&name)?;
        let mut dirs: Vec<(PathBuf, [bool; 5])> = Vec::new();
        match &support.backend {
            Backend::None { .. } => {}
            Backend::V2 { base, controllers } => {
                let base_enabled = enable_v2_controllers(base, controllers);
                let hng = base.join("hng");
                let run = hng.join(&name);
                mkdir_run(&run)?;
                let hng_enabled = enable_v2_controllers(&hng, &base_enabled);
                let mut run_enabled = enable_v2_controllers(&run, &hng_enabled);
                run_enabled[Controller::Cpuacct.index()] = true;
                dirs.push((run, run_enabled));
            }
            Backend::V1 { bases } => {
                for c in Controller::ALL {
                    let Some(base) = &bases[c.index()] else {
                        continue;
                    };
                    let run = base.join("hng").join(&name);
                    // Co-mounted controllers (e.g. "cpu,cpuacct") share one directory.
                    if let Some((_, set)) = dirs.iter_mut().find(|(d, _)| *d == run) {
                        set[c.index()] = true;
                        continue;
                    }
                    mkdir_run(&run)?;
                    let mut set = [false; 5];
                    set[c.index()] = true;
                    dirs.push((run, set));
                }
            }
        }
        let stale: usize = dirs
            .iter()
            .filter_map(|(run, _)| run.parent())
            .map(|hng| remove_stale_runs(hng, &name))
            .sum();
        if stale > 0 {
            tracing::info!(
                "removed {stale} cgroup(s) of runs whose supervisor died without removing them"
            );
        }
        Ok(CgroupRun {
            support: support.clone(),
            dirs,
            name,
            owned: true,
        })
    }

    /// Attaches to the run `name` (`<system>-<run id>`, what the supervisor passes in
    /// `HNG_CGROUP_RUN`) that another process created, without creating or removing
    /// anything: for the resource manager, which runs as a module inside the run (its
    /// own cgroup is `<base>/hng/<name>/<module>`, so the run is found among its own
    /// cgroup's ancestors, else under `<base>/hng/<name>`). Hierarchies without the run
    /// are skipped; fails when no hierarchy has it.
    pub fn open(support: &CgroupSupport, name: &str) -> Result<Self> {
        check_name(name)?;
        let find = |base: &Path| -> Option<PathBuf> {
            let up = base.ancestors().find(|d| {
                d.file_name() == Some(OsStr::new(name))
                    && d.parent().and_then(Path::file_name) == Some(OsStr::new("hng"))
            });
            let run = up.map_or_else(|| base.join("hng").join(name), Path::to_path_buf);
            run.is_dir().then_some(run)
        };
        let mut dirs: Vec<(PathBuf, [bool; 5])> = Vec::new();
        match &support.backend {
            Backend::None { reason } => {
                return Err(RmError::NoCgroups(reason.clone()));
            }
            Backend::V2 { base, controllers } => {
                if let Some(run) = find(base) {
                    let mut set = *controllers;
                    set[Controller::Cpuacct.index()] = true;
                    dirs.push((run, set));
                }
            }
            Backend::V1 { bases } => {
                for c in Controller::ALL {
                    let Some(run) = bases[c.index()].as_deref().and_then(find) else {
                        continue;
                    };
                    if let Some((_, set)) = dirs.iter_mut().find(|(d, _)| *d == run) {
                        set[c.index()] = true;
                        continue;
                    }
                    let mut set = [false; 5];
                    set[c.index()] = true;
                    dirs.push((run, set));
                }
            }
        }
        if dirs.is_empty() {
            return Err(RmError::NoCgroups(format!(
                "no hierarchy of {} has the run {name}",
                support.describe()
            )));
        }
        Ok(CgroupRun {
            support: support.clone(),
            dirs,
            name: name.to_owned(),
            owned: false,
        })
    }

    /// A view of the existing cgroup of `module` in this run, without creating it;
    /// `None` when no hierarchy has it. The view never removes the directories (its
    /// owner, the supervisor, does); use it to read counters and caps.
    pub fn existing_module(&self, module: &str) -> Result<Option<ModuleCgroup>> {
        check_name(module)?;
        let dirs: Vec<(PathBuf, [bool; 5])> = self
            .dirs
            .iter()
            .map(|(run, set)| (run.join(module), *set))
            .filter(|(d, _)| d.is_dir())
            .collect();
        if dirs.is_empty() {
            return Ok(None);
        }
        Ok(Some(ModuleCgroup {
            module: module.to_owned(),
            version: self.support.version(),
            dirs,
            removed: true,
        }))
    }

    /// `<system>-<run id>`.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The support this run was created with.
    #[must_use]
    pub fn support(&self) -> &CgroupSupport {
        &self.support
    }

    /// Creates (or reuses, e.g. after a restart) the leaf cgroup of a module.
    pub fn module(&self, module: &str) -> Result<ModuleCgroup> {
        check_name(module)?;
        let mut dirs = Vec::with_capacity(self.dirs.len());
        for (run, set) in &self.dirs {
            let dir = run.join(module);
            mkdir(&dir)?;
            dirs.push((dir, *set));
        }
        Ok(ModuleCgroup {
            module: module.to_owned(),
            version: self.support.version(),
            dirs,
            removed: false,
        })
    }

    /// Removes the run directories. Every module cgroup must have been removed first
    /// (leftover empty module directories are removed too).
    pub fn remove(mut self) -> Result<()> {
        let dirs = std::mem::take(&mut self.dirs);
        for (run, _) in &dirs {
            if let Ok(entries) = fs::read_dir(run) {
                for e in entries.flatten() {
                    if e.file_type().is_ok_and(|t| t.is_dir()) {
                        rmdir_cgroup(&e.path())?;
                    }
                }
            }
            rmdir_cgroup(run)?;
            rmdir_shared_parent(run);
        }
        Ok(())
    }
}

impl Drop for CgroupRun {
    fn drop(&mut self) {
        if !self.owned {
            return;
        }
        for (run, _) in &self.dirs {
            if fs::remove_dir(run).is_ok() {
                rmdir_shared_parent(run);
            }
        }
    }
}

fn rmdir_cgroup(dir: &Path) -> Result<()> {
    // After the last process exits the kernel may take a moment to drop its reference.
    let deadline = Instant::now() + Duration::from_millis(500);
    loop {
        match fs::remove_dir(dir) {
            Ok(()) => return Ok(()),
            Err(e) if e.kind() == ErrorKind::NotFound => return Ok(()),
            Err(e) if e.raw_os_error() == Some(libc::EBUSY) => {
                let empty = read_pids(&dir.join("cgroup.procs")).is_ok_and(|p| p.is_empty());
                if !empty || Instant::now() >= deadline {
                    return Err(RmError::CgroupBusy {
                        path: dir.to_owned(),
                    });
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(e) => return Err(RmError::io("remove directory", dir, e)),
        }
    }
}

fn read_pids(path: &Path) -> std::io::Result<Vec<i32>> {
    let text = fs::read_to_string(path)?;
    Ok(text
        .split_whitespace()
        .filter_map(|w| w.parse::<i32>().ok())
        .collect())
}

/// A module's CPU counter in its cgroup, for [`crate::sampler::ModuleTarget`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CgroupCpu {
    path: PathBuf,
    version: CgroupVersion,
}

impl CgroupCpu {
    /// `cpuacct.usage` (v1) or `cpu.stat` (v2).
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Cumulative CPU time in ns from the file's content.
    #[must_use]
    pub fn parse_ns(&self, text: &[u8]) -> Option<u64> {
        match self.version {
            CgroupVersion::V1 => {
                let end = text
                    .iter()
                    .position(|b| !b.is_ascii_digit())
                    .unwrap_or(text.len());
                parse_u64(&text[..end])
            }
            CgroupVersion::V2 => find_kv(text, b"usage_usec").map(|us| us.saturating_mul(1000)),
        }
    }
}

/// Whether a path's last component is a valid module or run name (for callers that
/// build names from user input).
#[must_use]
pub fn is_valid_name(name: impl AsRef<OsStr>) -> bool {
    name.as_ref()
        .to_str()
        .is_some_and(|n| check_name(n).is_ok())
}

#[cfg(test)]
mod tests {
    use super::module::format_pid;
    use super::*;

    #[test]
    fn formats_pids_and_a_negative_one_as_0() {
        let mut b = [0u8; 20];
        assert_eq!(format_pid(i32::MAX, &mut b), b"2147483647");
        assert_eq!(format_pid(-5, &mut b), b"0");
    }

    #[test]
    fn cpu_quota_respects_kernel_bounds() {
        assert_eq!(cpu_quota(20.0), Ok((20_000, 100_000)));
        assert_eq!(cpu_quota(250.0), Ok((250_000, 100_000)));
        // 0.5% -> 0.5 ms per 100 ms is under 1 ms: period stretched to 200 ms.
        assert_eq!(cpu_quota(0.5), Ok((1_000, 200_000)));
        assert_eq!(cpu_quota(0.1), Ok((1_000, 1_000_000)));
        assert!(cpu_quota(0.05).is_err());
        assert!(cpu_quota(0.0).is_err());
        assert!(cpu_quota(f64::NAN).is_err());
        assert!(cpu_quota(-3.0).is_err());
    }

    #[test]
    fn parses_mountinfo_and_proc_cgroup() {
        let mi = "35 24 0:30 / /sys/fs/cgroup/cpu rw,relatime shared:9 - cgroup cgroup rw,cpu\n\
                  36 24 0:31 / /sys/fs/cgroup/my\\040mem rw - cgroup cgroup rw,memory\n\
                  37 24 0:32 / /sys/fs/cgroup/unified rw - cgroup2 cgroup2 rw\n\
                  38 24 0:33 / /proc rw - proc proc rw\n";
        let m = parse_mountinfo(mi);
        assert_eq!(m.len(), 3);
        assert_eq!(m[1].point, PathBuf::from("/sys/fs/cgroup/my mem"));
        assert_eq!(m[2].fstype, "cgroup2");
        let (v1, v2) = parse_proc_cgroup("4:memory:/a/b\n1:cpu,cpuacct:/\n0::/x\n");
        assert_eq!(v1.len(), 2);
        assert_eq!(v1[1].0, vec!["cpu".to_owned(), "cpuacct".to_owned()]);
        assert_eq!(v2.as_deref(), Some("/x"));
        assert_eq!(
            base_dir(&m[1], "/a/b"),
            PathBuf::from("/sys/fs/cgroup/my mem/a/b")
        );
        let nested = Mount {
            root: "/a".into(),
            point: "/c".into(),
            fstype: "cgroup".into(),
            super_opts: String::new(),
        };
        assert_eq!(base_dir(&nested, "/a/b"), PathBuf::from("/c/b"));
        assert_eq!(base_dir(&nested, "/../z"), PathBuf::from("/c"));
    }

    #[test]
    fn cpu_counter_parsing() {
        let v1 = CgroupCpu {
            path: "x".into(),
            version: CgroupVersion::V1,
        };
        assert_eq!(v1.parse_ns(b"735294279653\n"), Some(735_294_279_653));
        let v2 = CgroupCpu {
            path: "x".into(),
            version: CgroupVersion::V2,
        };
        assert_eq!(
            v2.parse_ns(b"usage_usec 1500\nuser_usec 1000\nsystem_usec 500\n"),
            Some(1_500_000)
        );
    }

    #[test]
    fn a_runs_creator_is_read_from_its_name() {
        assert_eq!(
            creator_pid("hng-mission-16257-1796001200572537355"),
            Some(16257)
        );
        assert_eq!(
            creator_pid(&format!("sys-{}", unique_run_id())),
            Some(std::process::id() as i32)
        );
        for not_a_run in ["sys", "sys-1", "sys-x-1", "sys-1-x", "sys-0-5", "-1-2"] {
            assert_eq!(creator_pid(not_a_run), None, "{not_a_run}");
        }
    }

    #[test]
    fn names_are_checked() {
        assert!(is_valid_name("planner"));
        assert!(!is_valid_name("a/b"));
        assert!(!is_valid_name(""));
        assert!(!is_valid_name(".."));
    }

    #[test]
    fn no_cgroups_means_software_caps() {
        let support = CgroupSupport::none("test");
        let run = CgroupRun::create(&support, "sys", "1").expect("run without cgroups");
        let cg = run.module("m").expect("module without cgroups");
        assert!(!cg.is_real());
        let limits = ResourceLimits {
            cpu_percent: Some(20.0),
            memory_bytes: Some(1 << 20),
            memory_high_bytes: None,
            pids: Some(4),
        };
        let applied = cg.apply_limits(&limits);
        assert!(matches!(applied.cpu, Cap::Software { .. }));
        assert!(matches!(applied.memory, Cap::Software { .. }));
        assert!(cg.placement().expect("empty placement").is_empty());
        assert_eq!(cg.oom_kills().expect("no memory cgroup"), None);
        assert!(cg.cpu_counter().is_none());
        cg.remove().expect("nothing to remove");
        run.remove().expect("nothing to remove");
    }
}
