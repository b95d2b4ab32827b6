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

/// cgroup version in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CgroupVersion {
    /// Legacy: one hierarchy per controller.
    V1,
    /// Unified hierarchy.
    V2,
}

#[derive(Debug, Clone)]
enum Backend {
    V2 {
        base: PathBuf,
        controllers: [bool; 5],
    },
    V1 {
        bases: [Option<PathBuf>; 5],
    },
    None {
        reason: String,
    },
}

/// What this machine lets hng do with cgroups. Cheap to clone.
#[derive(Debug, Clone)]
pub struct CgroupSupport {
    backend: Backend,
}

impl CgroupSupport {
    /// Detects the writable hierarchies (call once per process and clone). Never fails: with nothing writable it logs
    /// [`FALLBACK_WARNING`] once per process and returns a support that creates cgroups
    /// without directories.
    ///
    /// Detection creates and removes a probe directory in each candidate hierarchy
    /// (that is the writability test).
    #[must_use]
    pub fn detect() -> Self {
        let support = match detect_backend() {
            Ok(b) => CgroupSupport { backend: b },
            Err(reason) => CgroupSupport::none(reason),
        };
        if let Backend::None { reason } = &support.backend {
            NO_CGROUP_WARNING.call_once(|| {
                tracing::warn!("no writable cgroup controller ({reason}): {FALLBACK_WARNING}");
            });
        }
        support
    }

    /// Uses a given cgroup v2 directory as the base (for instance a subtree delegated by
    /// systemd, or the v2 hierarchy of a hybrid machine) whatever controllers it has:
    /// with none, placement, CPU accounting (`cpu.stat`) and `cgroup.kill` still work
    /// and every cap falls to software.
    pub fn with_v2_base(base: impl Into<PathBuf>) -> Result<Self> {
        let base = base.into();
        let path = base.join("cgroup.controllers");
        let avail = fs::read_to_string(&path).map_err(|e| RmError::io("read", &path, e))?;
        let mut controllers = [false; 5];
        for c in [Controller::Cpu, Controller::Memory, Controller::Pids] {
            controllers[c.index()] = avail.split_whitespace().any(|w| w == c.name());
        }
        writable(&base).map_err(RmError::NoCgroups)?;
        Ok(CgroupSupport {
            backend: Backend::V2 { base, controllers },
        })
    }

    /// The cgroup v2 directory this process is in, if a cgroup2 file system is mounted
    /// (whether or not it has controllers or is writable).
    #[must_use]
    pub fn own_v2_dir() -> Option<PathBuf> {
        let mountinfo = fs::read_to_string("/proc/self/mountinfo").ok()?;
        let own = fs::read_to_string("/proc/self/cgroup").ok()?;
        let mounts = parse_mountinfo(&mountinfo);
        let m = mounts.iter().find(|m| m.fstype == "cgroup2")?;
        let (_, v2) = parse_proc_cgroup(&own);
        Some(base_dir(m, &v2?))
    }

    /// A support without cgroups (measuring only). Does not warn; `detect` does.
    #[must_use]
    pub fn none(reason: impl Into<String>) -> Self {
        CgroupSupport {
            backend: Backend::None {
                reason: reason.into(),
            },
        }
    }

    /// The version in use, `None` without writable cgroups.
    #[must_use]
    pub fn version(&self) -> Option<CgroupVersion> {
        match self.backend {
            Backend::V1 { .. } => Some(CgroupVersion::V1),
            Backend::V2 { .. } => Some(CgroupVersion::V2),
            Backend::None { .. } => None,
        }
    }

    /// Whether a controller is usable (for v2: available at the base; enabling it for
    /// the children may still fail, see [`CgroupRun::create`]).
    #[must_use]
    pub fn has(&self, c: Controller) -> bool {
        match &self.backend {
            Backend::V1 { bases } => bases[c.index()].is_some(),
            // v2 accounts CPU in every cgroup.
            Backend::V2 { controllers, .. } => c == Controller::Cpuacct || controllers[c.index()],
            Backend::None { .. } => false,
        }
    }

