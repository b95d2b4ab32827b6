//! Waiting on several inputs at once, without polling.
//!
//! A [`Waiter`] watches any number of subscribers (and, optionally, SIGINT/SIGTERM/SIGHUP).
//! [`Waiter::wait`] returns as soon as one of them has data, a signal arrives, or the timeout
//! passes. Two modes:
//!
//! - [`WaitMode::Blocking`] (default): a bounded, adaptive spin, then sleep in `epoll` on the
//!   iceoryx2 event listeners that sit beside every data service (the mechanism of iceoryx2's
//!   `WaitSet`, kept open across waits so inputs can be added while running). Waking a sleeping
//!   process across cores costs 20-60 us on a small VM; the spin catches the answer of a peer
//!   that replies within the spin budget, at the price of burning up to that budget of CPU per
//!   wait. The budget adapts like an adaptive mutex: the waiter keeps a moving average of how
//!   long its waits take until data comes and spins for twice that when it fits in `max_spin`;
//!   otherwise (an idle input, or a machine so loaded that peers are descheduled) it sleeps at
//!   once, and one wait in sixteen probes with a short spin. Publishers only send an event when a subscriber really sleeps
//!   ([`crate::wake`]), so a spinning or busy subscriber costs its publishers nothing.
//!   With [`Waiter::share_cpus`] (the module executor does it), the waiters of one system
//!   also spin only with a core to spare ([`crate::cpus`]): a spinner never keeps a core from
//!   a process that has work to do.
//! - [`WaitMode::Spin`]: poll continuously (lowest latency, one core busy). Never spin on
//!   both ends of a pipeline on a machine with fewer cores than spinners.

use std::os::fd::{AsFd, BorrowedFd};
use std::rc::Rc;
use std::time::Duration;

use iceoryx2::prelude::FileDescriptorBased;
use nix::sys::epoll::{Epoll, EpollCreateFlags, EpollEvent, EpollFlags, EpollTimeout};
use nix::sys::signal::{SigSet, Signal};
use nix::sys::signalfd::{SfdFlags, SignalFd};

use crate::channel::{Counters, Input, InputId, Node, Waitable};
use crate::clock::monotonic_ns;
use crate::cpus::CpuShare;
use crate::error::Error;

/// How a [`Waiter`] waits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitMode {
    /// Spin up to `max_spin`, adaptively, then sleep until notified.
    Blocking {
        /// Longest spin before sleeping.
        max_spin: Duration,
    },
    /// Poll without sleeping.
    Spin,
}

impl Default for WaitMode {
    fn default() -> Self {
        WaitMode::Blocking {
            max_spin: Duration::from_micros(200),
        }
    }
}

impl WaitMode {
    /// Sleep until notified, without spinning: for processes whose waits are not on a hot path
    /// (tools, tests, the supervisor), which should spend no CPU on them.
    pub const SLEEP: WaitMode = WaitMode::Blocking {
        max_spin: Duration::ZERO,
    };

    /// Parses `blocking`, `blocking:<µs>` or `spin`.
    pub fn parse(s: &str) -> Result<WaitMode, Error> {
        match s.split_once(':') {
            None if s == "spin" => Ok(WaitMode::Spin),
            None if s == "blocking" => Ok(WaitMode::default()),
            Some(("blocking", us)) => us
                .parse::<u64>()
                .map(|us| WaitMode::Blocking {
                    max_spin: Duration::from_micros(us),
                })
                .map_err(|_| {
                    Error::Config(format!(
                        "wait mode {s:?}: spin budget is not a number of microseconds"
                    ))
                }),
            _ => Err(Error::Config(format!(
                "wait mode {s:?}: expected `blocking`, `blocking:<microseconds>` or `spin`"
            ))),
        }
    }
}

/// Why [`Waiter::wait`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// At least one input has data.
    Data,
    /// The timeout passed.
    Timeout,
    /// A termination signal arrived (its number).
    Signal(i32),
}

const SIGNAL_TOKEN: u64 = u64::MAX;

/// What a [`Waiter`] did so far (to tune the spin budget, and for reports).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct WaitStats {
    /// Waits that found data already there.
    pub immediate: u64,
    /// Waits whose spin caught data.
    pub spin_hits: u64,
    /// Spins that ran out of budget.
    pub spin_misses: u64,
    /// Times the waiter slept in epoll.
    pub sleeps: u64,
    /// Spins cut short to give the core to a process that had work ([`crate::cpus`]).
    pub gave_way: u64,
    /// Waits that slept at once because spinning would have crowded the CPUs.
    pub crowded: u64,
}

