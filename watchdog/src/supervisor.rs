//! The supervisor: one event loop, driven by the caller, that owns the module
//! processes.
//!
//! ```no_run
//! use std::time::{Duration, Instant};
//! use hng_watchdog::{ModuleSpec, Supervisor, SupervisorOptions};
//! # fn main() -> Result<(), hng_watchdog::SupervisorError> {
//! let mut sup = Supervisor::new(
//!     vec![ModuleSpec::new("sleeper", "/bin/sleep", &["1000"])],
//!     SupervisorOptions::default(),
//! )?;
//! sup.start_all();
//! loop {
//!     // Blocks until a child exits, a timer (backoff, hang, stop timeout)
//!     // is due, the Waker is woken, or 50 ms pass.
//!     for event in sup.poll(Duration::from_millis(50))? {
//!         println!("{event}");
//!     }
//!     // ... read heartbeats from iceoryx2 here, then:
//!     // sup.heartbeat("sleeper", Instant::now())?;
//! #   break;
//! }
//! sup.shutdown()?;
//! # Ok(()) }
//! ```
//!
//! Exits are detected through a pidfd per child in an epoll set, so
//! detection latency is the wake-up latency of `epoll_wait`, not a polling
//! period. Timers are computed from the earliest deadline; nothing sleeps.

use std::collections::{HashMap, VecDeque};
use std::fmt;
use std::io;
use std::os::fd::{AsFd, BorrowedFd};
use std::os::unix::process::CommandExt;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nix::sys::signal::Signal;

use crate::launch::{ModuleSpec, RestartPolicy};
use crate::sys::{self, Epoll, EventFd, PidFd};

pub use self::options::{NoHooks, SupervisorError, SupervisorHooks, SupervisorOptions, Waker};
pub use self::status::{Event, EventKind, ExitCause, ModuleState, ModuleStatus};

mod options;
mod spawn;
mod status;

const WAKE_TOKEN: u64 = u64::MAX;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StopKind {
    Stop,
    Restart,
}

#[derive(Debug)]
struct Proc {
    child: Child,
    pidfd: PidFd,
    pid: u32,
    started: Instant,
    last_heartbeat: Option<Instant>,
    /// The period the last heartbeat announced for the next one, when longer than the
    /// configured period (an idle module's stretched heartbeat); the hang deadline moves by
    /// the difference.
    promised: Option<Duration>,
    /// Set when the supervisor killed it on purpose: overrides the wait status.
    kill_cause: Option<ExitCause>,
    sent_sigkill: bool,
    stop: Option<StopKind>,
    kill_at: Option<Instant>,
}

#[derive(Debug)]
struct Slot {
    spec: ModuleSpec,
    state: ModuleState,
    proc_: Option<Proc>,
    restarts: u32,
    consecutive: u32,
    restart_times: VecDeque<Instant>,
    restart_at: Option<Instant>,
    last_exit: Option<ExitCause>,
    last_pid: Option<u32>,
    start_seq: Option<u64>,
}

/// Supervises a fixed set of modules. See the module documentation.
pub struct Supervisor<H: SupervisorHooks = NoHooks> {
    slots: Vec<Slot>,
    index: HashMap<String, usize>,
    epoll: Epoll,
    wake: Arc<EventFd>,
    opts: SupervisorOptions,
    hooks: H,
    pending: Vec<Event>,
    seq: u64,
    shutting_down: bool,
    stop_queue: Vec<usize>,
    /// The last poll was woken and judged no hang (see [`Supervisor::poll`]).
    hangs_deferred: bool,
}

impl<H: SupervisorHooks> fmt::Debug for Supervisor<H> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Supervisor")
            .field("slots", &self.slots)
            .field("shutting_down", &self.shutting_down)
            .finish_non_exhaustive()
    }
}

impl Supervisor<NoHooks> {
    /// A supervisor without hooks. Nothing starts until [`start_all`](Self::start_all).
    pub fn new(modules: Vec<ModuleSpec>, opts: SupervisorOptions) -> Result<Self, SupervisorError> {
        Self::with_hooks(modules, opts, NoHooks)
    }
}

