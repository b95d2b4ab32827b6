//! Lockstep in a replay of one module (`hng replay --module`): the replay stands in for the
//! simulator's barrier ([`hng_runtime::clock::lockstep::Barrier`]). Each recorded clock
//! sample goes out with a round of this barrier, after the messages recorded with it, and the
//! replay waits until the module under test (and the recorder of its outputs) acknowledged
//! the round before it publishes more. The module then handles each step's inputs together,
//! at the recorded simulated time, however the processes are scheduled, and nothing
//! overflows a buffer however fast the replay goes.

use std::time::Duration;

use hng_runtime::channel::{Node, Publisher, Subscriber};
use hng_runtime::clock::CLOCK_CHANNEL;
use hng_runtime::clock::lockstep::{ACK_CHANNEL, Barrier, ClockAck, RoundCountdown, Verdict};
use hng_runtime::clock::monotonic_ns;
use hng_runtime::msg;
use hng_runtime::wait::{WaitMode, Waiter};

use crate::Error;
use crate::codec::FixedCodec;

/// The replay's barrier.
pub(crate) struct Driver {
    clock: Publisher<msg::Clock>,
    acks: Subscriber<ClockAck>,
    waiter: Waiter,
    barrier: Barrier,
    /// The answers the open round waits for: only the last one wakes the replay.
    countdown: RoundCountdown,
    /// Rounds opened.
    pub(crate) rounds: u64,
    /// Participants left out after not answering within the timeout (logged).
    pub(crate) left_out: u64,
}

impl Driver {
    /// Publishes the clock on `node` and waits for `participants`; one silent for `timeout`
    /// is not waited for until it answers again.
    pub(crate) fn new(
        node: &Node,
        participants: &[String],
        timeout: Duration,
    ) -> Result<Driver, Error> {
        let acks = node.subscriber::<ClockAck>(ACK_CHANNEL)?;
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&acks)?;
        Ok(Driver {
            clock: node.publisher::<msg::Clock>(CLOCK_CHANNEL)?,
            acks,
            waiter,
            barrier: Barrier::new(participants, timeout),
            countdown: RoundCountdown::open(node)?,
            rounds: 0,
            left_out: 0,
        })
    }

    /// Publishes the recorded clock sample `data` with a new round and waits until every
    /// participant acknowledged it.
    pub(crate) fn step(&mut self, data: &[u8]) -> Result<(), Error> {
        let mut c = msg::Clock::decode(data).map_err(|detail| Error::Codec {
            channel: CLOCK_CHANNEL.to_string(),
            detail,
        })?;
        c.round = self.barrier.open(monotonic_ns());
        // Armed before the round goes out, as the simulator does: the participant whose
        // answer completes it wakes the replay (a count left by an earlier system on this
        // prefix would otherwise hold that answer back until the wait's timeout).
        self.countdown.arm(c.round, self.barrier.members());
        self.rounds += 1;
        self.clock.publish_recorded(c)?;
        loop {
            while let Some(a) = self.acks.receive()? {
                self.barrier.ack(&a);
            }
            let (verdict, dropped) = self.barrier.poll(monotonic_ns());
            for name in &dropped {
                self.left_out += 1;
                tracing::warn!(
                    participant = %name,
                    "replay lockstep: no answer in time, not waited for until it answers"
                );
            }
            if verdict != Verdict::Waiting {
                return Ok(());
            }
            self.waiter.wait(Some(Duration::from_millis(50)))?;
        }
    }
}
