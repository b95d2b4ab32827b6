//! Per-module resource sampling from procfs (and the module's cgroup when it has one).
//!
//! One [`Sampler`] keeps, for each module, `/proc/PID/stat` open and re-reads it with
//! `pread` at offset 0: one system call per module and no allocation per pass. Holding the file open also pins the process: once the process is reaped the
//! read fails with `ESRCH`, so a recycled pid is never mistaken for the module (the
//! start time is compared as well, for a pid handed to [`Sampler::add`] too late).
//!
//! From that one read come CPU time (utime + stime), resident set size and the
//! minor/major page fault counters. CPU % is
//! `100 × Δ(utime + stime) / ticks_per_second / Δt` (per core, so it can exceed 100).
//! With `ticks_per_second` = 100 the granularity is 10 ms per sample, so when the module
//! has its own cgroup the sampler prefers the cgroup's CPU counter (`cpuacct.usage` in
//! ns on v1, `usage_usec` of `cpu.stat` on v2), which also includes the module's
//! children.
//!
//! PSS (proportional set size, which does not double count shared memory such as the
//! iceoryx2 segments every module maps) comes from `/proc/PID/smaps_rollup`. The kernel
//! walks the page tables to produce it (about 56 µs for a `sleep` process here, against
//! 4-6 µs for `stat`; 0.5-1 ms for a module of the default system, which maps every
//! channel's shared memory), so it is read when a module is added and then refreshed every
//! [`SamplerConfig::pss_every`] passes, staggered across modules, but only if its RSS moved
//! by more than 1/16 since the last refresh or [`PSS_MAX_SKIPS`] refreshes were skipped
//! (a module whose memory does not change costs one walk in 30 s instead of one in 5 s:
//! the default system's 15 walks in 5 s were a quarter of the resource manager's CPU at 1x);
//! without
//! `smaps_rollup` (kernel < 4.14, or no permission) `pss_bytes` stays `None` and
//! [`ModuleSample::memory_bytes`] falls back to RSS.
//!
//! For a module with a cgroup CPU counter, `stat` (RSS, faults, liveness) is read only
//! every [`SamplerConfig::cgroup_stat_every`] passes; the counter is read every pass.
//!
//! The procfs crate's `Process::stat()` opens the file, reads it into a fresh `String`
//! and parses every field into a struct: 23 µs per process measured here against 9 µs
//! for the kept-open `pread` path under the same load (parsing is 0.15 µs of that; the
//! rest is the kernel generating the text), see `rm/tests/bench_numbers.rs`. procfs is
//! still used for the constants (`ticks_per_second`, `page_size`).

use std::fs::File;
use std::io::ErrorKind;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::cgroup::CgroupCpu;
use crate::error::{Result, RmError};

/// Scheduled PSS refreshes skipped at most in a row while a module's RSS stays within 1/16 of
/// what it was at the last one (see the module documentation).
pub const PSS_MAX_SKIPS: u32 = 5;

/// Sampler settings. Plain data with documented defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct SamplerConfig {
    /// Sampling rate in Hz (default 10). Only used by [`Sampler::period`]: the caller
    /// drives the passes.
    pub rate_hz: f64,
    /// Refresh PSS from `smaps_rollup` every this many passes (default 50, i.e. every
    /// 5 s at 10 Hz), staggered so each pass reads PSS for about `1/pss_every` of the
    /// modules; PSS is also read when a module is added. 0 disables PSS. Reading
    /// `smaps_rollup` walks the page tables: about 15× the cost of reading `stat` for
    /// a small process, more for a big one.
    pub pss_every: u32,
    /// For a module with a cgroup CPU counter, read `/proc/PID/stat` (RSS, page faults,
    /// liveness) only every this many passes (default 5, i.e. 2 Hz at 10 Hz; staggered):
    /// its CPU comes from the cgroup counter on every pass, which costs ~0.7 µs against
    /// ~4 µs for `stat`. Modules without a cgroup read `stat` on every pass.
    pub cgroup_stat_every: u32,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig {
            rate_hz: 10.0,
            pss_every: 50,
            cgroup_stat_every: 5,
        }
    }
}

/// A process to sample.
#[derive(Debug, Clone)]
pub struct ModuleTarget {
    /// Module name (used in errors and in the samples).
    pub name: String,
    /// Its pid.
    pub pid: i32,
    /// Start time (clock ticks after boot, field 22 of `/proc/PID/stat`) the caller
    /// recorded when it spawned the process, if known: a process with another start time
    /// is refused as a reused pid.
    pub expected_starttime: Option<u64>,
    /// The module's own cgroup CPU counter, if it has one (see
    /// [`crate::cgroup::ModuleCgroup::cpu_counter`]).
    pub cgroup_cpu: Option<CgroupCpu>,
}

