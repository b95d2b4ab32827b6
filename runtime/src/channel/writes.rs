//! Which channels a node wrote: what a lockstep participant tells the barrier, so that the
//! next round opens only for the subscribers of those channels ([`crate::clock::lockstep`]).
//!
//! Channels are named by a 64-bit key ([`channel_key`]), the same for every process. The log
//! is off until [`super::Node::track_writes`] turns it on (lockstep participants and the
//! simulator); a publish then costs one more look at a short list.

use std::cell::{Cell, RefCell};

/// The key of a channel name (FNV-1a, 64 bits): what acknowledgements carry instead of
/// names. Two names with one key only cost a round nobody needed.
pub fn channel_key(channel: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in channel.as_bytes() {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// The channels a node wrote since they were last taken (each once).
#[derive(Debug, Default)]
pub(crate) struct WriteLog {
    enabled: Cell<bool>,
    keys: RefCell<Vec<u64>>,
}

impl WriteLog {
    pub(crate) fn set_enabled(&self, on: bool) {
        self.enabled.set(on);
        if !on {
            self.keys.borrow_mut().clear();
        }
    }

    #[inline]
    pub(crate) fn note(&self, key: u64) {
        if self.enabled.get() {
            let mut keys = self.keys.borrow_mut();
            if !keys.contains(&key) {
                keys.push(key);
            }
        }
    }

    pub(crate) fn take(&self) -> Vec<u64> {
        std::mem::take(&mut *self.keys.borrow_mut())
    }
}
