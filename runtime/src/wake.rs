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
//! under the system's prefix and are removed with the prefix ([`crate::cleanup_prefix`]).

use std::sync::atomic::{AtomicU32, Ordering};

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

impl WakeFlag {
    pub(crate) fn open(prefix: &str, channel: &str) -> Result<WakeFlag, Error> {
        let name = format!("/{prefix}{WAKE_TAG}{:016x}", fnv64(channel));
        let segment = Segment::open(&name, SEGMENT_LEN, &format!("channel {channel:?}"))?;
        Ok(WakeFlag { segment })
    }

    #[inline]
    fn counter(&self) -> &AtomicU32 {
        // SAFETY: the segment is 64 bytes, page-aligned, lives as long as self, and is only
        // ever accessed atomically.
        unsafe { self.segment.get() }
    }

    /// Subscriber side: announce that we are about to block. Check for samples after this.
    pub(crate) fn begin_wait(&self) {
        self.counter().fetch_add(1, Ordering::SeqCst);
    }

    /// Subscriber side: we are awake again.
    pub(crate) fn end_wait(&self) {
        // Saturating: a restarted subscriber must not wrap a count left by a dead one.
        let _ = self
            .counter()
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |v| v.checked_sub(1));
    }

    /// Publisher side, after sending: does anyone need a notification?
    #[inline]
    pub(crate) fn has_waiters(&self) -> bool {
        self.counter().fetch_add(0, Ordering::SeqCst) > 0
    }
}
