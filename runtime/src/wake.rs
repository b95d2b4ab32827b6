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

use std::num::NonZeroUsize;
use std::ptr::NonNull;
use std::sync::atomic::{AtomicU32, Ordering};

use nix::fcntl::OFlag;
use nix::sys::mman::{MapFlags, ProtFlags, mmap, munmap, shm_open};
use nix::sys::stat::Mode;

use crate::error::Error;

const SEGMENT_LEN: usize = 64;

/// File-name part that marks wake segments.
pub(crate) const WAKE_TAG: &str = "hngwake_";

pub(crate) struct WakeFlag {
    ptr: NonNull<AtomicU32>,
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
        let ctx = || format!("channel {channel:?}: wake segment {name}");
        let fd = shm_open(
            name.as_str(),
            OFlag::O_CREAT | OFlag::O_RDWR,
            Mode::S_IRUSR | Mode::S_IWUSR,
        )
        .map_err(|e| Error::io(ctx(), e))?;
        let len = SEGMENT_LEN as i64;
        let st = nix::sys::stat::fstat(&fd).map_err(|e| Error::io(ctx(), e))?;
        if st.st_size < len {
            nix::unistd::ftruncate(&fd, len).map_err(|e| Error::io(ctx(), e))?;
        }
        let size = NonZeroUsize::new(SEGMENT_LEN).ok_or_else(|| Error::Config("zero".into()))?;
        // SAFETY: a fresh shared mapping of a file we just sized; no other Rust object aliases it.
        let ptr = unsafe {
            mmap(
                None,
                size,
                ProtFlags::PROT_READ | ProtFlags::PROT_WRITE,
                MapFlags::MAP_SHARED,
                &fd,
                0,
            )
        }
        .map_err(|e| Error::io(ctx(), e))?;
        Ok(WakeFlag { ptr: ptr.cast() })
    }

    #[inline]
    fn counter(&self) -> &AtomicU32 {
        // SAFETY: the mapping is at least 64 bytes, page-aligned, lives as long as self, and is
        // only ever accessed atomically.
        unsafe { self.ptr.as_ref() }
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

impl Drop for WakeFlag {
    fn drop(&mut self) {
        // SAFETY: the mapping was created in `open` with this length and is not used after drop.
        let _ = unsafe { munmap(self.ptr.cast(), SEGMENT_LEN) };
    }
}