fn io_err(op: &'static str) -> impl FnOnce(io::Error) -> SupervisorError {
    move |source| SupervisorError::Io { op, source }
}

impl<H: SupervisorHooks> Supervisor<H> {
    /// A supervisor for `modules` (start order = vector order) with caller hooks.
    pub fn with_hooks(
        modules: Vec<ModuleSpec>,
        opts: SupervisorOptions,
        hooks: H,
    ) -> Result<Self, SupervisorError> {
        let epoll = Epoll::new().map_err(io_err("epoll_create1"))?;
        let wake = Arc::new(EventFd::new().map_err(io_err("eventfd"))?);
        epoll
            .add(wake.as_fd(), WAKE_TOKEN)
            .map_err(io_err("epoll_ctl(eventfd)"))?;
        let mut index = HashMap::new();
        let mut slots = Vec::with_capacity(modules.len());
        for (i, spec) in modules.into_iter().enumerate() {
            if index.insert(spec.name.clone(), i).is_some() {
                return Err(SupervisorError::DuplicateModule { name: spec.name });
            }
            slots.push(Slot {
                spec,
                state: ModuleState::Stopped,
                proc_: None,
                restarts: 0,
                consecutive: 0,
                restart_times: VecDeque::new(),
                restart_at: None,
                last_exit: None,
                last_pid: None,
                start_seq: None,
            });
        }
        Ok(Self {
            slots,
            index,
            epoll,
            wake,
            opts,
            hooks,
            pending: Vec::new(),
            seq: 0,
            shutting_down: false,
            stop_queue: Vec::new(),
            hangs_deferred: false,
        })
    }

    /// The caller's hooks.
    pub fn hooks(&self) -> &H {
        &self.hooks
    }

    /// The caller's hooks, mutable.
    pub fn hooks_mut(&mut self) -> &mut H {
        &mut self.hooks
    }

    /// A handle that wakes `poll` from another thread.
    pub fn waker(&self) -> Waker {
        Waker(Arc::clone(&self.wake))
    }

    /// Module specs in start order.
    pub fn modules(&self) -> impl Iterator<Item = &ModuleSpec> {
        self.slots.iter().map(|s| &s.spec)
    }

    fn slot_index(&self, name: &str) -> Result<usize, SupervisorError> {
        self.index
            .get(name)
            .copied()
            .ok_or_else(|| SupervisorError::UnknownModule {
                name: name.to_owned(),
            })
    }

    fn push(&mut self, at: Instant, i: usize, kind: EventKind) {
        let module = self.slots[i].spec.name.clone();
        tracing::debug!(module, ?kind, "supervisor event");
        self.pending.push(Event { at, module, kind });
    }

    /// Spawn every stopped module, in order. Spawn failures are events and go
    /// through the restart policy.
    pub fn start_all(&mut self) {
        let now = Instant::now();
        self.shutting_down = false;
        self.stop_queue.clear();
        for i in 0..self.slots.len() {
            if matches!(self.slots[i].state, ModuleState::Stopped) {
                self.fresh_start(i, now);
            }
        }
    }

    /// Start a stopped or deactivated module (with a clean failure history).
    pub fn start(&mut self, name: &str) -> Result<(), SupervisorError> {
        let i = self.slot_index(name)?;
        if matches!(
            self.slots[i].state,
            ModuleState::Stopped | ModuleState::Deactivated | ModuleState::BackingOff
        ) {
            self.fresh_start(i, Instant::now());
        }
        Ok(())
    }

    fn fresh_start(&mut self, i: usize, now: Instant) {
        let slot = &mut self.slots[i];
        slot.consecutive = 0;
        slot.restart_times.clear();
        slot.restart_at = None;
        if let Some(dead) = slot.last_pid {
            self.hooks.before_restart(&self.slots[i].spec, dead);
        }
        self.spawn(i, now);
    }

    /// Record a heartbeat of `name` at `now`. The first one after a start moves
    /// the module from Starting to Running. Heartbeats for a module without a
    /// live process are ignored (returns false).
    pub fn heartbeat(&mut self, name: &str, now: Instant) -> Result<bool, SupervisorError> {
        self.heartbeat_promising(name, now, None)
    }

