//! The executor's side of the simulation clock and of lockstep ([`crate::clock::lockstep`]):
//! where the simulated time and the round come from, what the module waits on between
//! rounds, and its answers.
//!
//! A module on the simulation clock reads the common [`CLOCK_CHANNEL`]. Once the simulator
//! calls it on its own [`round_channel`] (it does so to every participant until it knows
//! what they read), it takes its rounds from there only: it is then woken only for the
//! rounds it has work in. A module that is no participant (not in the simulator's
//! `lockstep` list, or a simulator without lockstep) is never called there and follows the
//! common channel, as every module did before selective rounds.

use crate::channel::{Node, Subscriber, channel_key};
use crate::clock::lockstep::{Acker, round_channel};
use crate::clock::{CLOCK_CHANNEL, Clock};
use crate::error::Error;
use crate::msg;
use crate::wait::{WaitMode, Waiter};

pub(super) struct Rounds {
    clock: Clock,
    /// The common clock channel (watched by the executor's waiter until selective).
    pub(super) common: Subscriber<msg::Clock>,
    /// This module's own round channel.
    own: Subscriber<msg::Clock>,
    /// The latest round called on the own channel (0: none).
    own_round: u64,
    /// Rounds come from the own channel only.
    selective: bool,
    /// What the module waits on while it holds its inputs for the next round.
    pub(super) waiter: Waiter,
    pub(super) acker: Acker,
    /// The latest round (0: none).
    pub(super) round: u64,
}

impl Rounds {
    /// Subscribes to both clock channels and reads the latest round: a module started while
    /// the simulator waits for a round's answers must answer it, not wait for the next one.
    pub(super) fn new(node: &Node, catch_signals: bool) -> Result<Rounds, Error> {
        let common = node.subscriber::<msg::Clock>(CLOCK_CHANNEL)?;
        let own = node.subscriber::<msg::Clock>(&round_channel(node.name()))?;
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&common)?;
        waiter.attach(&own)?;
        if catch_signals {
            waiter.catch_termination_signals()?;
        }
        let mut r = Rounds {
            clock: node.clock().clone(),
            common,
            own,
            own_round: 0,
            selective: false,
            waiter,
            acker: Acker::new(node)?,
            round: 0,
        };
        r.read(node)?;
        Ok(r)
    }

    /// Reads the latest clock sample: sets the simulated time and the round, and tells the
    /// node ("two phases"). Returns true when the module just became selective (the
    /// executor then stops watching the common channel).
    pub(super) fn read(&mut self, node: &Node) -> Result<bool, Error> {
        let mut became = false;
        if let Some(c) = self.own.latest()? {
            self.own_round = c.round;
            if self.selective {
                self.clock.set_sim_ns(c.sim_time_ns);
                self.round = c.round;
            }
        }
        if !self.selective
            && let Some(c) = self.common.latest()?
        {
            self.clock.set_sim_ns(c.sim_time_ns);
            self.round = c.round;
            // Called on the own channel to this very round: the simulator calls us there
            // (it publishes there before the common channel).
            if self.round != 0 && self.own_round == self.round {
                self.selective = true;
                self.waiter.detach(self.common.id())?;
                became = true;
            }
        }
        // What this iteration publishes belongs to this round, and what others publish
        // in it waits for the next (crate::clock::lockstep, "two phases").
        node.set_lockstep_round(self.round);
        Ok(became)
    }

    /// True while the module holds its inputs until it is called to the next round.
    pub(super) fn holds(&self) -> bool {
        self.acker.holds(self.round)
    }

    /// The end of an iteration: answers the round (see [`Acker::after_iteration`]), with
    /// the channels `waiter` watches as the module's inputs (the clock channels excepted).
    pub(super) fn answer(
        &mut self,
        node: &Node,
        waiter: &Waiter,
        ignored_out: u64,
        next_due_ns: u64,
    ) -> Result<(), Error> {
        if !self.acker.holds(self.round) && self.round != 0 {
            let common = channel_key(CLOCK_CHANNEL);
            self.acker
                .declare_inputs(waiter.input_keys().filter(|k| *k != common));
        }
        self.acker
            .after_iteration(node, self.round, ignored_out, next_due_ns)
    }
}