/// Waits on several inputs; see the module documentation.
pub struct Waiter {
    epoll: Epoll,
    inputs: Vec<(InputId, Rc<dyn Input>)>,
    signals: Option<SignalFd>,
    mode: WaitMode,
    ewma_ns: u64,
    probe: u32,
    events: Vec<EpollEvent>,
    stats: WaitStats,
    cpus: Option<Shared>,
}

/// A waiter's place among the CPUs of its system, and its node's count of sleepers woken.
struct Shared {
    share: CpuShare,
    counters: Rc<Counters>,
    wakeups_seen: u64,
}

/// Blocks SIGINT, SIGTERM and SIGHUP in the calling thread, and so in every thread it starts
/// from then on; returns the mask. A binary that reads them from a signalfd
/// ([`Waiter::catch_termination_signals`]) calls this first thing in `main`, while it is the
/// only thread: a library that starts a thread before the signalfd exists (a writer, a
/// worker) would otherwise leave a thread where the signal's default action kills the process.
///
/// # Errors
/// The mask could not be changed.
pub fn block_termination_signals() -> Result<SigSet, Error> {
    let mut mask = SigSet::empty();
    mask.add(Signal::SIGINT);
    mask.add(Signal::SIGTERM);
    mask.add(Signal::SIGHUP);
    mask.thread_block()
        .map_err(|e| Error::io("blocking termination signals", e))?;
    Ok(mask)
}

impl std::fmt::Debug for Waiter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Waiter")
            .field("inputs", &self.inputs.len())
            .field("mode", &self.mode)
            .finish_non_exhaustive()
    }
}

fn listener_fd(input: &dyn Input) -> BorrowedFd<'_> {
    let fd = input.inlet().listener.file_descriptor();
    // SAFETY: the listener owns the descriptor and outlives the borrow (it lives in the inlet).
    unsafe { BorrowedFd::borrow_raw(fd.native_handle()) }
}

impl Waiter {
    /// A waiter with no inputs.
    pub fn new(mode: WaitMode) -> Result<Waiter, Error> {
        let epoll = Epoll::new(EpollCreateFlags::EPOLL_CLOEXEC)
            .map_err(|e| Error::io("creating the epoll instance", e))?;
        Ok(Waiter {
            epoll,
            inputs: Vec::new(),
            signals: None,
            mode,
            ewma_ns: 0,
            probe: 0,
            events: vec![EpollEvent::empty(); 16],
            stats: WaitStats::default(),
            cpus: None,
        })
    }

    /// Shares the CPUs with the other waiters of `node`'s system (see [`crate::cpus`] for the
    /// rule): in blocking mode this waiter then spins only with a core to spare, and gives its
    /// core up when another one wakes and needs it. The sleepers that `node`'s publishes woke
    /// count as awake.
    pub fn share_cpus(&mut self, node: &Node) -> Result<(), Error> {
        let counters = node.shared_counters();
        self.cpus = Some(Shared {
            share: CpuShare::join(node.prefix())?,
            wakeups_seen: counters.wakeups.get(),
            counters,
        });
        Ok(())
    }

    /// What this waiter did so far.
    pub fn stats(&self) -> WaitStats {
        self.stats
    }

    /// The mode.
    pub fn mode(&self) -> WaitMode {
        self.mode
    }

    /// Watches a subscriber.
    pub fn attach(&mut self, sub: &impl Waitable) -> Result<(), Error> {
        let input = sub.erased();
        let id = sub.input_id();
        if self.inputs.iter().any(|(i, _)| *i == id) {
            return Ok(());
        }
        let token = self.inputs.len() as u64;
        self.epoll
            .add(
                listener_fd(&*input),
                EpollEvent::new(EpollFlags::EPOLLIN, token),
            )
            .map_err(|e| Error::io(format!("watching channel {:?}", input.inlet().channel), e))?;
        self.inputs.push((id, input));
        Ok(())
    }

    /// Stops watching a subscriber.
    pub fn detach(&mut self, id: InputId) -> Result<(), Error> {
        let Some(pos) = self.inputs.iter().position(|(i, _)| *i == id) else {
            return Ok(());
        };
        let (_, input) = self.inputs.remove(pos);
        let _ = self.epoll.delete(listener_fd(&*input));
        // Tokens are positions: re-register the inputs that moved.
        for (token, (_, input)) in self.inputs.iter().enumerate().skip(pos) {
            let mut ev = EpollEvent::new(EpollFlags::EPOLLIN, token as u64);
            self.epoll
                .modify(listener_fd(&**input), &mut ev)
                .map_err(|e| Error::io("re-registering an input", e))?;
        }
        Ok(())
    }

