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
    /// Publishes are not noted (see [`super::Node::unannounced`]).
    quiet: Cell<bool>,
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
        if self.enabled.get() && !self.quiet.get() {
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

/// While it lives, the node's publishes are not noted as writes: see [`super::Node::unannounced`].
pub(crate) struct Unannounced<'a>(&'a WriteLog);

impl Drop for Unannounced<'_> {
    fn drop(&mut self) {
        self.0.quiet.set(false);
    }
}

impl super::Node {
    /// Until the guard is dropped, what this node publishes is not noted as written, so in
    /// lockstep no reader is called for it: the readers read it when something else calls
    /// them (the contract plane's repeated heartbeats, [`crate::control`]). For messages that
    /// change nothing a reader does before its next call.
    pub(crate) fn unannounced(&self) -> Unannounced<'_> {
        self.writes.quiet.set(true);
        Unannounced(&self.writes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::channel::{Node, NodeOptions};
    use crate::msg::Twist;
    use crate::shm;

    #[test]
    fn an_unannounced_publish_is_not_noted_and_the_next_one_is() {
        let prefix = shm::unique_prefix("unannounced");
        let node = Node::new(NodeOptions::new("a").prefix(&prefix)).expect("node");
        let p = node.publisher::<Twist>("u/t").expect("publisher");
        node.track_writes(true);
        {
            let _quiet = node.unannounced();
            p.publish(Twist::default()).expect("publish");
        }
        assert!(node.take_written().is_empty());
        p.publish(Twist::default()).expect("publish");
        assert_eq!(node.take_written(), [channel_key("u/t")]);
        drop((p, node));
        shm::remove_prefix_files(&prefix);
    }
}
