//! A heartbeat kept during a long computation, for modules whose one callback can take longer
//! than the watchdog's heartbeat timeout (Planning inflating and searching a 20000 x 20000
//! map took tens of seconds: it missed its heartbeats, was SIGKILLed ten times and the
//! mission ran into its time limit without saying why).
//!
//! The SDK sends a module's report (its heartbeat) from the module's thread, between
//! callbacks. [`BusyHeartbeat`] adds a thread with its own node that sends the same report,
//! pid and name while the module marks itself busy ([`BusyHeartbeat::busy`], a guard around
//! the computation), a quarter period into it and then at the report period, and for at most
//! `max_busy`: a computation that
//! runs longer than that is treated as a hang again (the thread falls silent and the watchdog
//! kills the module after its heartbeat timeout). Outside computations the thread sleeps on a
//! condition variable; nothing wakes on a period.
//!
//! Marking busy does not wake the thread for every computation: Planning marks every pose
//! (50 Hz), and a notification each time cost the process 50 thread wake-ups a second (0.12 %
//! of a core at 1x). While computations keep coming the thread looks every quarter period
//! (the first beat's delay): a computation that began after one look is seen at the next,
//! before it is a quarter period old, so the first beat still goes out a quarter period in.
//! Only a quarter period without any computation puts it to sleep until the next one, which
//! then notifies it.

use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{ModuleReport, ModuleState};
use hng_runtime::{Context, Node, NodeOptions, RunOptions};

#[derive(Debug, Default)]
struct State {
    /// Since when the module computes (`None`: idle), and the report to send meanwhile.
    busy: Option<(Instant, ModuleReport)>,
    /// Computations begun so far (the thread sees whether any came since its last look).
    begun: u64,
    /// The thread sleeps without a timeout: the next computation must notify it.
    asleep: bool,
    stop: bool,
}

#[derive(Debug, Default)]
struct Shared {
    state: Mutex<State>,
    wake: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// The heartbeat thread of a module (see the module documentation).
#[derive(Debug)]
pub struct BusyHeartbeat {
    shared: Arc<Shared>,
    period: Duration,
    thread: Option<JoinHandle<()>>,
}

/// Marks the module busy while it lives.
#[derive(Debug)]
pub struct BusyGuard<'a> {
    hb: &'a BusyHeartbeat,
}

impl Drop for BusyGuard<'_> {
    fn drop(&mut self) {
        self.hb.shared.lock().busy = None;
    }
}

impl BusyHeartbeat {
    /// Starts the thread for the module of `ctx` (its name, prefix and clock; the report
    /// period from the environment the supervisor sets). Computations longer than
    /// `max_busy` fall silent.
    pub fn start(ctx: &Context, max_busy: Duration) -> Result<BusyHeartbeat, hng_runtime::Error> {
        let opts = RunOptions::from_env(ctx.name())?;
        let period = opts.report_period.max(Duration::from_millis(1));
        let shared = Arc::new(Shared::default());
        let name = ctx.name().to_owned();
        let prefix = ctx.node().prefix().to_owned();
        let clock = ctx.clock().clone();
        let node_name = format!("{name}-heartbeat");
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let shared2 = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name(node_name.clone())
            .spawn(move || {
                let node = Node::new(NodeOptions::new(&node_name).prefix(&prefix).clock(clock));
                let publisher = node.as_ref().map_err(|e| e.to_string()).and_then(|n| {
                    n.publisher::<ModuleReport>(REPORT_CHANNEL)
                        .map_err(|e| e.to_string())
                });
                match publisher {
                    Ok(p) => {
                        let _ = ready_tx.send(Ok(()));
                        beat(&shared2, &p, period, max_busy);
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                    }
                }
            })
            .map_err(|e| hng_runtime::Error::Io {
                context: "starting the heartbeat thread".to_owned(),
                source: e,
            })?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(BusyHeartbeat {
                shared,
                period,
                thread: Some(thread),
            }),
            Ok(Err(e)) => Err(hng_runtime::Error::Config(format!(
                "{name}: heartbeat thread: {e}"
            ))),
            Err(_) => Err(hng_runtime::Error::Config(format!(
                "{name}: the heartbeat thread ended before it was ready"
            ))),
        }
    }

    /// Marks the module busy until the guard drops: the thread sends its report meanwhile.
    pub fn busy(&self, ctx: &Context) -> BusyGuard<'_> {
        let c = ctx.node().counters();
        let (aptitude, quality) = ctx.quality();
        let mut report = ModuleReport {
            pid: std::process::id(),
            state: ModuleState::Running as u8,
            aptitude: u8::from(aptitude),
            quality,
            period_ns: u64::try_from(self.period.as_nanos()).unwrap_or(u64::MAX),
            msgs_in: c.msgs_in.get(),
            msgs_out: c.msgs_out.get(),
            msgs_dropped: c.msgs_dropped.get(),
            deadline_misses: ctx.deadline_misses(),
            ..ModuleReport::default()
        };
        report.set_name(ctx.name());
        let asleep = {
            let mut st = self.shared.lock();
            st.busy = Some((Instant::now(), report));
            st.begun = st.begun.wrapping_add(1);
            st.asleep
        };
        // A thread that is not asleep looks again within a quarter period by itself.
        if asleep {
            self.shared.wake.notify_one();
        }
        BusyGuard { hb: self }
    }
}