    /// Blocks SIGINT, SIGTERM and SIGHUP for this thread and reports them from
    /// [`Waiter::wait`] as [`Wake::Signal`] instead. Call before starting other threads (or
    /// block them with [`block_termination_signals`] at the top of `main`).
    pub fn catch_termination_signals(&mut self) -> Result<(), Error> {
        let mask = block_termination_signals()?;
        let sfd = SignalFd::with_flags(&mask, SfdFlags::SFD_NONBLOCK | SfdFlags::SFD_CLOEXEC)
            .map_err(|e| Error::io("creating a signalfd", e))?;
        self.epoll
            .add(
                sfd.as_fd(),
                EpollEvent::new(EpollFlags::EPOLLIN, SIGNAL_TOKEN),
            )
            .map_err(|e| Error::io("watching the signalfd", e))?;
        self.signals = Some(sfd);
        Ok(())
    }

    fn pending_signal(&self) -> Option<i32> {
        let sfd = self.signals.as_ref()?;
        match sfd.read_signal() {
            Ok(Some(info)) => Some(info.ssi_signo as i32),
            _ => None,
        }
    }

    /// True if any watched input has data.
    pub fn any_ready(&self) -> bool {
        self.inputs.iter().any(|(_, i)| i.has_samples())
    }

    /// The keys ([`crate::channel::channel_key`]) of the channels watched: a lockstep
    /// participant's inputs.
    pub fn input_keys(&self) -> impl Iterator<Item = u64> + '_ {
        self.inputs.iter().map(|(_, i)| i.inlet().key)
    }

    /// The ids of the inputs that have data to handle now. In lockstep, an input whose only
    /// messages were sent in the current round is not ready: they wait for the next round
    /// (and are set aside for it), so whether a handler runs in a round never depends on how
    /// fast another member answered the same round.
    pub fn ready(&self) -> impl Iterator<Item = InputId> + '_ {
        self.inputs
            .iter()
            .filter(|(_, i)| i.handleable())
            .map(|(id, _)| *id)
    }

    /// Waits until an input has data, a termination signal arrives, or `timeout` passes
    /// (`None`: no timeout).
    pub fn wait(&mut self, timeout: Option<Duration>) -> Result<Wake, Error> {
        // Poll a little (a few microseconds) before reading the clock: data that is about to
        // arrive (the common case on a busy pipeline) then costs no clock read at all. Kept
        // even when the CPUs are crowded: it measured faster than sleeping at once. A look at
        // an input without history reads its channel's publish count, and asks the port only
        // when something was published since it was found empty (crate::wake). A waiter that
        // must not spin ([`WaitMode::SLEEP`]: a lockstep module between its rounds, a paced
        // simulator, tools) looks once: the 64 looks were a tenth of a paced simulator's CPU
        // (an input with history asks its port at every look).
        let looks = if self.mode == WaitMode::SLEEP { 1 } else { 64 };
        for i in 0..looks {
            if self.any_ready() {
                if i == 0 {
                    self.stats.immediate += 1;
                } else {
                    self.stats.spin_hits += 1;
                }
                return Ok(Wake::Data);
            }
            std::hint::spin_loop();
        }
        let start = monotonic_ns();
        let end = timeout.map(|t| start.saturating_add(t.as_nanos() as u64));
        match self.mode {
            WaitMode::Spin => self.spin(end),
            WaitMode::Blocking { max_spin } => {
                let max = max_spin.as_nanos() as u64;
                let budget = if self.crowded() {
                    self.stats.crowded += 1;
                    0
                } else {
                    self.spin_budget(max)
                };
                let spin_end = end.map_or(start + budget, |e| e.min(start + budget));
                let wake = match (budget > 0).then(|| self.spin_until(spin_end)).flatten() {
                    Some(wake) => {
                        self.stats.spin_hits += 1;
                        wake
                    }
                    None => {
                        if budget > 0 {
                            self.stats.spin_misses += 1;
                        }
                        self.sleep(end)?
                    }
                };
                // Learn how long data takes to come (an EWMA over 8 waits); a timeout counts
                // as "longer than the budget", so an idle input stops spinning at once.
                let took = match wake {
                    Wake::Data => monotonic_ns().saturating_sub(start),
                    _ => max.saturating_mul(4),
                };
                self.ewma_ns = self.ewma_ns - self.ewma_ns / 8 + took / 8;
                Ok(wake)
            }
        }
    }

    /// Spin for about twice the typical time data takes to come, if that fits in `max`;
    /// otherwise sleep at once, and probe with a short spin one wait in sixteen.
    fn spin_budget(&mut self, max: u64) -> u64 {
        let want = self.ewma_ns.saturating_mul(2).max(2_000);
        if want <= max {
            return want;
        }
        self.probe = self.probe.wrapping_add(1);
        if self.probe.is_multiple_of(16) {
            max / 4
        } else {
            0
        }
    }

    /// True when the system's awake waiters, with the processes the node woke since the
    /// last wait, would outnumber the CPUs if this one spun.
    fn crowded(&mut self) -> bool {
        let Some(c) = self.cpus.as_mut() else {
            return false;
        };
        let wakeups = c.counters.wakeups.get();
        let woken = wakeups.wrapping_sub(c.wakeups_seen);
        c.wakeups_seen = wakeups;
        !c.share.may_spin(u32::try_from(woken).unwrap_or(u32::MAX))
    }

    fn spin_until(&mut self, end: u64) -> Option<Wake> {
        let mut n: u32 = 0;
        loop {
            if self.any_ready() {
                return Some(Wake::Data);
            }
            n = n.wrapping_add(1);
            if n.is_multiple_of(64) {
                if monotonic_ns() >= end {
                    return None;
                }
                if self.cpus.as_ref().is_some_and(|c| c.share.give_way()) {
                    self.stats.gave_way += 1;
                    return None;
                }
            }
            std::hint::spin_loop();
        }
    }

    fn spin(&self, end: Option<u64>) -> Result<Wake, Error> {
        match self.spin_on(end, || Ok(self.any_ready().then_some(()))) {
            Ok(Some(())) => Ok(Wake::Data),
            Ok(None) => Ok(Wake::Timeout),
            Err(Error::Interrupted { signal }) => Ok(Wake::Signal(signal)),
            Err(e) => Err(e),
        }
    }

    /// Polls `poll` until it yields a value; `None` when the deadline passed, and
    /// [`Error::Interrupted`] when a termination signal arrived.
    #[inline]
    fn spin_on<T>(
        &self,
        end: Option<u64>,
        mut poll: impl FnMut() -> Result<Option<T>, Error>,
    ) -> Result<Option<T>, Error> {
        let mut n: u32 = 0;
        loop {
            if let Some(x) = poll()? {
                return Ok(Some(x));
            }
            n = n.wrapping_add(1);
            if n.is_multiple_of(256) {
                if end.is_some_and(|e| monotonic_ns() >= e) {
                    return Ok(None);
                }
                // A read() of the signalfd is a syscall: check about every 64 K spins.
                if n.is_multiple_of(65_536)
                    && let Some(signal) = self.pending_signal()
                {
                    return Err(Error::Interrupted { signal });
                }
            }
            std::hint::spin_loop();
        }
    }

    /// Waits until `poll` yields a value, polling it after every wake-up, for at most
    /// `timeout`; `None` when the time ran out. In spin mode `poll` itself is what spins, so
    /// the value is taken the moment it is there, with no second look (the waiter's own
    /// readiness check followed by the caller's receive): [`Receiver::receive_timeout`] uses
    /// this. A termination signal caught by this waiter is returned as
    /// [`Error::Interrupted`].
    ///
    /// [`Receiver::receive_timeout`]: crate::channel::Receiver::receive_timeout
    #[inline]
    pub fn wait_for<T>(
        &mut self,
        timeout: Duration,
        mut poll: impl FnMut() -> Result<Option<T>, Error>,
    ) -> Result<Option<T>, Error> {
        if let Some(x) = poll()? {
            return Ok(Some(x));
        }
        let end = monotonic_ns().saturating_add(timeout.as_nanos() as u64);
        if self.mode == WaitMode::Spin {
            return self.spin_on(Some(end), poll);
        }
        loop {
            let left = end.saturating_sub(monotonic_ns());
            let wake = self.wait(Some(Duration::from_nanos(left)))?;
            if let Wake::Signal(signal) = wake {
                return Err(Error::Interrupted { signal });
            }
            // Data, or the time ran out: either way one more look.
            if let Some(x) = poll()? {
                return Ok(Some(x));
            }
            if wake == Wake::Timeout || monotonic_ns() >= end {
                return Ok(None);
            }
        }
    }

    fn sleep(&mut self, end: Option<u64>) -> Result<Wake, Error> {
        self.stats.sleeps += 1;
        loop {
            for (_, i) in &self.inputs {
                i.inlet().wake.begin_wait();
            }
            let ready = self.any_ready();
            let result = if ready {
                Ok(0)
            } else {
                let timeout = match end {
                    None => EpollTimeout::NONE,
                    Some(e) => {
                        let left = e.saturating_sub(monotonic_ns());
                        // epoll counts milliseconds: round up so we never wake early.
                        let ms = left.div_ceil(1_000_000);
                        EpollTimeout::try_from(ms).unwrap_or(EpollTimeout::MAX)
                    }
                };
                if let Some(c) = &self.cpus {
                    c.share.sleep();
                }
                self.epoll.wait(&mut self.events, timeout)
            };
            // Awake again (also after a spin that gave its core up and then found data).
            if let Some(c) = &self.cpus {
                c.share.wake();
            }
            for (_, i) in &self.inputs {
                i.inlet().wake.end_wait();
            }
            let n = match result {
                Ok(n) => n,
                Err(nix::errno::Errno::EINTR) => 0,
                Err(e) => return Err(Error::io("waiting in epoll", e)),
            };
            for ev in &self.events[..n] {
                let token = ev.data();
                if token == SIGNAL_TOKEN {
                    if let Some(sig) = self.pending_signal() {
                        return Ok(Wake::Signal(sig));
                    }
                } else if let Some((_, input)) = self.inputs.get(token as usize) {
                    input.inlet().drain_events();
                }
            }
            if self.any_ready() {
                return Ok(Wake::Data);
            }
            if end.is_some_and(|e| monotonic_ns() >= e) {
                return Ok(Wake::Timeout);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::channel::NodeOptions;
    use crate::msg::{Goal, Twist};
    use crate::shm;

    /// Looks at inputs without history read publish counts; what arrives without a publish
    /// (a late joiner's history, handed over when the publisher updates its connections) is
    /// still found on a channel with history, and a publish after an empty look on a channel
    /// without history is found at once.
    #[test]
    fn a_waiter_finds_new_publishes_and_history_that_came_without_one() {
        let prefix = shm::unique_prefix("waitcount");
        let a = Node::new(NodeOptions::new("a").prefix(&prefix)).expect("node a");
        let b = Node::new(NodeOptions::new("b").prefix(&prefix)).expect("node b");
        let publisher = a.publisher::<Goal>("t/goal").expect("publisher");
        publisher
            .publish(Goal::default())
            .expect("before anyone reads");
        let subscriber = b.subscriber::<Goal>("t/goal").expect("subscriber");
        let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
        waiter.attach(&subscriber).expect("attach");
        // Found empty at the current count (the history is not handed over yet).
        let short = Duration::from_millis(5);
        assert_eq!(waiter.wait(Some(short)).expect("wait"), Wake::Timeout);
        // The history comes with the publisher's next update, without a publish.
        a.update_connections();
        assert_eq!(
            waiter.wait(Some(Duration::from_secs(5))).expect("wait"),
            Wake::Data,
            "history without a publish"
        );
        assert_eq!(subscriber.receive().expect("rx").map(|g| g.id), Some(0));
        assert!(subscriber.receive().expect("rx").is_none());
        assert_eq!(waiter.wait(Some(short)).expect("wait"), Wake::Timeout);
        // A publish after an empty look is seen by the spin.
        publisher
            .publish(Goal {
                id: 7,
                ..Goal::default()
            })
            .expect("publish");
        assert_eq!(waiter.wait(Some(short)).expect("wait"), Wake::Data);
        assert_eq!(subscriber.receive().expect("rx").map(|g| g.id), Some(7));

        // A channel without history (commands): empty looks are answered from the count.
        let commands = a.publisher::<Twist>("t/cmd").expect("commands");
        let command_sub = b.subscriber::<Twist>("t/cmd").expect("command sub");
        waiter.attach(&command_sub).expect("attach");
        for _ in 0..3 {
            assert!(command_sub.receive().expect("rx").is_none());
            assert!(!waiter.any_ready());
            assert_eq!(waiter.ready().count(), 0);
        }
        let cmd = Twist {
            linear_x: 0.5,
            ..Twist::default()
        };
        commands.publish(cmd).expect("publish");
        assert!(waiter.any_ready());
        assert_eq!(waiter.ready().collect::<Vec<_>>(), [command_sub.id()]);
        assert_eq!(waiter.wait(Some(short)).expect("wait"), Wake::Data);
        let got: Vec<f64> = std::iter::from_fn(|| command_sub.receive().expect("rx"))
            .map(|t| t.linear_x)
            .collect();
        assert_eq!(got, [0.5]);
        assert_eq!(waiter.wait(Some(short)).expect("wait"), Wake::Timeout);
        commands.publish(cmd).expect("publish");
        assert_eq!(waiter.wait(Some(short)).expect("wait"), Wake::Data);
        assert!(command_sub.receive().expect("rx").is_some());
        drop((command_sub, commands));
        drop((subscriber, publisher, waiter, a, b));
        shm::remove_prefix_files(&prefix);
    }
}
