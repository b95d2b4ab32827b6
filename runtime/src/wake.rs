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
///
/// A paced simulator (real time, a factor) that would only go back to sleep after a quiet
/// round, its next step not being due yet, says until when (`quiet_until`, `CLOCK_MONOTONIC`
/// ns) and which channels its participants read (a [`ReadFilter`]): the last answer then
/// notifies only if the round may have given someone work (an answer wrote a channel the
/// filter may hold) or that time has passed; otherwise the simulator finds the answers at its
/// next step, on its own timer, when it would have looked anyway.
pub(crate) struct Countdown {
    segment: Segment,
}

/// The words of the countdown segment.
const COUNT: usize = 0;
/// Until when (`CLOCK_MONOTONIC` ns) a quiet round need not wake the simulator (0: always).
const QUIET_UNTIL: usize = 1;
/// The latest round (its low 32 bits, plus one) in which an answer wrote what a participant
/// may read.
const WORK_ROUND: usize = 2;
/// The [`ReadFilter`]'s words.
const FILTER: usize = 3;
const WORDS: usize = SEGMENT_LEN / 8;
/// Bits of a [`ReadFilter`].
const FILTER_BITS: u64 = ((WORDS - FILTER) * 64) as u64;

/// The channels the participants of a lockstep barrier read, as a Bloom filter of their
/// keys (two bits each): [`ReadFilter::may_read`] is never false for a key added, and true
/// for every key once [`ReadFilter::all`] was set (a participant that reads every channel, or
/// whose inputs are not known).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadFilter([u64; WORDS - FILTER]);

impl ReadFilter {
    fn bits(key: u64) -> [u64; 2] {
        [(key & 0xffff_ffff) % FILTER_BITS, (key >> 32) % FILTER_BITS]
    }

    /// Adds a channel's key.
    pub fn add(&mut self, key: u64) {
        for b in Self::bits(key) {
            self.0[(b / 64) as usize] |= 1 << (b % 64);
        }
    }

    /// Every channel may be read.
    pub fn all(&mut self) {
        self.0 = [u64::MAX; WORDS - FILTER];
    }

    /// May a participant read the channel of `key`?
    pub fn may_read(&self, key: u64) -> bool {
        Self::bits(key)
            .iter()
            .all(|b| self.0[(*b / 64) as usize] & (1 << (b % 64)) != 0)
    }
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
    fn words(&self) -> &[AtomicU64; WORDS] {
        // SAFETY: as WakeFlag::word; the segment is SEGMENT_LEN bytes, all atomic words.
        unsafe { self.segment.get() }
    }

    /// Simulator side: round `round` waits for `answers` answers; a last answer that finds
    /// the round quiet (nothing written that `reads` may hold) before `quiet_until_ns`
    /// (`CLOCK_MONOTONIC`; 0: never) need not wake the simulator.
    pub(crate) fn arm(&self, round: u64, answers: u32, quiet_until_ns: u64, reads: &ReadFilter) {
        let w = self.words();
        for (word, bits) in w[FILTER..].iter().zip(reads.0) {
            word.store(bits, Ordering::SeqCst);
        }
        w[QUIET_UNTIL].store(quiet_until_ns, Ordering::SeqCst);
        w[COUNT].store(
            ((round as u32 as u64) << 32) | u64::from(answers),
            Ordering::SeqCst,
        );
    }

    /// Participant side: may a participant read the channel of `key` (as of the open round)?
    pub(crate) fn may_be_read(&self, key: u64) -> bool {
        let mut f = ReadFilter::default();
        for (bits, word) in f.0.iter_mut().zip(&self.words()[FILTER..]) {
            *bits = word.load(Ordering::Relaxed);
        }
        f.may_read(key)
    }

    /// Participant side, after publishing its answer to `round` (`work`: it wrote a channel a
    /// participant may read) at `now_ns` (`CLOCK_MONOTONIC`): should it notify?
    pub(crate) fn answered(&self, round: u64, work: bool, now_ns: u64) -> bool {
        let w = self.words();
        let round = round as u32;
        if work {
            // Before the count goes down: the last answer, which sees the count after ours,
            // sees this too.
            w[WORK_ROUND].store(u64::from(round) + 1, Ordering::SeqCst);
        }
        let mut notify = true;
        let mut last = false;
        let _ = w[COUNT].fetch_update(Ordering::SeqCst, Ordering::SeqCst, |v| {
            let left = v as u32;
            if (v >> 32) as u32 != round || left == 0 {
                notify = true;
                last = false;
                return None;
            }
            notify = left == 1;
            last = notify;
            Some(v - 1)
        });
        if last
            && w[WORK_ROUND].load(Ordering::SeqCst) != u64::from(round) + 1
            && now_ns < w[QUIET_UNTIL].load(Ordering::SeqCst)
        {
            // Quiet, and the simulator wakes on its own before its next step is due.
            return false;
        }
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
        let none = ReadFilter::default();
        // Never armed (zeros): every answer notifies.
        assert!(module.answered(1, false, 0));
        sim.arm(7, 3, 0, &none);
        assert!(!module.answered(7, false, 0));
        assert!(
            module.answered(6, false, 0),
            "an answer to another round notifies"
        );
        assert!(!module.answered(7, false, 0));
        assert!(
            module.answered(7, false, 0),
            "the third answer completes the round"
        );
        assert!(
            module.answered(7, false, 0),
            "an extra answer (a left-out member) notifies"
        );
        sim.arm(8, 0, 0, &none);
        assert!(module.answered(8, false, 0));
        drop((sim, module));
        crate::shm::remove_prefix_files(&prefix);
    }

    #[test]
    fn a_quiet_round_wakes_a_paced_simulator_only_once_its_next_step_is_due() {
        let prefix = crate::shm::unique_prefix("quietwake");
        let sim = Countdown::open(&prefix, "t/ack").expect("open");
        let module = Countdown::open(&prefix, "t/ack").expect("open");
        let mut reads = ReadFilter::default();
        reads.add(11);
        reads.add(22);
        sim.arm(3, 2, 1_000, &reads);
        assert!(module.may_be_read(11) && module.may_be_read(22));
        // Quiet answers before the simulator's next step: nobody is woken.
        assert!(!module.answered(3, false, 500));
        assert!(
            !module.answered(3, false, 500),
            "quiet and early: no wake-up"
        );
        // Quiet, but late: the simulator is woken as before.
        sim.arm(4, 2, 1_000, &reads);
        assert!(!module.answered(4, false, 500));
        assert!(module.answered(4, false, 1_000));
        // A member that wrote something read, even if not the last: the last one notifies.
        sim.arm(5, 2, 1_000, &reads);
        assert!(!module.answered(5, true, 500));
        assert!(module.answered(5, false, 500), "the round may be busy");
        // Not paced (0): every last answer notifies.
        sim.arm(6, 1, 0, &reads);
        assert!(module.answered(6, false, 500));
        // A participant reading everything: every channel may be read.
        let mut all = ReadFilter::default();
        all.all();
        sim.arm(7, 1, 1_000, &all);
        assert!(module.may_be_read(12_345));
        drop((sim, module));
        crate::shm::remove_prefix_files(&prefix);
    }

    #[test]
    fn a_read_filter_holds_every_key_added() {
        let mut f = ReadFilter::default();
        let keys: Vec<u64> = (0..40u64)
            .map(|i| i.wrapping_mul(0x9e37_79b9_7f4a_7c15))
            .collect();
        for k in &keys {
            f.add(*k);
        }
        assert!(keys.iter().all(|k| f.may_read(*k)));
        assert!(!ReadFilter::default().may_read(keys[3]));
    }
}