impl Drop for BusyHeartbeat {
    fn drop(&mut self) {
        self.shared.lock().stop = true;
        self.shared.wake.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How long after `busy_for` into a computation the next beat is due: beats at `first`,
/// then every `period` after it.
fn next_beat_in(busy_for: Duration, first: Duration, period: Duration) -> Duration {
    if busy_for < first {
        return first - busy_for;
    }
    let into = (busy_for - first).as_nanos() % period.as_nanos().max(1);
    period.saturating_sub(Duration::from_nanos(u64::try_from(into).unwrap_or(0)))
}

/// The thread's loop: asleep while idle, a look every quarter period while computations
/// keep coming, a report every `period` while busy (up to `max_busy`).
fn beat(
    shared: &Shared,
    publisher: &hng_runtime::Publisher<ModuleReport>,
    period: Duration,
    max_busy: Duration,
) {
    let first = period / 4;
    let mut st = shared.lock();
    let mut seen = st.begun;
    loop {
        if st.stop {
            return;
        }
        let Some((since, report)) = st.busy else {
            if st.begun == seen {
                // Nothing began for a whole look: sleep until a computation notifies.
                st.asleep = true;
                st = shared.wake.wait(st).unwrap_or_else(PoisonError::into_inner);
                st.asleep = false;
            } else {
                // Computations keep coming: one that begins now is seen before it is a
                // quarter period old.
                seen = st.begun;
                st = wait_for(shared, st, first);
            }
            continue;
        };
        seen = st.begun;
        // The module's own report may have gone out up to a period before the computation
        // began (the SDK reports after its callbacks, when due), and one computation may
        // follow another within a callback (Planning reads a map, then plans): a first beat
        // one period in left up to two periods of silence, plus the scheduling delays of a
        // loaded machine, against a timeout of about three (`long_compute` was killed as
        // hung, silent 107 and 163 ms against 100 ms, at load 15-22). The first beat is due
        // a quarter period in; computations shorter than that send none.
        let busy_for = since.elapsed();
        if busy_for >= first && busy_for <= max_busy {
            drop(st);
            if let Err(e) = publisher.publish(report) {
                tracing::warn!("heartbeat during a computation: {e}");
            }
            st = shared.lock();
        }
        let wait = if busy_for > max_busy {
            // Too long: silent until the computation ends (the watchdog decides).
            None
        } else {
            Some(next_beat_in(busy_for, first, period))
        };
        st = match wait {
            Some(w) => wait_for(shared, st, w),
            None => {
                st.asleep = true;
                let mut st = shared.wake.wait(st).unwrap_or_else(PoisonError::into_inner);
                st.asleep = false;
                st
            }
        };
    }
}

/// Waits on the condition variable for `wait` (at least 1 ms), or until notified.
fn wait_for<'a>(
    shared: &'a Shared,
    st: MutexGuard<'a, State>,
    wait: Duration,
) -> MutexGuard<'a, State> {
    shared
        .wake
        .wait_timeout(st, wait.max(Duration::from_millis(1)))
        .unwrap_or_else(PoisonError::into_inner)
        .0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_beat_comes_a_quarter_period_in_then_one_every_period() {
        let ms = Duration::from_millis;
        let (first, period) = (ms(30) / 4, ms(30));
        assert_eq!(next_beat_in(ms(0), first, period), first);
        assert_eq!(next_beat_in(ms(5), first, period), first - ms(5));
        // Just after the first beat: the next a period later.
        assert_eq!(next_beat_in(first, first, period), period);
        assert_eq!(next_beat_in(first + ms(10), first, period), ms(20));
        assert_eq!(next_beat_in(first + ms(61), first, period), ms(29));
    }
}