impl ModuleTarget {
    /// A target with only a name and a pid.
    #[must_use]
    pub fn new(name: impl Into<String>, pid: i32) -> Self {
        ModuleTarget {
            name: name.into(),
            pid,
            expected_starttime: None,
            cgroup_cpu: None,
        }
    }

    /// Sets the cgroup CPU counter.
    #[must_use]
    pub fn with_cgroup_cpu(mut self, cpu: Option<CgroupCpu>) -> Self {
        self.cgroup_cpu = cpu;
        self
    }

    /// Sets the expected start time.
    #[must_use]
    pub fn with_starttime(mut self, starttime: u64) -> Self {
        self.expected_starttime = Some(starttime);
        self
    }
}

/// State of a sampled process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Liveness {
    /// Running (or sleeping) at the last `stat` read (every pass, or every
    /// [`SamplerConfig::cgroup_stat_every`] passes for a module with a cgroup counter).
    Alive,
    /// The process exited (zombie, or reaped). The sample holds the last values read.
    Exited,
    /// The pid now belongs to another process. The sample holds the last values read.
    PidReused,
    /// Reading failed with another error; the sample holds the last values read.
    ReadError(ErrorKind),
}

/// Where the CPU figure came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CpuSource {
    /// utime + stime of `/proc/PID/stat` (clock-tick granularity).
    ProcStat,
    /// The module's cgroup counter (ns or µs granularity; includes its children).
    Cgroup,
}

/// The latest measurement of one module.
#[derive(Debug, Clone, PartialEq)]
pub struct ModuleSample {
    /// Module name.
    pub name: String,
    /// Pid.
    pub pid: i32,
    /// Process start time (clock ticks after boot).
    pub starttime: u64,
    /// When the sample was taken (the `now` given to [`Sampler::sample`]).
    pub at: Option<Instant>,
    /// Process state.
    pub liveness: Liveness,
    /// CPU use over the last sampling interval, % of one core. `None` until two samples
    /// exist.
    pub cpu_percent: Option<f64>,
    /// Source of `cpu_percent` and `cpu_time`.
    pub cpu_source: CpuSource,
    /// Cumulative CPU time.
    pub cpu_time: Duration,
    /// Resident set size in bytes.
    pub rss_bytes: u64,
    /// Proportional set size in bytes, when `smaps_rollup` is available (refreshed every
    /// `pss_every` passes).
    pub pss_bytes: Option<u64>,
    /// Cumulative minor page faults.
    pub minor_faults: u64,
    /// Cumulative major page faults.
    pub major_faults: u64,
    /// Minor faults per second over the last interval.
    pub minor_faults_per_s: Option<f64>,
    /// Major faults per second over the last interval.
    pub major_faults_per_s: Option<f64>,
}

impl ModuleSample {
    /// Memory use to charge to the module: PSS when known, else RSS.
    #[must_use]
    pub fn memory_bytes(&self) -> u64 {
        self.pss_bytes.unwrap_or(self.rss_bytes)
    }
}

#[derive(Debug, Clone, Copy)]
struct PrevCpu {
    at: Instant,
    cpu_ns: u64,
}

#[derive(Debug, Clone, Copy)]
struct PrevFaults {
    at: Instant,
    minflt: u64,
    majflt: u64,
}

#[derive(Debug)]
struct Target {
    stat: Option<File>,
    /// `smaps_rollup`, opened at the first PSS refresh and kept open (re-read with
    /// `pread` like `stat`: no path walk, no open/close per refresh).
    smaps: Option<File>,
    smaps_path: PathBuf,
    smaps_ok: bool,
    /// RSS at the last PSS refresh, and the scheduled refreshes skipped since.
    pss_rss: u64,
    pss_skips: u32,
    cgroup_cpu: Option<(File, CgroupCpu)>,
    prev_cpu: Option<PrevCpu>,
    prev_faults: Option<PrevFaults>,
}

/// Samples a set of modules. Feed it `now` and call [`Sampler::sample`] at the rate you
/// want (see [`Sampler::period`]).
#[derive(Debug)]
pub struct Sampler {
    config: SamplerConfig,
    ns_per_tick: u64,
    page_size: u64,
    targets: Vec<Target>,
    samples: Vec<ModuleSample>,
    buf: Vec<u8>,
    pass: u64,
}

