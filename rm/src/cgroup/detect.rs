//! Which cgroup hierarchy this process can use: mounts, its own cgroup, controllers, write access.

#[allow(clippy::wildcard_imports)]
use super::*;

/// cgroup version in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CgroupVersion {
    /// Legacy: one hierarchy per controller.
    V1,
    /// Unified hierarchy.
    V2,
}

#[derive(Debug, Clone)]
pub(super) enum Backend {
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
    pub(super) backend: Backend,
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

pub(super) fn names(set: &[bool; 5]) -> String {
    Controller::ALL
        .iter()
        .filter(|c| set[c.index()])
        .map(|c| c.name())
        .collect::<Vec<_>>()
        .join(" ")
}

pub(super) struct Mount {
    pub(super) root: String,
    pub(super) point: PathBuf,
    pub(super) fstype: String,
    pub(super) super_opts: String,
}

pub(super) fn unescape_mount(s: &str) -> String {
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

pub(super) fn parse_mountinfo(text: &str) -> Vec<Mount> {
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
pub(super) fn parse_proc_cgroup(text: &str) -> (Vec<(Vec<String>, String)>, Option<String>) {
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
pub(super) fn base_dir(mount: &Mount, own: &str) -> PathBuf {
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
pub(super) fn writable(base: &Path) -> std::result::Result<(), String> {
    let probe = base.join(format!("hng-probe-{}", unique_run_id()));
    match fs::create_dir(&probe) {
        Ok(()) => {
            let _ = fs::remove_dir(&probe);
            Ok(())
        }
        Err(e) => Err(format!("{}: {e}", base.display())),
    }
}

pub(super) fn detect_backend() -> std::result::Result<Backend, String> {
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