    /// [`Supervisor::heartbeat`] from a module that announces when its next heartbeat comes
    /// (`next_within`, the period its report carries). A module with nothing to do stretches
    /// its heartbeat (the SDK does, up to its idle report period, and heartbeats again at
    /// once when work comes); the hang timeout then follows: a heartbeat promised later than
    /// the configured period moves the deadline by the difference. `None`, or a period not
    /// longer than the configured one, keeps the configured timeout.
    pub fn heartbeat_promising(
        &mut self,
        name: &str,
        now: Instant,
        next_within: Option<Duration>,
    ) -> Result<bool, SupervisorError> {
        let i = self.slot_index(name)?;
        let slot = &mut self.slots[i];
        let Some(p) = slot.proc_.as_mut() else {
            return Ok(false);
        };
        if p.last_heartbeat.is_none_or(|t| now >= t) {
            p.promised = next_within;
        }
        p.last_heartbeat = Some(p.last_heartbeat.map_or(now, |t| t.max(now)));
        if slot.state == ModuleState::Starting {
            slot.state = ModuleState::Running;
            let pid = p.pid;
            self.push(now, i, EventKind::Running { pid });
        }
        Ok(true)
    }

    fn signal_proc(&mut self, i: usize, signal: Signal) -> Result<(), SupervisorError> {
        let slot = &mut self.slots[i];
        let Some(p) = slot.proc_.as_mut() else {
            return Err(SupervisorError::NotRunning {
                name: slot.spec.name.clone(),
                state: slot.state,
            });
        };
        if signal == Signal::SIGKILL {
            p.sent_sigkill = true;
        }
        p.pidfd
            .send_signal(signal as i32)
            .map_err(|source| SupervisorError::Signal {
                name: slot.spec.name.clone(),
                pid: p.pid,
                signal: signal.as_str().to_owned(),
                source,
            })
    }

    /// Send `signal` to the module's process (fault injection). The resulting
    /// exit is classified from the wait status, like a real crash; SIGSTOP
    /// makes a hang once heartbeats stop.
    pub fn kill(&mut self, name: &str, signal: Signal) -> Result<(), SupervisorError> {
        let i = self.slot_index(name)?;
        self.signal_proc(i, signal)
    }

    /// SIGKILL the module because it exceeds a resource limit; the exit cause
    /// is `OverLimit { reason }` and the restart policy applies.
    pub fn kill_over_limit(&mut self, name: &str, reason: &str) -> Result<(), SupervisorError> {
        let i = self.slot_index(name)?;
        if let Some(p) = self.slots[i].proc_.as_mut()
            && p.kill_cause.is_none()
        {
            p.kill_cause = Some(ExitCause::OverLimit {
                reason: reason.to_owned(),
            });
        }
        self.signal_proc(i, Signal::SIGKILL)
    }

    /// Stop one module: SIGTERM, SIGKILL after its `stop_timeout`. It stays
    /// Stopped (no restart). A module waiting for a restart is just Stopped.
    pub fn stop(&mut self, name: &str) -> Result<(), SupervisorError> {
        let i = self.slot_index(name)?;
        self.begin_stop(i, StopKind::Stop, Instant::now());
        Ok(())
    }

    /// Maintenance restart: stop (SIGTERM, then SIGKILL) and start again at
    /// once; does not count as a failure. Also revives a Stopped or
    /// Deactivated module.
    pub fn restart(&mut self, name: &str) -> Result<(), SupervisorError> {
        let i = self.slot_index(name)?;
        let now = Instant::now();
        if self.slots[i].proc_.is_some() {
            self.begin_stop(i, StopKind::Restart, now);
        } else {
            self.fresh_start(i, now);
        }
        Ok(())
    }