/// Fields of `/proc/PID/stat` the sampler (and `hng eval nav`'s CPU figures) use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatFields {
    /// Process state (`R`, `S`, `D`, `Z`, `T`, ...).
    pub state: u8,
    /// Parent's pid.
    pub ppid: u32,
    /// Minor page faults.
    pub minflt: u64,
    /// Major page faults.
    pub majflt: u64,
    /// User CPU time, clock ticks.
    pub utime: u64,
    /// System CPU time, clock ticks.
    pub stime: u64,
    /// Start time, clock ticks after boot.
    pub starttime: u64,
    /// Resident set size, pages.
    pub rss_pages: u64,
}

/// Parses the fields the sampler needs out of the text of `/proc/PID/stat`.
/// The command name (field 2) may contain spaces and parentheses, so the fields are
/// counted from the last `)`.
pub fn parse_stat(text: &[u8]) -> Option<StatFields> {
    let close = text.iter().rposition(|&b| b == b')')?;
    let rest = text.get(close + 1..)?;
    let mut it = rest
        .split(|&b| b == b' ' || b == b'\n')
        .filter(|s| !s.is_empty());
    // After ')': index 0 is field 3 (state); field k is index k - 3.
    let state = *it.next()?.first()?;
    let mut nth = |skip: usize| -> Option<u64> { parse_u64(it.nth(skip)?) };
    let ppid = u32::try_from(nth(0)?).ok()?; // index 1 (field 4)
    // Field 10 (minflt) is index 7; we consumed indexes 0 and 1.
    let minflt = nth(5)?; // index 7
    let majflt = nth(1)?; // index 9
    let utime = nth(1)?; // index 11 (field 14)
    let stime = nth(0)?; // index 12 (field 15)
    let starttime = nth(6)?; // index 19 (field 22)
    let rss_pages = nth(1)?; // index 21 (field 24)
    Some(StatFields {
        state,
        ppid,
        minflt,
        majflt,
        utime,
        stime,
        starttime,
        rss_pages,
    })
}

/// Parses an unsigned decimal; a leading `-` (rss may be reported as -1 in odd cases)
/// yields 0.
pub(crate) fn parse_u64(s: &[u8]) -> Option<u64> {
    if s.first() == Some(&b'-') {
        return s[1..].iter().all(u8::is_ascii_digit).then_some(0);
    }
    if s.is_empty() {
        return None;
    }
    let mut v: u64 = 0;
    for &b in s {
        if !b.is_ascii_digit() {
            return None;
        }
        v = v.checked_mul(10)?.checked_add(u64::from(b - b'0'))?;
    }
    Some(v)
}

