//! Channels written from outside the barrier, watched by the simulator.
//!
//! The supervisor, the resource manager and an operator's tools publish without taking part
//! in the rounds, so nobody's acknowledgement says they wrote. The simulator looks at their
//! channels' publish counts (a word in shared memory beside each channel's wake flag,
//! `crate::wake`) before every step, without subscribing and without being woken: a count
//! that moved makes the channel's readers pending, as if the step had written it, so each
//! reader handles the message at that step. Before this, every participant was called every
//! `lockstep_idle_s` (0.1 s of simulated time) in case something had come from outside.

use crate::channel::{Node, channel_key};
use crate::error::Error;
use crate::msg::ORDER_CHANNEL;
use crate::system::SUPERVISOR_EVENTS;
use crate::wake::WakeFlag;

/// The channels of the default system written from outside the barrier on an event: the
/// supervisor's events (a module died, was started, ...), the operator's orders,
/// teleoperation and missions. Not the resource manager's costs: it publishes them every
/// period (10 Hz), whatever changed, so watching them would call every contracted module
/// at that rate; a module reads them at its next call (its contract deadlines come every
/// refresh period, 0.2 s by default, and `lockstep_idle_s` bounds the rest).
pub const DEFAULT_OUTSIDE: [&str; 4] = [
    SUPERVISOR_EVENTS,
    ORDER_CHANNEL,
    "hng/teleop",
    "hng/mission",
];

/// The publish counts of channels written from outside the barrier.
pub struct OutsideWrites {
    /// Each channel's key, its count word and the count last seen.
    watched: Vec<(u64, WakeFlag, u32)>,
}

impl std::fmt::Debug for OutsideWrites {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OutsideWrites")
            .field("channels", &self.watched.len())
            .finish()
    }
}

impl OutsideWrites {
    /// Watches `channels` of `node`'s system from their present counts on.
    pub fn open<S: AsRef<str>>(node: &Node, channels: &[S]) -> Result<OutsideWrites, Error> {
        let watched = channels
            .iter()
            .map(|c| {
                let flag = WakeFlag::open(node.prefix(), c.as_ref())?;
                let seen = flag.published();
                Ok((channel_key(c.as_ref()), flag, seen))
            })
            .collect::<Result<Vec<_>, Error>>()?;
        Ok(OutsideWrites { watched })
    }

    /// The keys of the channels published to since the last call (appended to `out`).
    pub fn written_since(&mut self, out: &mut Vec<u64>) {
        for (key, flag, seen) in &mut self.watched {
            let now = flag.published();
            if now != *seen {
                *seen = now;
                out.push(*key);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::channel::NodeOptions;
    use crate::msg::Twist;

    #[test]
    fn a_publish_on_a_watched_channel_is_seen_once_and_others_not_at_all() {
        let prefix = crate::shm::unique_prefix("outside");
        let node = Node::new(NodeOptions::new("sim").prefix(&prefix)).expect("node");
        let peer = Node::new(NodeOptions::new("operator").prefix(&prefix)).expect("node");
        let watched = peer.publisher::<Twist>("t/watched").expect("publisher");
        watched.publish(Twist::default()).expect("publish");
        let mut w = OutsideWrites::open(&node, &["t/watched", "t/quiet"]).expect("open");
        let other = peer.publisher::<Twist>("t/other").expect("publisher");
        let mut keys = Vec::new();
        w.written_since(&mut keys);
        assert!(
            keys.is_empty(),
            "what was published before it watched is not news"
        );
        watched.publish(Twist::default()).expect("publish");
        watched.publish(Twist::default()).expect("publish");
        other.publish(Twist::default()).expect("publish");
        w.written_since(&mut keys);
        assert_eq!(keys, [channel_key("t/watched")]);
        keys.clear();
        w.written_since(&mut keys);
        assert!(keys.is_empty(), "seen once");
        drop((watched, other, peer, node, w));
        crate::shm::remove_prefix_files(&prefix);
    }
}