    fn begin_stop(&mut self, i: usize, kind: StopKind, now: Instant) {
        let slot = &mut self.slots[i];
        let stop_timeout = slot.spec.stop_timeout;
        match slot.proc_.as_mut() {
            Some(p) => {
                if p.stop.is_some() {
                    // Already stopping: a Stop request wins over a Restart.
                    if kind == StopKind::Stop {
                        p.stop = Some(kind);
                    }
                    return;
                }
                p.stop = Some(kind);
                p.kill_at = Some(now + stop_timeout);
                let pid = p.pid;
                // SIGCONT after SIGTERM so a SIGSTOPped process can act on it.
                let r = p
                    .pidfd
                    .send_signal(libc::SIGTERM)
                    .and_then(|()| p.pidfd.send_signal(libc::SIGCONT));
                if let Err(e) = r {
                    tracing::warn!(module = %slot.spec.name, pid, "SIGTERM failed: {e}");
                }
                slot.state = ModuleState::Stopping;
                self.push(now, i, EventKind::StopRequested { pid });
            }
            None => {
                if kind == StopKind::Stop
                    && matches!(slot.state, ModuleState::BackingOff | ModuleState::Starting)
                {
                    slot.restart_at = None;
                    slot.state = ModuleState::Stopped;
                    self.push(now, i, EventKind::Stopped);
                }
            }
        }
    }

    /// Begin an orderly shutdown: modules are stopped one at a time in reverse
    /// start order (SIGTERM, SIGKILL after each one's `stop_timeout`); no
    /// restarts happen any more. Keep calling [`poll`](Self::poll) until
    /// [`is_shut_down`](Self::is_shut_down), or call [`shutdown`](Self::shutdown).
    pub fn begin_shutdown(&mut self) {
        if self.shutting_down {
            return;
        }
        self.shutting_down = true;
        let mut order: Vec<usize> = (0..self.slots.len()).collect();
        // Never-started modules first (popped last), then by start sequence.
        order.sort_by_key(|&i| self.slots[i].start_seq.map_or(0, |s| s + 1));
        self.stop_queue = order;
        self.advance_shutdown(Instant::now());
    }

    /// All modules are down after [`begin_shutdown`](Self::begin_shutdown).
    pub fn is_shut_down(&self) -> bool {
        self.shutting_down
            && self.stop_queue.is_empty()
            && self.slots.iter().all(|s| s.proc_.is_none())
    }

    /// Orderly shutdown, blocking until every module process is gone.
    /// Returns the events of the shutdown.
    pub fn shutdown(&mut self) -> Result<Vec<Event>, SupervisorError> {
        self.begin_shutdown();
        let mut events = Vec::new();
        while !self.is_shut_down() {
            events.extend(self.poll(Duration::from_secs(1))?);
        }
        events.append(&mut self.pending);
        Ok(events)
    }

    fn advance_shutdown(&mut self, now: Instant) {
        if !self.shutting_down {
            return;
        }
        while let Some(&i) = self.stop_queue.last() {
            if self.slots[i].proc_.is_some() {
                self.begin_stop(i, StopKind::Stop, now);
                return;
            }
            self.stop_queue.pop();
            let slot = &mut self.slots[i];
            slot.restart_at = None;
            if !matches!(slot.state, ModuleState::Stopped | ModuleState::Deactivated) {
                slot.state = ModuleState::Stopped;
                self.push(now, i, EventKind::Stopped);
            }
        }
    }

    /// The earliest time at which the supervisor has something to do without
    /// an fd becoming ready (restart due, heartbeat deadline, stop timeout).
    pub fn next_deadline(&self) -> Option<Instant> {
        let mut next: Option<Instant> = None;
        let mut consider = |t: Instant| next = Some(next.map_or(t, |n| n.min(t)));
        for s in &self.slots {
            if let Some(t) = s.restart_at {
                consider(t);
            }
            if let Some(p) = &s.proc_ {
                if let Some(t) = p.kill_at {
                    consider(t);
                }
                if let Some(t) = hang_deadline(&s.spec, p) {
                    consider(t);
                }
            }
        }
        next
    }

