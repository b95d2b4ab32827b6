//! The wake flag: a shared counter of subscribers blocked on a channel.
//!
//! iceoryx2's event notification costs a datagram per listener (a few microseconds). A
//! publisher only needs to pay it when a subscriber actually sleeps: a subscriber that spins,
//! or that is busy, sees new samples by itself. Each channel therefore has a tiny shared
//! segment holding the number of subscribers about to block. The protocol is the classic
//! futex one:
//!
//! - subscriber: `waiters.fetch_add(1)`; check for samples; block (with a timeout);
//!   `waiters -= 1`
//! - publisher: write and send the sample; `if waiters.fetch_add(0) > 0 { notify }`
//!
//! Both sides read-modify-write the same counter, so the two operations are ordered in its
//! modification order and the later one synchronizes with the earlier (acquire-release): if
//! the publisher's comes first, the subscriber's check sees the sample; if the subscriber's
//! comes first, the publisher sees the waiter and notifies. A wake-up is never lost, and no
//! full fence is needed (a locked add is cheaper than `mfence` on x86). A subscriber killed while blocked leaves the count
//! raised; publishers then merely notify when they need not. The segments live in `/dev/shm`
//! under the system's prefix and are removed with the prefix ([`crate::shm::remove_prefix_files`]).
//!
//! The same word also counts the samples published (its high 32 bits; the low 32 bits are
//! the waiters): the publisher's read-modify-write adds one to the count instead of zero, so
//! it costs nothing more. A subscriber that found its port empty at count `c` knows it is
//! still empty while the count reads `c`, and reads one word instead of asking iceoryx2,
//! whose look walks every publisher slot of the channel (128 on the report and control
//! channels): in the spin before a sleep, in the executor's look at its inputs after a wake,
//! and in the `receive` that ends a drain (the contract plane drains a handful of channels at
//! every call). Only on channels without history: a publisher hands its history to a late
//! joiner when it updates its connections, which no publish counts, so a subscriber of a
//! channel with history always asks its port (those channels have at most 4 publishers).

use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::Error;
use crate::shm::Segment;

const SEGMENT_LEN: usize = 64;

/// File-name part that marks wake segments.
pub(crate) const WAKE_TAG: &str = "hngwake_";

pub(crate) struct WakeFlag {
    segment: Segment,
}

