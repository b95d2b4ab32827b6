//! One module's leaf cgroup: creation, limits, counters, freezing, and placing a child in it.

#[allow(clippy::wildcard_imports)]
use super::*;

/// The leaf cgroup(s) of one module.
#[derive(Debug)]
pub struct ModuleCgroup {
    pub(super) module: String,
    pub(super) version: Option<CgroupVersion>,
    pub(super) dirs: Vec<(PathBuf, [bool; 5])>,
    pub(super) removed: bool,
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

    pub(super) fn refused(&self, cap: String, why: String) -> Cap {
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

    pub(super) fn kill_listed(&self) -> Result<()> {
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

pub(super) fn freeze(state: &Path, on: bool) -> std::io::Result<()> {
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
    pub(super) fds: Vec<OwnedFd>,
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
        let mut buf = [0u8; 20];
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
pub(super) fn format_pid(pid: i32, buf: &mut [u8; 20]) -> &[u8] {
    hng_runtime::fatal::decimal(u64::try_from(pid).unwrap_or(0), buf)
}