    /// Run the event loop once: block until a module process exits, a timer
    /// is due, the [`Waker`] fires or `timeout` passes (whichever is first),
    /// handle what happened and return the events. Returns at once if events
    /// are already pending (from `start_all`, `kill`, `heartbeat`, ...).
    ///
    /// A call that reaps a process returns its exit (and the scheduled restart)
    /// without spawning: the caller can tell the system about the death before
    /// the restart's clean-up and spawn; the next call spawns without sleeping.
    pub fn poll(&mut self, timeout: Duration) -> Result<Vec<Event>, SupervisorError> {
        let now = Instant::now();
        let mut wait = timeout;
        if let Some(d) = self.next_deadline() {
            wait = wait.min(d.saturating_duration_since(now));
        }
        if !self.pending.is_empty() {
            wait = Duration::ZERO;
        }
        let tokens = self.epoll.wait(wait).map_err(io_err("epoll_wait"))?;
        let now = Instant::now();
        let before = self.pending.len();
        let mut woken = false;
        for t in tokens {
            if t == WAKE_TOKEN {
                self.wake.drain();
                woken = true;
            } else if let Ok(i) = usize::try_from(t) {
                self.reap(i, now);
            }
        }
        // A death is reported at once: restarts due now (clean-up and spawn take
        // milliseconds) wait for the next call, which returns without sleeping.
        let reaped = self.pending.len() > before;
        // Woken (the caller's receiver has heartbeats it has not handed over yet): no hang is
        // judged before the caller applied them; the next call judges, without sleeping when
        // a deadline passed. Once only, so a stream of wake-ups cannot put it off. Before, a
        // supervisor woken late on a loaded machine could kill a module whose heartbeat was
        // already waiting in its inbox.
        let defer = woken && !self.hangs_deferred;
        self.hangs_deferred = defer;
        self.run_timers(now, !reaped, !defer);
        self.advance_shutdown(now);
        Ok(std::mem::take(&mut self.pending))
    }

    fn reap(&mut self, i: usize, now: Instant) {
        let Some(slot) = self.slots.get_mut(i) else {
            return;
        };
        let Some(p) = slot.proc_.as_mut() else {
            return;
        };
        let status = match p.child.try_wait() {
            Ok(Some(status)) => Ok(status),
            // Readable pidfd but not yet waitable: level-triggered epoll retries.
            Ok(None) => return,
            Err(e) => Err(e),
        };
        let Some(p) = slot.proc_.take() else {
            return;
        };
        let _ = self.epoll.delete(p.pidfd.as_fd());
        if self.opts.process_group
            && let Err(e) = sys::kill_group(p.pid, libc::SIGKILL)
        {
            tracing::warn!(module = %slot.spec.name, pid = p.pid, "killing leftover process group failed: {e}");
        }
        let cause = match (p.kill_cause, status) {
            (Some(c), _) => c,
            (None, Err(e)) => ExitCause::Unknown {
                error: format!("waitpid: {e}"),
            },
            (None, Ok(status)) => {
                let c = ExitCause::from_status(status);
                let oom = matches!(c, ExitCause::Signaled { number, .. } if number == libc::SIGKILL)
                    && !p.sent_sigkill
                    && self.hooks.oom_killed(&slot.spec, p.pid);
                if oom { ExitCause::OomKilled } else { c }
            }
        };
        let uptime = now.saturating_duration_since(p.started);
        slot.last_pid = Some(p.pid);
        self.push(
            now,
            i,
            EventKind::Exited {
                pid: p.pid,
                cause: cause.clone(),
                uptime,
            },
        );
        self.after_exit(i, now, cause, uptime, p.stop);
    }