fn fnv64(s: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in s.as_bytes() {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Opens (or creates) the wake segment of `key` under `prefix`; `what` names it in errors.
/// Every wake segment carries [`WAKE_TAG`], by which the prefix's clean-up finds it.
fn open_segment(prefix: &str, key: &str, what: &str) -> Result<Segment, Error> {
    let name = format!("/{prefix}{WAKE_TAG}{:016x}", fnv64(key));
    Segment::open(&name, SEGMENT_LEN, what)
}

impl WakeFlag {
    pub(crate) fn open(prefix: &str, channel: &str) -> Result<WakeFlag, Error> {
        let segment = open_segment(prefix, channel, &format!("channel {channel:?}"))?;
        Ok(WakeFlag { segment })
    }

    #[inline]
    fn word(&self) -> &AtomicU64 {
        // SAFETY: the segment is 64 bytes, page-aligned, lives as long as self, and is only
        // ever accessed atomically.
        unsafe { self.segment.get() }
    }

    /// Subscriber side: announce that we are about to block. Check for samples after this.
    pub(crate) fn begin_wait(&self) {
        self.word().fetch_add(1, Ordering::SeqCst);
    }

    /// Subscriber side: we are awake again.
    pub(crate) fn end_wait(&self) {
        // Saturating: a restarted subscriber must not wrap a count left by a dead one (nor
        // borrow from the publish count above it).
        let _ = self
            .word()
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |v| {
                (waiters(v) > 0).then(|| v - 1)
            });
    }

    /// Publisher side, after sending: counts the sample; does anyone need a notification?
    #[inline]
    pub(crate) fn published_has_waiters(&self) -> bool {
        waiters(self.word().fetch_add(PUBLISHED_ONE, Ordering::SeqCst)) > 0
    }

    /// Subscriber side: the samples published so far (wrapping). Read it before asking the
    /// port whether it has samples: if the port had none, it has none while this is unchanged.
    #[inline]
    pub(crate) fn published(&self) -> u32 {
        (self.word().load(Ordering::SeqCst) >> 32) as u32
    }
}

/// One sample in the publish count (the word's high half).
const PUBLISHED_ONE: u64 = 1 << 32;

/// The answers a lockstep round still waits for, shared by the simulator and its
/// participants: only the answer that completes the round wakes the simulator
/// ([`crate::clock::lockstep`], "one wake-up per round").
///
/// One word: the round (its low 32 bits) in the high half, the answers outstanding in the
/// low half. The simulator arms it before it calls the round's members; a participant
/// counts its answer down after publishing it, and notifies only when the count reaches
/// zero, when it was zero already, or when the word names another round (a simulator that
/// does not count, a restarted one, a late answer). So the last answer of a round always
/// notifies; an answer that does not is seen by the simulator when the last one wakes it
/// (it was published first), or at once if the simulator was not asleep.
pub(crate) struct Countdown {
    segment: Segment,
}

impl Countdown {
    pub(crate) fn open(prefix: &str, channel: &str) -> Result<Countdown, Error> {
        let segment = open_segment(
            prefix,
            &format!("{channel}#countdown"),
            &format!("countdown of {channel:?}"),
        )?;
        Ok(Countdown { segment })
    }

    #[inline]
    fn word(&self) -> &AtomicU64 {
        // SAFETY: as WakeFlag::word.
        unsafe { self.segment.get() }
    }

    /// Simulator side: round `round` waits for `answers` answers.
    pub(crate) fn arm(&self, round: u64, answers: u32) {
        self.word().store(
            ((round as u32 as u64) << 32) | u64::from(answers),
            Ordering::SeqCst,
        );
    }

    /// Participant side, after publishing its answer to `round`: should it notify?
    pub(crate) fn answered(&self, round: u64) -> bool {
        let round = round as u32;
        let mut notify = true;
        let _ = self
            .word()
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |v| {
                let left = v as u32;
                if (v >> 32) as u32 != round || left == 0 {
                    notify = true;
                    return None;
                }
                notify = left == 1;
                Some(v - 1)
            });
        notify
    }
}

#[inline]
fn waiters(word: u64) -> u32 {
    word as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publishes_are_counted_apart_from_waiters_and_waiters_never_borrow_from_them() {
        let prefix = crate::shm::unique_prefix("wakeword");
        let flag = WakeFlag::open(&prefix, "t/wake").expect("open");
        let before = flag.published();
        assert!(!flag.published_has_waiters());
        assert_eq!(flag.published(), before.wrapping_add(1));
        flag.begin_wait();
        assert!(flag.published_has_waiters());
        assert_eq!(flag.published(), before.wrapping_add(2));
        flag.end_wait();
        // One end too many (a waiter that died blocked, then restarted): the count stays.
        flag.end_wait();
        assert_eq!(flag.published(), before.wrapping_add(2));
        assert!(!flag.published_has_waiters());
        drop(flag);
        crate::shm::remove_prefix_files(&prefix);
    }

    #[test]
    fn only_the_answer_that_completes_a_round_notifies() {
        let prefix = crate::shm::unique_prefix("countdown");
        let sim = Countdown::open(&prefix, "t/ack").expect("open");
        let module = Countdown::open(&prefix, "t/ack").expect("open");
        // Never armed (zeros): every answer notifies.
        assert!(module.answered(1));
        sim.arm(7, 3);
        assert!(!module.answered(7));
        assert!(module.answered(6), "an answer to another round notifies");
        assert!(!module.answered(7));
        assert!(module.answered(7), "the third answer completes the round");
        assert!(
            module.answered(7),
            "an extra answer (a left-out member) notifies"
        );
        sim.arm(8, 0);
        assert!(module.answered(8));
        drop((sim, module));
        crate::shm::remove_prefix_files(&prefix);
    }
}