    /// Whether anything is writable.
    #[must_use]
    pub fn is_writable(&self) -> bool {
        !matches!(self.backend, Backend::None { .. })
    }

    /// One line for logs and skip messages.
    #[must_use]
    pub fn describe(&self) -> String {
        match &self.backend {
            Backend::V2 { base, controllers } => format!(
                "cgroup v2 at {} with [{}]",
                base.display(),
                names(controllers)
            ),
            Backend::V1 { bases } => {
                let list: Vec<String> = Controller::ALL
                    .iter()
                    .filter_map(|c| {
                        bases[c.index()]
                            .as_ref()
                            .map(|b| format!("{}={}", c.name(), b.display()))
                    })
                    .collect();
                format!("cgroup v1: {}", list.join(", "))
            }
            Backend::None { reason } => format!("no writable cgroups ({reason})"),
        }
    }
}

fn names(set: &[bool; 5]) -> String {
    Controller::ALL
        .iter()
        .filter(|c| set[c.index()])
        .map(|c| c.name())
        .collect::<Vec<_>>()
        .join(" ")
}

struct Mount {
    root: String,
    point: PathBuf,
    fstype: String,
    super_opts: String,
}

fn unescape_mount(s: &str) -> String {
    // mountinfo escapes space, tab, newline and backslash as \ooo.
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'\\'
            && i + 4 <= b.len()
            && b[i + 1..i + 4].iter().all(|d| (b'0'..=b'7').contains(d))
        {
            let v = (b[i + 1] - b'0') * 64 + (b[i + 2] - b'0') * 8 + (b[i + 3] - b'0');
            out.push(v);
            i += 4;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn parse_mountinfo(text: &str) -> Vec<Mount> {
    text.lines()
        .filter_map(|line| {
            let (pre, post) = line.split_once(" - ")?;
            let pre: Vec<&str> = pre.split(' ').collect();
            let mut post = post.split(' ');
            let fstype = post.next()?;
            if fstype != "cgroup" && fstype != "cgroup2" {
                return None;
            }
            let _source = post.next()?;
            let super_opts = post.next().unwrap_or("");
            Some(Mount {
                root: unescape_mount(pre.get(3)?),
                point: PathBuf::from(unescape_mount(pre.get(4)?)),
                fstype: fstype.to_owned(),
                super_opts: super_opts.to_owned(),
            })
        })
        .collect()
}

/// Own cgroup paths: (v1 controller list, path) and the v2 path.
fn parse_proc_cgroup(text: &str) -> (Vec<(Vec<String>, String)>, Option<String>) {
    let mut v1 = Vec::new();
    let mut v2 = None;
    for line in text.lines() {
        let mut parts = line.splitn(3, ':');
        let (Some(id), Some(ctrls), Some(path)) = (parts.next(), parts.next(), parts.next()) else {
            continue;
        };
        if id == "0" && ctrls.is_empty() {
            v2 = Some(path.to_owned());
        } else {
            v1.push((
                ctrls.split(',').map(str::to_owned).collect(),
                path.to_owned(),
            ));
        }
    }
    (v1, v2)
}

/// `<mount point>/<own path relative to the mount root>`.
fn base_dir(mount: &Mount, own: &str) -> PathBuf {
    let rel = if mount.root == "/" {
        own
    } else {
        own.strip_prefix(mount.root.as_str()).unwrap_or("")
    };
    let rel = rel.trim_start_matches('/');
    // A process in a cgroup namespace may see "/.." style paths; do not leave the mount.
    if rel.split('/').any(|c| c == "..") || rel.is_empty() {
        mount.point.clone()
    } else {
        mount.point.join(rel)
    }
}

/// Writability test: create and remove a probe directory in `base`.
fn writable(base: &Path) -> std::result::Result<(), String> {
    let probe = base.join(format!("hng-probe-{}", unique_run_id()));
    match fs::create_dir(&probe) {
        Ok(()) => {
            let _ = fs::remove_dir(&probe);
            Ok(())
        }
        Err(e) => Err(format!("{}: {e}", base.display())),
    }
}

fn detect_backend() -> std::result::Result<Backend, String> {
    let mountinfo = fs::read_to_string("/proc/self/mountinfo")
        .map_err(|e| format!("cannot read /proc/self/mountinfo: {e}"))?;
    let own = fs::read_to_string("/proc/self/cgroup")
        .map_err(|e| format!("cannot read /proc/self/cgroup: {e}"))?;
    let mounts = parse_mountinfo(&mountinfo);
    let (own_v1, own_v2) = parse_proc_cgroup(&own);
    let mut reasons = Vec::new();

    // v2 first: used when it has any of the controllers that matter.
    if let (Some(m), Some(own2)) = (mounts.iter().find(|m| m.fstype == "cgroup2"), &own_v2) {
        let base = base_dir(m, own2);
        let avail = fs::read_to_string(base.join("cgroup.controllers")).unwrap_or_default();
        let mut controllers = [false; 5];
        for c in [Controller::Cpu, Controller::Memory, Controller::Pids] {
            controllers[c.index()] = avail.split_whitespace().any(|w| w == c.name());
        }
        if controllers.iter().any(|&b| b) {
            match writable(&base) {
                Ok(()) => return Ok(Backend::V2 { base, controllers }),
                Err(e) => reasons.push(format!("cgroup v2 not writable: {e}")),
            }
        } else {
            reasons.push(format!(
                "cgroup v2 at {} has no cpu/memory/pids controller",
                base.display()
            ));
        }
    }

    let mut bases: [Option<PathBuf>; 5] = Default::default();
    for c in Controller::ALL {
        let Some(m) = mounts
            .iter()
            .find(|m| m.fstype == "cgroup" && m.super_opts.split(',').any(|o| o == c.name()))
        else {
            continue;
        };
        let own_path = own_v1
            .iter()
            .find(|(ctrls, _)| ctrls.iter().any(|x| x == c.name()))
            .map_or("/", |(_, p)| p.as_str());
        let base = base_dir(m, own_path);
        match writable(&base) {
            Ok(()) => bases[c.index()] = Some(base),
            Err(e) => reasons.push(format!("cgroup v1 {} not writable: {e}", c.name())),
        }
    }
    if bases.iter().any(Option::is_some) {
        return Ok(Backend::V1 { bases });
    }
    if reasons.is_empty() {
        reasons.push("no cgroup file system mounted".into());
    }
    Err(reasons.join("; "))
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
    /// Creates `hng/<system>-<run_id>` in every usable hierarchy. Without cgroups this
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

/// The leaf cgroup(s) of one module.
#[derive(Debug)]
pub struct ModuleCgroup {
    module: String,
    version: Option<CgroupVersion>,
    dirs: Vec<(PathBuf, [bool; 5])>,
    removed: bool,
}

impl ModuleCgroup {
    /// Module name.
    #[must_use]
    pub fn module(&self) -> &str {
        &self.module
    }

    /// cgroup version, `None` when the module has no cgroup (measuring only).
    #[must_use]
    pub fn version(&self) -> Option<CgroupVersion> {
        self.version
    }

    /// Whether the module has at least one cgroup directory.
    #[must_use]
    pub fn is_real(&self) -> bool {
        !self.dirs.is_empty()
    }

    /// The directory serving a controller.
    #[must_use]
    pub fn dir(&self, c: Controller) -> Option<&Path> {
        self.dirs
            .iter()
            .find(|(_, set)| set[c.index()])
            .map(|(d, _)| d.as_path())
    }

    /// All directories (one on v2, one per hierarchy on v1).
    pub fn dirs(&self) -> impl Iterator<Item = &Path> {
        self.dirs.iter().map(|(d, _)| d.as_path())
    }

    /// The CPU counter for the sampler, if the module's CPU is accounted in a cgroup.
    #[must_use]
    pub fn cpu_counter(&self) -> Option<CgroupCpu> {
        match self.version? {
            CgroupVersion::V1 => Some(CgroupCpu {
                path: self.dir(Controller::Cpuacct)?.join("cpuacct.usage"),
                version: CgroupVersion::V1,
            }),
            CgroupVersion::V2 => Some(CgroupCpu {
                path: self.dirs.first()?.0.join("cpu.stat"),
                version: CgroupVersion::V2,
            }),
        }
    }

    fn refused(&self, cap: String, why: String) -> Cap {
        let err = RmError::CapRefused {
            module: self.module.clone(),
            cap,
            why: why.clone(),
        };
        warn_once(err.to_string());
        Cap::Software { reason: why }
    }

    /// Writes the caps. Never fails: a cap the kernel refuses (or that has no writable
    /// controller) is logged once here with the fallback and comes back as
    /// [`Cap::Software`] (CPU, memory) or [`Cap::Unenforced`] (pids); give
    /// [`AppliedLimits::software_limits`] to a [`crate::limits::SoftwareEnforcer`].
    ///
    /// CPU: quota = percent/100 × period with the period 100 ms; when that quota would be
    /// under the kernel's 1 ms minimum the period is lengthened (up to 1 s), and below
    /// 0.1% of a core the cap falls to software.
    pub fn apply_limits(&self, limits: &ResourceLimits) -> AppliedLimits {
        let Some(version) = self.version else {
            return AppliedLimits::all_software(limits, "no writable cgroup");
        };
        let cpu = match limits.cpu_percent {
            None => Cap::NotRequested,
            Some(pct) => match (self.dir(Controller::Cpu), cpu_quota(pct)) {
                (None, _) => self.refused(
                    format!("cpu quota {pct}%"),
                    "no writable cpu controller".into(),
                ),
                (_, Err(why)) => self.refused(format!("cpu quota {pct}%"), why),
                (Some(dir), Ok((quota, period))) => {
                    let res = match version {
                        CgroupVersion::V2 => {
                            write_file(&dir.join("cpu.max"), &format!("{quota} {period}"))
                        }
                        CgroupVersion::V1 => {
                            write_file(&dir.join("cpu.cfs_period_us"), &period.to_string())
                                .and_then(|()| {
                                    write_file(&dir.join("cpu.cfs_quota_us"), &quota.to_string())
                                })
                        }
                    };
                    match res {
                        Ok(()) => Cap::Kernel,
                        Err(e) => self.refused(
                            format!("cpu quota {quota} µs per {period} µs ({pct}%)"),
                            e.to_string(),
                        ),
                    }
                }
            },
        };
        let memory = match limits.memory_bytes {
            None => Cap::NotRequested,
            Some(bytes) => match self.dir(Controller::Memory) {
                None => self.refused(
                    format!("memory limit {bytes} bytes"),
                    "no writable memory controller".into(),
                ),
                Some(dir) => {
                    let file = match version {
                        CgroupVersion::V2 => "memory.max",
                        CgroupVersion::V1 => "memory.limit_in_bytes",
                    };
                    match write_file(&dir.join(file), &bytes.to_string()) {
                        Ok(()) => Cap::Kernel,
                        Err(e) => {
                            self.refused(format!("memory limit {bytes} bytes"), e.to_string())
                        }
                    }
                }
            },
        };
        if let (Some(high), Some(dir), Some(CgroupVersion::V2)) = (
            limits.memory_high_bytes,
            self.dir(Controller::Memory),
            self.version,
        ) && let Err(e) = write_file(&dir.join("memory.high"), &high.to_string())
        {
            warn_once(format!(
                "cannot set memory.high {high} for module '{}': {e}; only the hard limit applies",
                self.module
            ));
        }
        let pids = match limits.pids {
            None => Cap::NotRequested,
            Some(n) => match self.dir(Controller::Pids) {
                None => {
                    warn_once(format!(
                        "no writable pids controller: pids limit {n} of module '{}' is not enforced",
                        self.module
                    ));
                    Cap::Unenforced {
                        reason: "no writable pids controller".into(),
                    }
                }
                Some(dir) => match write_file(&dir.join("pids.max"), &n.to_string()) {
                    Ok(()) => Cap::Kernel,
                    Err(e) => {
                        warn_once(format!(
                            "kernel refused pids limit {n} for module '{}': {e}; not enforced",
                            self.module
                        ));
                        Cap::Unenforced {
                            reason: e.to_string(),
                        }
                    }
                },
            },
        };
        AppliedLimits { cpu, memory, pids }
    }

    /// Opens every `cgroup.procs` of the module for writing, in the parent, before fork.
    /// Without cgroups the placement is empty and placing is a no-op.
    pub fn placement(&self) -> Result<Placement> {
        let mut fds = Vec::with_capacity(self.dirs.len());
        for (dir, _) in &self.dirs {
            let path = dir.join("cgroup.procs");
            let f: File = OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_CLOEXEC)
                .open(&path)
                .map_err(|e| RmError::io("open", &path, e))?;
            fds.push(OwnedFd::from(f));
        }
        Ok(Placement { fds })
    }

    /// OOM kills in this cgroup so far (v2 `memory.events` `oom_kill`, v1
    /// `memory.oom_control` `oom_kill`). `None` without a memory controller or on a
    /// kernel that does not report the counter.
    pub fn oom_kills(&self) -> Result<Option<u64>> {
        let (Some(dir), Some(version)) = (self.dir(Controller::Memory), self.version) else {
            return Ok(None);
        };
        let path = dir.join(match version {
            CgroupVersion::V2 => "memory.events",
            CgroupVersion::V1 => "memory.oom_control",
        });
        let text = fs::read(&path).map_err(|e| RmError::io("read", &path, e))?;
        Ok(find_kv(&text, b"oom_kill ").or_else(|| find_kv(&text, b"oom_kill\t")))
    }

    /// The caps the kernel currently enforces on this group, read back from the cgroup
    /// files (`cpu.max` / `cpu.cfs_quota_us`+`cpu.cfs_period_us`, `memory.max` /
    /// `memory.limit_in_bytes`, `pids.max`): `None` fields are unlimited or unreadable.
    /// Lets a process that did not write the caps (the RM) tell which limits the kernel
    /// takes care of.
    #[must_use]
    pub fn kernel_caps(&self) -> ResourceLimits {
        let read = |c: Controller, file: &str| -> Option<String> {
            fs::read_to_string(self.dir(c)?.join(file)).ok()
        };
        let num = |t: &str| t.trim().parse::<u64>().ok();
        let mut caps = ResourceLimits::default();
        match self.version {
            Some(CgroupVersion::V2) => {
                if let Some(t) = read(Controller::Cpu, "cpu.max") {
                    let mut it = t.split_whitespace();
                    if let (Some(q), Some(p)) = (it.next().and_then(num), it.next().and_then(num))
                        && p > 0
                    {
                        caps.cpu_percent = Some(100.0 * q as f64 / p as f64);
                    }
                }
                caps.memory_bytes = read(Controller::Memory, "memory.max").and_then(|t| num(&t));
                caps.memory_high_bytes =
                    read(Controller::Memory, "memory.high").and_then(|t| num(&t));
            }
            Some(CgroupVersion::V1) => {
                let quota = read(Controller::Cpu, "cpu.cfs_quota_us")
                    .and_then(|t| t.trim().parse::<i64>().ok());
                let period = read(Controller::Cpu, "cpu.cfs_period_us").and_then(|t| num(&t));
                if let (Some(q), Some(p)) = (quota, period)
                    && q > 0
                    && p > 0
                {
                    caps.cpu_percent = Some(100.0 * q as f64 / p as f64);
                }
                // v1 reports "no limit" as a huge page-aligned number.
                caps.memory_bytes = read(Controller::Memory, "memory.limit_in_bytes")
                    .and_then(|t| num(&t))
                    .filter(|&b| b < (1 << 62));
            }
            None => {}
        }
        caps.pids = read(Controller::Pids, "pids.max").and_then(|t| num(&t));
        caps
    }

    /// Pids currently in the module's cgroup(s).
    pub fn pids(&self) -> Result<Vec<i32>> {
        let mut all = Vec::new();
        for (dir, _) in &self.dirs {
            let path = dir.join("cgroup.procs");
            let mut p = read_pids(&path).map_err(|e| RmError::io("read", &path, e))?;
            all.append(&mut p);
        }
        all.sort_unstable();
        all.dedup();
        Ok(all)
    }

    /// SIGKILLs every process of the group: v2 `cgroup.kill` (race-free, Linux 5.14+);
    /// otherwise freeze (v1 freezer, when available), SIGKILL each pid in
    /// `cgroup.procs`, thaw. The caller still waits for (reaps) its own children.
    pub fn kill_all(&self) -> Result<()> {
        if self.version == Some(CgroupVersion::V2)
            && let Some((dir, _)) = self.dirs.first()
        {
            let kill = dir.join("cgroup.kill");
            if kill.exists() {
                return write_file(&kill, "1").map_err(|e| RmError::io("write", &kill, e));
            }
        }
        let freezer = self
            .dir(Controller::Freezer)
            .map(|d| d.join("freezer.state"));
        let frozen = match &freezer {
            Some(state) => freeze(state, true).is_ok(),
            None => false,
        };
        let result = self.kill_listed();
        if let (Some(state), true) = (&freezer, frozen) {
            freeze(state, false).map_err(|e| RmError::io("write", state, e))?;
        }
        result
    }

    fn kill_listed(&self) -> Result<()> {
        let mut killed: Vec<i32> = Vec::new();
        // Without a freezer a process may fork while we kill; rescan until no new pid.
        for _ in 0..100 {
            let pids = self.pids()?;
            let fresh: Vec<i32> = pids.into_iter().filter(|p| !killed.contains(p)).collect();
            if fresh.is_empty() {
                return Ok(());
            }
            for pid in fresh {
                // ESRCH: already gone.
                let _ = nix::sys::signal::kill(
                    nix::unistd::Pid::from_raw(pid),
                    nix::sys::signal::Signal::SIGKILL,
                );
                killed.push(pid);
            }
        }
        Ok(())
    }

    /// Removes the module's cgroup directories. The group must be empty: kill it and
    /// wait for the processes first, else [`RmError::CgroupBusy`].
    pub fn remove(mut self) -> Result<()> {
        for (dir, _) in &self.dirs {
            rmdir_cgroup(dir)?;
        }
        self.removed = true;
        Ok(())
    }
}

impl Drop for ModuleCgroup {
    fn drop(&mut self) {
        if !self.removed {
            for (dir, _) in &self.dirs {
                let _ = fs::remove_dir(dir);
            }
        }
    }
}

fn freeze(state: &Path, on: bool) -> std::io::Result<()> {
    write_file(state, if on { "FROZEN" } else { "THAWED" })?;
    if !on {
        return Ok(());
    }
    // Freezing is asynchronous: wait (bounded) until the kernel reports FROZEN.
    let deadline = Instant::now() + Duration::from_millis(200);
    loop {
        let s = fs::read_to_string(state)?;
        if s.trim() == "FROZEN" {
            return Ok(());
        }
        if Instant::now() >= deadline {
            return Err(std::io::Error::new(
                ErrorKind::TimedOut,
                format!("{} did not reach FROZEN", state.display()),
            ));
        }
        std::thread::yield_now();
    }
}

/// CFS quota and period (µs) for a CPU share in % of one core.
pub fn cpu_quota(percent: f64) -> std::result::Result<(u64, u64), String> {
    if !(percent.is_finite() && percent > 0.0) {
        return Err(format!(
            "cpu limit must be a positive percentage, got {percent}"
        ));
    }
    let mut period = DEFAULT_CPU_PERIOD_US;
    let mut quota = (percent / 100.0 * period as f64).round();
    if quota < MIN_CPU_QUOTA_US as f64 {
        // Lengthen the period so the quota reaches the kernel's 1 ms minimum.
        let needed = (MIN_CPU_QUOTA_US as f64 * 100.0 / percent).ceil();
        if needed > MAX_CPU_PERIOD_US as f64 {
            return Err(format!(
                "{percent}% of a core is under the kernel minimum quota of {MIN_CPU_QUOTA_US} µs per {MAX_CPU_PERIOD_US} µs (0.1%)"
            ));
        }
        period = needed as u64;
        quota = MIN_CPU_QUOTA_US as f64;
    }
    if quota > 1e15 {
        return Err(format!("cpu limit {percent}% is too large"));
    }
    Ok((quota as u64, period))
}

/// Pre-opened `cgroup.procs` descriptors of one module (see [`ModuleCgroup::placement`]).
#[derive(Debug)]
pub struct Placement {
    fds: Vec<OwnedFd>,
}

impl Placement {
    /// A placement that does nothing (no cgroups).
    #[must_use]
    pub fn empty() -> Self {
        Placement { fds: Vec::new() }
    }

    /// Whether placing does nothing.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.fds.is_empty()
    }

    /// Moves the calling process into the module's cgroups.
    ///
    /// Async-signal-safe: only `getpid()` and `write()` on descriptors opened before the
    /// fork, the pid formatted on the stack, no allocation, no lock. Meant for
    /// `std::os::unix::process::CommandExt::pre_exec`:
    ///
    /// ```no_run
    /// # fn f(cg: &hng_rm::cgroup::ModuleCgroup) -> Result<(), Box<dyn std::error::Error>> {
    /// use std::os::unix::process::CommandExt;
    /// let placement = cg.placement()?;
    /// let mut cmd = std::process::Command::new("/usr/bin/my-module");
    /// // SAFETY: place_self is async-signal-safe.
    /// unsafe { cmd.pre_exec(move || placement.place_self()) };
    /// let child = cmd.spawn()?;
    /// # Ok(()) }
    /// ```
    ///
    /// The descriptors are close-on-exec, so the module never inherits them.
    pub fn place_self(&self) -> std::io::Result<()> {
        // SAFETY: getpid has no preconditions and is async-signal-safe.
        let pid = unsafe { libc::getpid() };
        self.place(pid)
    }

    /// Moves `pid` into the module's cgroups (also async-signal-safe).
    pub fn place(&self, pid: i32) -> std::io::Result<()> {
        let mut buf = [0u8; 16];
        let text = format_pid(pid, &mut buf);
        for fd in &self.fds {
            // SAFETY: fd is an open descriptor owned by self; text points to
            // text.len() initialised bytes on the stack.
            let n = unsafe { libc::write(fd.as_raw_fd(), text.as_ptr().cast(), text.len()) };
            if n < 0 {
                return Err(std::io::Error::last_os_error());
            }
            if n as usize != text.len() {
                return Err(std::io::Error::from_raw_os_error(libc::EIO));
            }
        }
        Ok(())
    }
}

/// Formats a non-negative pid into `buf` without allocating; a negative pid gives "0"
/// (which the kernel reads as "the writing process").
fn format_pid(pid: i32, buf: &mut [u8; 16]) -> &[u8] {
    let mut v = u32::try_from(pid).unwrap_or(0);
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (v % 10) as u8;
        v /= 10;
        if v == 0 || i == 0 {
            break;
        }
    }
    &buf[i..]
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
    use super::*;

    #[test]
    fn formats_pids() {
        let mut b = [0u8; 16];
        assert_eq!(format_pid(0, &mut b), b"0");
        assert_eq!(format_pid(7, &mut b), b"7");
        assert_eq!(format_pid(4_194_304, &mut b), b"4194304");
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