    /// Decide what follows an exit (or a failed spawn).
    fn after_exit(
        &mut self,
        i: usize,
        now: Instant,
        cause: ExitCause,
        uptime: Duration,
        stop: Option<StopKind>,
    ) {
        let shutting_down = self.shutting_down;
        let slot = &mut self.slots[i];
        slot.last_exit = Some(cause.clone());
        match stop {
            Some(StopKind::Restart) if !shutting_down => {
                slot.restart_at = Some(now);
                slot.state = ModuleState::BackingOff;
                let attempt = slot.restarts + 1;
                self.push(
                    now,
                    i,
                    EventKind::Restarting {
                        delay: Duration::ZERO,
                        attempt,
                    },
                );
                return;
            }
            Some(_) => {
                slot.state = ModuleState::Stopped;
                self.push(now, i, EventKind::Stopped);
                return;
            }
            None => {}
        }
        let wanted = match slot.spec.restart {
            RestartPolicy::Always => true,
            RestartPolicy::OnFailure => cause.is_failure(),
            RestartPolicy::Never => false,
        };
        if shutting_down || !wanted {
            slot.state = ModuleState::Stopped;
            self.push(now, i, EventKind::Stopped);
            return;
        }
        if uptime >= slot.spec.backoff_reset_after {
            slot.consecutive = 0;
        }
        let window = slot.spec.give_up_window;
        slot.restart_times.push_back(now);
        while slot
            .restart_times
            .front()
            .is_some_and(|&t| now.saturating_duration_since(t) > window)
        {
            slot.restart_times.pop_front();
        }
        let failures = u32::try_from(slot.restart_times.len()).unwrap_or(u32::MAX);
        if failures > slot.spec.give_up_failures {
            slot.state = ModuleState::Deactivated;
            slot.restart_at = None;
            tracing::warn!(module = %slot.spec.name, failures, "module deactivated");
            self.push(now, i, EventKind::Deactivated { failures, window });
            return;
        }
        let delay = backoff_delay(&slot.spec, slot.consecutive);
        slot.consecutive = slot.consecutive.saturating_add(1);
        slot.restart_at = Some(now + delay);
        slot.state = ModuleState::BackingOff;
        let attempt = slot.restarts + 1;
        self.push(now, i, EventKind::Restarting { delay, attempt });
    }

    fn run_timers(&mut self, now: Instant, restarts: bool, hangs: bool) {
        for i in 0..self.slots.len() {
            // Hang detection and stop escalation.
            let slot = &mut self.slots[i];
            let mut hang = None;
            let mut escalated = None;
            if let Some(p) = slot.proc_.as_mut() {
                if hangs
                    && p.kill_cause.is_none()
                    && p.stop.is_none()
                    && let Some(deadline) = hang_deadline(&slot.spec, p)
                    && now >= deadline
                {
                    let silent_for =
                        now.saturating_duration_since(p.last_heartbeat.unwrap_or(p.started));
                    p.kill_cause = Some(ExitCause::Hang { silent_for });
                    p.sent_sigkill = true;
                    if let Err(e) = p.pidfd.send_signal(libc::SIGKILL) {
                        tracing::warn!(module = %slot.spec.name, pid = p.pid, "SIGKILL failed: {e}");
                    }
                    hang = Some((p.pid, silent_for));
                }
                if let Some(t) = p.kill_at
                    && now >= t
                {
                    p.kill_at = None;
                    p.sent_sigkill = true;
                    if p.kill_cause.is_none() {
                        p.kill_cause = Some(ExitCause::StopTimeout);
                    }
                    if let Err(e) = p.pidfd.send_signal(libc::SIGKILL) {
                        tracing::warn!(module = %slot.spec.name, pid = p.pid, "SIGKILL failed: {e}");
                    }
                    escalated = Some(p.pid);
                }
            }
            if let Some((pid, silent_for)) = hang {
                tracing::warn!(module = %self.slots[i].spec.name, pid, ?silent_for, "hang detected");
                self.push(now, i, EventKind::HangDetected { pid, silent_for });
            }
            if let Some(pid) = escalated {
                self.push(now, i, EventKind::StopTimedOut { pid });
            }
            // Due restarts.
            let slot = &mut self.slots[i];
            if restarts
                && slot.state == ModuleState::BackingOff
                && slot.proc_.is_none()
                && slot.restart_at.is_some_and(|t| now >= t)
                && !self.shutting_down
            {
                slot.restart_at = None;
                slot.restarts = slot.restarts.saturating_add(1);
                if let Some(dead) = slot.last_pid {
                    self.hooks.before_restart(&self.slots[i].spec, dead);
                }
                self.spawn(i, now);
            }
        }
    }

