//! The sending side every publisher shares: notifier, wake flag, header stamping, and the
//! note of what was written (lockstep).

use super::*;

/// What the sending side of a channel shares between fixed and slice publishers.
pub(super) struct Outlet {
    pub(super) notifier: Notifier<Service>,
    pub(super) wake: WakeFlag,
    pub(super) seq: Cell<u64>,
    pub(super) source: u32,
    pub(super) clock: Clock,
    pub(super) channel: Rc<str>,
    pub(super) counters: Rc<Counters>,
    pub(super) notified: Cell<u64>,
    pub(super) round: Rc<Cell<u32>>,
    pub(super) key: u64,
    pub(super) writes: Rc<WriteLog>,
}

impl Outlet {
    #[inline]
    pub(super) fn stamp(&self, h: &mut Header) {
        let seq = self.seq.get() + 1;
        self.seq.set(seq);
        h.seq = seq;
        h.stamp_ns = self.clock.now_ns();
        h.source = self.source;
        h.round = self.round.get();
    }

    /// Numbers a recorded header (replay): the sequence is this publisher's, the stamp and
    /// the source are the recording's.
    pub(super) fn stamp_recorded(&self, h: &mut Header) {
        let seq = self.seq.get() + 1;
        self.seq.set(seq);
        h.seq = seq;
        h.round = self.round.get();
    }

    #[inline]
    pub(super) fn sent(&self) -> Result<(), Error> {
        self.sent_gated(|| true)
    }

    /// [`Outlet::sent`], notifying a sleeping subscriber only if `gate` says so. The gate
    /// runs after the send and before the wake flag is read (whether anyone sleeps or not):
    /// when gates of several publishers agree on which of them notifies (a countdown), the
    /// samples of the others were sent before that one reads the flag, so a subscriber that
    /// it does not notify (it was not asleep yet) sees them all when it looks.
    #[inline]
    pub(super) fn sent_gated(&self, gate: impl FnOnce() -> bool) -> Result<(), Error> {
        Counters::add(&self.counters.msgs_out, 1);
        self.writes.note(self.key);
        let notify = gate();
        if self.wake.published_has_waiters() && notify {
            self.notified.set(self.notified.get() + 1);
            Counters::add(&self.counters.wakeups, 1);
            self.notifier
                .notify()
                .map_err(|e| Error::channel(&self.channel, "notify", e))?;
        }
        Ok(())
    }
}
