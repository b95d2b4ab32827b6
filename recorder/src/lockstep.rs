//! The recorder as a lockstep participant ([`hng_runtime::clock::lockstep`]): in a simulated
//! run the simulator waits, every round, until the recorder too has read what the round
//! brought, so no channel's buffer can overflow before the recorder reads it, however seldom
//! its thread is scheduled.
//!
//! Each pass of the recorder: wait for the next clock sample (its round `r`), read every
//! channel, acknowledge `r` (never busy: what the recorder publishes is nobody's input).
//! Everything published before round `r` was opened is in the recorder's queues when it reads
//! the clock sample of `r` (iceoryx2 delivers at publish time), so it is read before the
//! acknowledgement; a round is opened only when every participant acknowledged the last one,
//! so between two reads a channel receives at most what one round causes, far below its
//! buffer.

use std::time::Duration;

use hng_runtime::Subscriber;
use hng_runtime::channel::{Node, NodeOptions};
use hng_runtime::clock::lockstep::Acker;
use hng_runtime::clock::{CLOCK_CHANNEL, Clock};
use hng_runtime::msg;
use hng_runtime::wait::{WaitMode, Waiter};

use crate::Error;

/// The participant name `hng run --record` adds to the simulator's `lockstep` list.
pub const PARTICIPANT: &str = "recorder";

/// The recorder's side of the barrier.
pub(crate) struct Participant {
    node: Node,
    clock: Subscriber<msg::Clock>,
    acker: Acker,
    waiter: Waiter,
    /// The latest round seen (0: none yet, or no lockstep).
    round: u64,
    /// Rounds acknowledged.
    pub(crate) acks: u64,
}

impl Participant {
    /// Joins as `name` (a name in the simulator's `lockstep` list) on `prefix`.
    pub(crate) fn new(prefix: &str, name: &str) -> Result<Participant, Error> {
        // Its acknowledgements carry the simulated time of the round, like a module's.
        let node = Node::new(NodeOptions::new(name).prefix(prefix).clock(Clock::sim()))?;
        let clock = node.subscriber::<msg::Clock>(CLOCK_CHANNEL)?;
        let acker = Acker::new(&node)?;
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&clock)?;
        Ok(Participant {
            node,
            clock,
            acker,
            waiter,
            round: 0,
            acks: 0,
        })
    }

    /// Waits at most `timeout` for a clock sample; keeps the latest round seen.
    pub(crate) fn wait(&mut self, timeout: Duration) -> Result<(), Error> {
        let first = self.clock.receive_timeout(&mut self.waiter, timeout)?;
        let mut latest = first;
        while let Some(c) = self.clock.receive()? {
            latest = Some(c);
        }
        if let Some(c) = latest {
            self.node.clock().set_sim_ns(c.sim_time_ns);
            self.round = c.round;
        }
        Ok(())
    }

    /// Every channel was read after the clock sample of the latest round: acknowledge it
    /// (once per round).
    pub(crate) fn ack(&mut self) -> Result<(), Error> {
        let before = self.acker.holds(self.round);
        self.acker
            .after_iteration(&self.node, self.round, 0, u64::MAX)?;
        if !before && self.acker.holds(self.round) {
            self.acks += 1;
        }
        Ok(())
    }
}