    /// A snapshot for `hng ps`.
    pub fn status(&self, now: Instant) -> Vec<ModuleStatus> {
        self.slots
            .iter()
            .map(|s| ModuleStatus {
                name: s.spec.name.clone(),
                state: s.state,
                pid: s.proc_.as_ref().map(|p| p.pid),
                uptime: s
                    .proc_
                    .as_ref()
                    .map(|p| now.saturating_duration_since(p.started)),
                restarts: s.restarts,
                last_exit: s.last_exit.clone(),
                heartbeat_age: s
                    .proc_
                    .as_ref()
                    .and_then(|p| p.last_heartbeat)
                    .map(|t| now.saturating_duration_since(t)),
                restart_in: s.restart_at.map(|t| t.saturating_duration_since(now)),
                manager: s.spec.manager,
            })
            .collect()
    }

    /// State of one module.
    pub fn state(&self, name: &str) -> Result<ModuleState, SupervisorError> {
        Ok(self.slots[self.slot_index(name)?].state)
    }

    /// Current pid of one module.
    pub fn pid(&self, name: &str) -> Result<Option<u32>, SupervisorError> {
        Ok(self.slots[self.slot_index(name)?]
            .proc_
            .as_ref()
            .map(|p| p.pid))
    }
}

/// Delay before restart number `consecutive` (0-based) of a crash series:
/// 0, initial, 2*initial, 4*initial, ... capped at `backoff_max`.
pub fn backoff_delay(spec: &ModuleSpec, consecutive: u32) -> Duration {
    if consecutive == 0 {
        return Duration::ZERO;
    }
    let factor = 1u32.checked_shl(consecutive - 1).unwrap_or(u32::MAX);
    spec.backoff_initial
        .checked_mul(factor)
        .unwrap_or(spec.backoff_max)
        .min(spec.backoff_max)
}

fn hang_deadline(spec: &ModuleSpec, p: &Proc) -> Option<Instant> {
    if p.kill_cause.is_some() || p.stop.is_some() {
        return None;
    }
    let hb = spec.heartbeat?;
    let stretched = p
        .promised
        .map_or(Duration::ZERO, |d| d.saturating_sub(hb.period));
    Some(match p.last_heartbeat {
        Some(t) => t + hb.timeout + stretched,
        None => p.started + spec.start_timeout,
    })
}

impl<H: SupervisorHooks> AsFd for Supervisor<H> {
    /// The epoll fd: readable when a module process has exited or the
    /// [`Waker`] fired. To embed the supervisor in another poll loop, wait on
    /// this fd with a timeout up to [`Supervisor::next_deadline`], then call
    /// `poll(Duration::ZERO)`.
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.epoll.as_fd()
    }
}

impl<H: SupervisorHooks> Drop for Supervisor<H> {
    /// Last resort (the caller should `shutdown()`): SIGKILL and reap every
    /// module process so none outlives the supervisor.
    fn drop(&mut self) {
        for slot in &mut self.slots {
            if let Some(mut p) = slot.proc_.take() {
                let _ = p.pidfd.send_signal(libc::SIGKILL);
                let _ = p.child.wait();
                if self.opts.process_group {
                    let _ = sys::kill_group(p.pid, libc::SIGKILL);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_cap() {
        let mut spec = ModuleSpec::new("m", "/bin/true", &[]);
        spec.backoff_initial = Duration::from_millis(100);
        spec.backoff_max = Duration::from_millis(500);
        let delays: Vec<u128> = (0..7)
            .map(|n| backoff_delay(&spec, n).as_millis())
            .collect();
        assert_eq!(delays, vec![0, 100, 200, 400, 500, 500, 500]);
        assert_eq!(backoff_delay(&spec, u32::MAX), Duration::from_millis(500));
    }

    #[test]
    fn signal_names() {
        use super::status::signal_name;
        assert_eq!(signal_name(9), "SIGKILL");
        assert_eq!(signal_name(11), "SIGSEGV");
        assert_eq!(signal_name(6), "SIGABRT");
        assert_eq!(signal_name(40), "SIG40");
    }
}