/// Finds `key` at the start of a line (e.g. `b"Pss:"`) and parses the number after it.
pub(crate) fn find_kv(text: &[u8], key: &[u8]) -> Option<u64> {
    let mut start = 0;
    while start < text.len() {
        let line_end = text[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(text.len(), |p| start + p);
        let line = &text[start..line_end];
        if let Some(rest) = line.strip_prefix(key) {
            let num = rest
                .split(|&b| b == b' ' || b == b'\t')
                .find(|s| !s.is_empty())?;
            return parse_u64(num);
        }
        start = line_end + 1;
    }
    None
}

/// Reads the whole of a (small, procfs or cgroupfs) file from offset 0 into `buf`,
/// growing it if needed. Returns the number of bytes read.
pub(crate) fn pread_all(file: &File, buf: &mut Vec<u8>) -> std::io::Result<usize> {
    loop {
        if buf.len() < buf.capacity() {
            buf.resize(buf.capacity(), 0);
        }
        if buf.is_empty() {
            buf.resize(1024, 0);
        }
        let n = file.read_at(buf, 0)?;
        if n < buf.len() {
            return Ok(n);
        }
        // Filled the buffer: the file may be longer. Grow and read again from 0 so the
        // content is one consistent snapshot.
        let len = buf.len();
        buf.resize(len * 2, 0);
    }
}

/// Reads the start time of `pid` (clock ticks after boot), for PID-reuse checks.
pub fn process_starttime(pid: i32) -> Result<u64> {
    let path = PathBuf::from(format!("/proc/{pid}/stat"));
    let text = std::fs::read(&path).map_err(|e| RmError::io("read", &path, e))?;
    parse_stat(&text)
        .map(|f| f.starttime)
        .ok_or_else(|| RmError::Parse {
            path,
            what: "unexpected format".into(),
        })
}

impl Sampler {
    /// A sampler with no targets.
    pub fn new(config: SamplerConfig) -> Result<Self> {
        if !(config.rate_hz.is_finite() && config.rate_hz > 0.0) {
            return Err(RmError::Config(format!(
                "sampling rate must be a positive number of Hz, got {}",
                config.rate_hz
            )));
        }
        let tps = procfs::ticks_per_second().max(1);
        Ok(Sampler {
            config,
            ns_per_tick: 1_000_000_000 / tps,
            page_size: procfs::page_size(),
            targets: Vec::new(),
            samples: Vec::new(),
            buf: Vec::with_capacity(1024),
            pass: 0,
        })
    }

    /// Time between two passes at the configured rate.
    #[must_use]
    pub fn period(&self) -> Duration {
        Duration::try_from_secs_f64(1.0 / self.config.rate_hz).unwrap_or(Duration::MAX)
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &SamplerConfig {
        &self.config
    }

    /// Starts sampling a module. Opens its `/proc/PID/stat` (kept open) and, if given,
    /// its cgroup CPU counter. Fails if the process does not exist, if its start time
    /// differs from `expected_starttime`, or if the name is already sampled.
    pub fn add(&mut self, target: ModuleTarget) -> Result<()> {
        if self.samples.iter().any(|s| s.name == target.name) {
            return Err(RmError::Duplicate(target.name));
        }
        let stat_path = PathBuf::from(format!("/proc/{}/stat", target.pid));
        let stat = File::open(&stat_path).map_err(|e| {
            if e.kind() == ErrorKind::NotFound {
                RmError::NoSuchProcess {
                    module: target.name.clone(),
                    pid: target.pid,
                }
            } else {
                RmError::io("open", &stat_path, e)
            }
        })?;
        let n = pread_all(&stat, &mut self.buf).map_err(|e| RmError::io("read", &stat_path, e))?;
        let fields = parse_stat(&self.buf[..n]).ok_or_else(|| RmError::Parse {
            path: stat_path.clone(),
            what: "unexpected format".into(),
        })?;
        if let Some(expected) = target.expected_starttime
            && expected != fields.starttime
        {
            return Err(RmError::PidReused {
                module: target.name,
                pid: target.pid,
                expected,
                found: fields.starttime,
            });
        }
        let cgroup_cpu = match target.cgroup_cpu {
            Some(cpu) => {
                let f = File::open(cpu.path()).map_err(|e| RmError::io("open", cpu.path(), e))?;
                Some((f, cpu))
            }
            None => None,
        };
        let cpu_source = if cgroup_cpu.is_some() {
            CpuSource::Cgroup
        } else {
            CpuSource::ProcStat
        };
        let smaps_path = PathBuf::from(format!("/proc/{}/smaps_rollup", target.pid));
        let mut smaps_ok = self.config.pss_every > 0;
        let mut pss_bytes = None;
        if smaps_ok {
            match read_pss_bytes(&smaps_path, &mut self.buf) {
                Ok(Some(pss)) => pss_bytes = Some(pss),
                Ok(None) => smaps_ok = false,
                Err(e) if matches!(e.kind(), ErrorKind::NotFound | ErrorKind::PermissionDenied) => {
                    smaps_ok = false;
                }
                Err(_) => {}
            }
        }
        let rss_bytes = fields.rss_pages.saturating_mul(self.page_size);
        self.targets.push(Target {
            stat: Some(stat),
            smaps: None,
            smaps_path,
            smaps_ok,
            pss_rss: rss_bytes,
            pss_skips: 0,
            cgroup_cpu,
            prev_cpu: None,
            prev_faults: None,
        });
        self.samples.push(ModuleSample {
            name: target.name,
            pid: target.pid,
            starttime: fields.starttime,
            at: None,
            liveness: Liveness::Alive,
            cpu_percent: None,
            cpu_source,
            cpu_time: Duration::ZERO,
            rss_bytes,
            pss_bytes,
            minor_faults: fields.minflt,
            major_faults: fields.majflt,
            minor_faults_per_s: None,
            major_faults_per_s: None,
        });
        Ok(())
    }

    /// Stops sampling a module. Returns whether it was sampled.
    pub fn remove(&mut self, name: &str) -> bool {
        match self.samples.iter().position(|s| s.name == name) {
            Some(i) => {
                self.samples.swap_remove(i);
                self.targets.swap_remove(i);
                true
            }
            None => false,
        }
    }

    /// Number of sampled modules.
    #[must_use]
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether no module is sampled.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The latest samples, one per module (in no particular order).
    #[must_use]
    pub fn samples(&self) -> &[ModuleSample] {
        &self.samples
    }

    /// The latest sample of one module.
    #[must_use]
    pub fn get(&self, name: &str) -> Option<&ModuleSample> {
        self.samples.iter().find(|s| s.name == name)
    }

    /// One sampling pass over every module. `now` should be taken just before the call.
    /// Never fails as a whole: a module whose files cannot be read gets a
    /// [`Liveness`] other than `Alive` and keeps its last values.
    pub fn sample(&mut self, now: Instant) -> &[ModuleSample] {
        let every = u64::from(self.config.pss_every);
        let stat_every = u64::from(self.config.cgroup_stat_every.max(1));
        let pass = self.pass;
        self.pass = self.pass.wrapping_add(1);
        for (i, (t, s)) in self
            .targets
            .iter_mut()
            .zip(self.samples.iter_mut())
            .enumerate()
        {
            // Staggered: module i refreshes PSS on the passes where (pass + i) % every == 0.
            let plan = PassPlan {
                read_pss: every > 0 && pass.wrapping_add(i as u64).is_multiple_of(every),
                read_stat: pass.wrapping_add(i as u64).is_multiple_of(stat_every),
            };
            sample_one(
                t,
                s,
                now,
                plan,
                self.ns_per_tick,
                self.page_size,
                &mut self.buf,
            );
        }
        &self.samples
    }
}

/// What one pass reads for one module.
#[derive(Debug, Clone, Copy)]
struct PassPlan {
    read_stat: bool,
    read_pss: bool,
}

fn mark_gone(t: &mut Target, s: &mut ModuleSample, liveness: Liveness) {
    s.liveness = liveness;
    t.stat = None;
    t.smaps = None;
    s.cpu_percent = None;
}

fn sample_one(
    t: &mut Target,
    s: &mut ModuleSample,
    now: Instant,
    plan: PassPlan,
    ns_per_tick: u64,
    page_size: u64,
    buf: &mut Vec<u8>,
) {
    let Some(stat) = t.stat.as_ref() else {
        return;
    };
    // Without a cgroup counter, stat is the CPU source and is read on every pass.
    let mut proc_ns = None;
    if plan.read_stat || t.cgroup_cpu.is_none() {
        let n = match pread_all(stat, buf) {
            Ok(n) => n,
            Err(e) => {
                let l = if e.raw_os_error() == Some(libc::ESRCH) || e.kind() == ErrorKind::NotFound
                {
                    Liveness::Exited
                } else {
                    Liveness::ReadError(e.kind())
                };
                mark_gone(t, s, l);
                return;
            }
        };
        let Some(f) = parse_stat(&buf[..n]) else {
            s.liveness = Liveness::ReadError(ErrorKind::InvalidData);
            return;
        };
        if f.starttime != s.starttime {
            mark_gone(t, s, Liveness::PidReused);
            return;
        }
        if f.state == b'Z' || f.state == b'X' {
            mark_gone(t, s, Liveness::Exited);
            return;
        }
        s.liveness = Liveness::Alive;
        s.rss_bytes = f.rss_pages.saturating_mul(page_size);
        s.minor_faults = f.minflt;
        s.major_faults = f.majflt;
        if let Some(p) = t.prev_faults {
            let dt = now.saturating_duration_since(p.at).as_secs_f64();
            if dt > 0.0 {
                s.minor_faults_per_s = Some(f.minflt.saturating_sub(p.minflt) as f64 / dt);
                s.major_faults_per_s = Some(f.majflt.saturating_sub(p.majflt) as f64 / dt);
            }
        }
        t.prev_faults = Some(PrevFaults {
            at: now,
            minflt: f.minflt,
            majflt: f.majflt,
        });
        proc_ns = Some(f.utime.saturating_add(f.stime).saturating_mul(ns_per_tick));
    }

    let mut cpu = proc_ns.map(|ns| (ns, CpuSource::ProcStat));
    if let Some((file, kind)) = t.cgroup_cpu.as_ref() {
        match pread_all(file, buf)
            .ok()
            .and_then(|n| kind.parse_ns(&buf[..n]))
        {
            Some(ns) => cpu = Some((ns, CpuSource::Cgroup)),
            None => {
                // The cgroup went away or is unreadable: /proc from the next pass on,
                // and restart the interval so the two sources are never subtracted.
                t.cgroup_cpu = None;
                t.prev_cpu = None;
                cpu = None;
            }
        }
    }
    if let Some((cpu_ns, source)) = cpu {
        s.cpu_source = source;
        s.cpu_time = Duration::from_nanos(cpu_ns);
        if let Some(p) = t.prev_cpu {
            let dt = now.saturating_duration_since(p.at).as_secs_f64();
            if dt > 0.0 {
                s.cpu_percent = Some(100.0 * cpu_ns.saturating_sub(p.cpu_ns) as f64 / 1e9 / dt);
            }
        }
        t.prev_cpu = Some(PrevCpu { at: now, cpu_ns });
        s.at = Some(now);
    }

    if plan.read_pss && t.smaps_ok && !pss_still_fresh(t, s) {
        t.pss_rss = s.rss_bytes;
        t.pss_skips = 0;
        if t.smaps.is_none() {
            t.smaps = File::open(&t.smaps_path).ok();
        }
        let read = match t.smaps.as_ref() {
            Some(f) => pread_all(f, buf)
                .map(|n| find_kv(&buf[..n], b"Pss:").map(|kb| kb.saturating_mul(1024))),
            None => read_pss_bytes(&t.smaps_path, buf),
        };
        match read {
            Ok(Some(pss)) => s.pss_bytes = Some(pss),
            Ok(None) => t.smaps_ok = false,
            Err(e) if e.kind() == ErrorKind::PermissionDenied => t.smaps_ok = false,
            Err(_) => {} // The process is probably exiting; the next stat read tells.
        }
    }
}

/// A scheduled PSS refresh that can be skipped: PSS known, RSS within 1/16 of what it was at
/// the last refresh, fewer than [`PSS_MAX_SKIPS`] skipped (counted here).
fn pss_still_fresh(t: &mut Target, s: &ModuleSample) -> bool {
    let moved = s.rss_bytes.abs_diff(t.pss_rss) > t.pss_rss / 16;
    if s.pss_bytes.is_none() || moved || t.pss_skips >= PSS_MAX_SKIPS {
        return false;
    }
    t.pss_skips += 1;
    true
}

fn read_pss_bytes(path: &Path, buf: &mut Vec<u8>) -> std::io::Result<Option<u64>> {
    let f = File::open(path)?;
    let n = pread_all(&f, buf)?;
    Ok(find_kv(&buf[..n], b"Pss:").map(|kb| kb.saturating_mul(1024)))
}

/// Machine-wide free resources, the input of the cost controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SystemSample {
    /// Fraction of all CPU time that was idle over the last interval, in [0, 1].
    /// `None` on the first sample.
    pub cpu_free: Option<f64>,
    /// `MemAvailable` in bytes.
    pub mem_available_bytes: u64,
    /// `MemTotal` in bytes.
    pub mem_total_bytes: u64,
    /// Number of online CPUs (from `/proc/stat`'s `cpuN` lines at creation).
    pub cpus: u32,
}

impl SystemSample {
    /// Free memory as a fraction of total, in [0, 1].
    #[must_use]
    pub fn mem_free(&self) -> f64 {
        if self.mem_total_bytes == 0 {
            return 0.0;
        }
        (self.mem_available_bytes as f64 / self.mem_total_bytes as f64).clamp(0.0, 1.0)
    }
}

/// Samples `/proc/stat` (first line) and `/proc/meminfo` (first lines) with kept-open files.
#[derive(Debug)]
pub struct SystemSampler {
    stat: File,
    meminfo: File,
    buf: Vec<u8>,
    prev: Option<(u64, u64)>,
    cpus: u32,
}

impl SystemSampler {
    /// Opens `/proc/stat` and `/proc/meminfo`.
    pub fn new() -> Result<Self> {
        let stat = File::open("/proc/stat").map_err(|e| RmError::io("open", "/proc/stat", e))?;
        let meminfo =
            File::open("/proc/meminfo").map_err(|e| RmError::io("open", "/proc/meminfo", e))?;
        let mut buf = Vec::with_capacity(16 * 1024);
        let n = pread_all(&stat, &mut buf).map_err(|e| RmError::io("read", "/proc/stat", e))?;
        let cpus = buf[..n]
            .split(|&b| b == b'\n')
            .filter(|l| l.starts_with(b"cpu") && l.get(3).is_some_and(u8::is_ascii_digit))
            .count();
        Ok(SystemSampler {
            stat,
            meminfo,
            buf,
            prev: None,
            cpus: u32::try_from(cpus.max(1)).unwrap_or(1),
        })
    }

    /// One reading.
    pub fn sample(&mut self) -> Result<SystemSample> {
        let n = pread_all(&self.stat, &mut self.buf)
            .map_err(|e| RmError::io("read", "/proc/stat", e))?;
        let (busy, total) = parse_cpu_line(&self.buf[..n]).ok_or_else(|| RmError::Parse {
            path: "/proc/stat".into(),
            what: "no 'cpu ' line".into(),
        })?;
        let cpu_free = self.prev.and_then(|(pb, pt)| {
            let dt = total.checked_sub(pt)?;
            (dt > 0).then(|| 1.0 - (busy.saturating_sub(pb) as f64 / dt as f64).clamp(0.0, 1.0))
        });
        self.prev = Some((busy, total));
        let n = pread_all(&self.meminfo, &mut self.buf)
            .map_err(|e| RmError::io("read", "/proc/meminfo", e))?;
        let text = &self.buf[..n];
        let total_kb = find_kv(text, b"MemTotal:").ok_or_else(|| RmError::Parse {
            path: "/proc/meminfo".into(),
            what: "no MemTotal".into(),
        })?;
        let avail_kb = find_kv(text, b"MemAvailable:")
            .or_else(|| find_kv(text, b"MemFree:"))
            .unwrap_or(0);
        Ok(SystemSample {
            cpu_free,
            mem_available_bytes: avail_kb.saturating_mul(1024),
            mem_total_bytes: total_kb.saturating_mul(1024),
            cpus: self.cpus,
        })
    }
}

/// (busy, total) jiffies from the aggregate `cpu ` line of /proc/stat. Idle = idle + iowait.
fn parse_cpu_line(text: &[u8]) -> Option<(u64, u64)> {
    let line = text
        .split(|&b| b == b'\n')
        .find(|l| l.starts_with(b"cpu "))?;
    let mut total = 0u64;
    let mut idle = 0u64;
    // user nice system idle iowait irq softirq steal guest guest_nice; guest time is
    // already included in user/nice, so only the first 8 count.
    for (i, v) in line[4..]
        .split(|&b| b == b' ')
        .filter(|s| !s.is_empty())
        .take(8)
        .enumerate()
    {
        let v = parse_u64(v)?;
        total = total.saturating_add(v);
        if i == 3 || i == 4 {
            idle = idle.saturating_add(v);
        }
    }
    Some((total.saturating_sub(idle), total))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_stat_with_spaces_and_parens_in_comm() {
        let text = b"1234 (a b) c)) S 1 1234 1234 0 -1 4194560 111 0 7 0 250 30 0 0 20 0 1 0 98765 1000000 321 18446744073709551615 1 1 0 0 0 0 0 0 0 0 0 0 17 1 0 0 0 0 0\n";
        let f = parse_stat(text).expect("valid stat line");
        assert_eq!(f.state, b'S');
        assert_eq!(f.ppid, 1);
        assert_eq!(f.minflt, 111);
        assert_eq!(f.majflt, 7);
        assert_eq!(f.utime, 250);
        assert_eq!(f.stime, 30);
        assert_eq!(f.starttime, 98765);
        assert_eq!(f.rss_pages, 321);
    }

    #[test]
    fn rejects_truncated_stat() {
        assert!(parse_stat(b"1 (x) S 1 2 3").is_none());
        assert!(parse_stat(b"no paren").is_none());
    }

    #[test]
    fn own_stat_matches_procfs() {
        let me = procfs::process::Process::myself().expect("procfs self");
        let st = me.stat().expect("procfs stat");
        let text = std::fs::read("/proc/self/stat").expect("read own stat");
        let f = parse_stat(&text).expect("parse own stat");
        assert_eq!(f.starttime, st.starttime);
        assert!(f.utime >= st.utime);
    }

    #[test]
    fn finds_pss() {
        let text = b"55-7f ---p 00000000 00:00 0   [rollup]\nRss:  1740 kB\nPss:   349 kB\n";
        assert_eq!(find_kv(text, b"Pss:"), Some(349));
        assert_eq!(find_kv(text, b"Rss:"), Some(1740));
        assert_eq!(find_kv(text, b"Swap:"), None);
    }

    #[test]
    fn a_pss_refresh_is_skipped_while_rss_holds_but_not_for_long() {
        let mib = 1u64 << 20;
        let mut t = Target {
            stat: None,
            smaps: None,
            smaps_path: PathBuf::new(),
            smaps_ok: true,
            pss_rss: 16 * mib,
            pss_skips: 0,
            cgroup_cpu: None,
            prev_cpu: None,
            prev_faults: None,
        };
        let mut s = ModuleSample {
            name: "m".into(),
            pid: 1,
            starttime: 0,
            at: None,
            liveness: Liveness::Alive,
            cpu_percent: None,
            cpu_source: CpuSource::ProcStat,
            cpu_time: Duration::ZERO,
            rss_bytes: 16 * mib + mib / 2,
            pss_bytes: None,
            minor_faults: 0,
            major_faults: 0,
            minor_faults_per_s: None,
            major_faults_per_s: None,
        };
        assert!(!pss_still_fresh(&mut t, &s), "no PSS yet: read it");
        s.pss_bytes = Some(8 * mib);
        for _ in 0..PSS_MAX_SKIPS {
            assert!(pss_still_fresh(&mut t, &s), "RSS within 1/16: skipped");
        }
        assert!(!pss_still_fresh(&mut t, &s), "skipped enough: read it");
        t.pss_skips = 0;
        s.rss_bytes = 18 * mib;
        assert!(!pss_still_fresh(&mut t, &s), "RSS moved by 1/8: read it");
    }

    #[test]
    fn parses_cpu_line() {
        let text = b"cpu  10 0 10 70 10 0 0 0 5 0\ncpu0 1 2 3 4\n";
        assert_eq!(parse_cpu_line(text), Some((20, 100)));
    }

    #[test]
    fn samples_self_and_sees_exit_of_a_reaped_child() {
        let mut s = Sampler::new(SamplerConfig {
            pss_every: 1,
            ..SamplerConfig::default()
        })
        .expect("sampler");
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .expect("spawn sleep");
        let pid = i32::try_from(child.id()).expect("pid fits i32");
        s.add(ModuleTarget::new("sleeper", pid)).expect("add");
        let t0 = Instant::now();
        s.sample(t0);
        let first = s.get("sleeper").expect("sample").clone();
        assert_eq!(first.liveness, Liveness::Alive);
        // (The child may not have faulted in any page yet right after exec, so check
        // RSS and PSS on ourselves.)
        let me = i32::try_from(std::process::id()).expect("pid");
        s.add(ModuleTarget::new("me", me)).expect("add self");
        s.sample(Instant::now());
        let mine = s.get("me").expect("own sample");
        assert!(mine.rss_bytes > 0);
        assert!(
            mine.pss_bytes.is_some_and(|p| p > 0 && p <= mine.rss_bytes),
            "{mine:?}"
        );
        assert!(first.cpu_percent.is_none());
        s.sample(Instant::now());
        let second = s.get("sleeper").expect("sample");
        assert!(second.cpu_percent.is_some_and(|c| c < 5.0), "{second:?}");
        child.kill().expect("kill");
        child.wait().expect("wait");
        s.sample(Instant::now());
        assert_eq!(s.get("sleeper").expect("sample").liveness, Liveness::Exited);
        // Later passes keep reporting the exit and never read the (possibly reused) pid.
        s.sample(Instant::now());
        assert_eq!(s.get("sleeper").expect("sample").liveness, Liveness::Exited);
    }

    #[test]
    fn refuses_wrong_starttime() {
        let me = i32::try_from(std::process::id()).expect("pid");
        let st = process_starttime(me).expect("own starttime");
        let mut s = Sampler::new(SamplerConfig::default()).expect("sampler");
        let err = s
            .add(ModuleTarget::new("me", me).with_starttime(st + 1))
            .expect_err("must refuse");
        assert!(matches!(err, RmError::PidReused { .. }), "{err}");
        s.add(ModuleTarget::new("me", me).with_starttime(st))
            .expect("right starttime accepted");
        assert!(matches!(
            s.add(ModuleTarget::new("me", me)),
            Err(RmError::Duplicate(_))
        ));
    }

    #[test]
    fn system_sample_is_sane() {
        let mut s = SystemSampler::new().expect("system sampler");
        let a = s.sample().expect("sample");
        assert!(a.cpu_free.is_none());
        assert!(a.mem_total_bytes > 0 && a.mem_available_bytes <= a.mem_total_bytes);
        // Burn a little so the cpu counters move.
        let t = Instant::now();
        while t.elapsed() < Duration::from_millis(30) {
            std::hint::black_box(0u64);
        }
        let b = s.sample().expect("sample");
        assert!(
            b.cpu_free.is_some_and(|f| (0.0..=1.0).contains(&f)),
            "{b:?}"
        );
    }
}
