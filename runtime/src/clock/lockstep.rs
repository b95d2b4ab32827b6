//! Lockstep simulation: a barrier on the simulation clock.
//!
//! Without it, a simulator running faster than real time can outrun the modules that follow
//! its clock: at `speed = "max"` it steps on while they are still busy with older sensor
//! data, and what the robot does depends on how the processes were scheduled. In lockstep
//! (as Gazebo's lockstep between physics and sensor consumers) simulated time advances only
//! once every participating module has handled what the previous step caused.
//!
//! **A round opens only for those it can give work to.** Waking every module for every round
//! costs a context switch each (about 15 per round in the default mission), although most
//! rounds carry work for one or two of them. So:
//!
//! 1. The simulator takes a step and publishes its sensor data. It then opens a barrier
//!    `round` and *calls* its members: it publishes a [`msg::Clock`] with the round on each
//!    member's own channel ([`round_channel`]), then on [`CLOCK_CHANNEL`] (for tools, and for
//!    participants that read every round there).
//! 2. A called module handles its inputs, timers and deadlines at that time (the executor
//!    does this, [`Acker`]) and acknowledges the round with a [`ClockAck`] on
//!    [`ACK_CHANNEL`]: its name, the round, the channels it **wrote** since its previous
//!    acknowledgement (their [`channel_key`]s, its report excepted), the channels it
//!    **reads** (the inputs its executor watches; not its polled inputs,
//!    [`crate::Context::subscribe_polled`]), and its next deadline in simulated time
//!    (its next timer, input deadline or contract deadline; none: `u64::MAX`).
//! 3. The simulator ([`Barrier`]) waits for the acknowledgements of the round's members
//!    only. A channel written by a member, or by the step, makes every participant that
//!    reads it *pending*. The members of a round are the pending participants, those whose
//!    deadline has come (at most `idle` of simulated time after their last round: see below),
//!    and those whose inputs are not known yet (not answered since they joined) or who read
//!    every round on [`CLOCK_CHANNEL`] (tools such as the recorder, tests). Everybody else
//!    is neither woken nor waited for.
//! 4. When a round closes with someone pending, another round opens at the same time, and
//!    so on until nobody is (the system is quiet). Only then does the simulator step on.
//!    Steps that write nothing a participant reads and reach nobody's deadline need no
//!    round; the simulator takes them one after the other.
//!
//! Why a quiet round proves that nothing is in flight: a message travels on a channel, and
//! whoever wrote it says so in its acknowledgement of the round it wrote it in (the
//! simulator knows what its steps wrote). The barrier marks every reader of that channel
//! pending, and a pending participant is a member of the next round, which opens only after
//! every acknowledgement of this one. A module handles everything sent before its round
//! opened (step 2), so after a round with nobody pending no message is unhandled. A module
//! that is not called has nothing in its queues that a participant sent, and no deadline
//! due: calling it would have changed nothing (a module that handles no input and fires no
//! timer publishes nothing, and the contract plane's timers are part of its deadline).
//! Messages from processes outside the barrier (the supervisor's events, the resource
//! manager, an operator's order) are nobody's acknowledgement. The simulator watches the
//! channels written on an event ([`OutsideWrites`], `lockstep_outside`: the supervisor's
//! events, orders, teleoperation, missions) and makes their readers pending at the next
//! step; what else comes from outside (the resource manager's periodic costs) a module reads
//! at its next round: its own deadline, at the latest `idle` of simulated time later
//! (`lockstep_idle_s`). So are the contract heartbeats that repeat the last one, which a
//! member writes unannounced (`control/repeats.rs`): both sides of a contract have a
//! deadline every refresh period.
//!
//! **Two phases: what a round delivers does not depend on scheduling.** A module that answers
//! round `r` quickly could hand its output to another module within `r` (if that one had not
//! read its inputs yet) or in `r + 1` (if it had): the same simulated instant, but the
//! receiver then handled its inputs in different groups and orders, and two runs with one
//! seed drifted apart. So every message carries the round in which it was sent
//! ([`msg::Header::round`], set from [`crate::Node::set_lockstep_round`], which the executor
//! calls with each round it handles), and a subscriber in round `r` keeps a message sent in
//! `r` for its next round (copied out of shared memory); the writer's acknowledgement of `r`
//! makes the reader pending, so that is `r + 1`. In round `r` every member thus handles
//! exactly the messages sent before `r` opened: a bulk-synchronous step, whatever the
//! scheduling. Who is called depends only on what was written and on the deadlines, so it is
//! the same in two runs with one seed. The simulator sends a step's data outside any round
//! (0), so every module handles it in the round the step opens.
//!
//! Dead modules never freeze the world: the simulator drops a participant when the supervisor
//! reports it died or was deactivated, takes it back when it is started again (the world then
//! waits for the restarted module, which resumes from its checkpoint, and calls it every
//! round until it answers), and drops one that has not answered for `timeout` of wall time
//! (logged; it is still called, and rejoins with its next acknowledgement).

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;

pub use crate::channel::channel_key;
use crate::channel::{Node, Publisher};
use crate::clock::CLOCK_CHANNEL;
use crate::error::Error;
use crate::msg::{self, Header, MODULE_NAME_LEN};
use crate::qos::ChannelKind;
use crate::wake::Countdown;
pub use crate::wake::ReadFilter;

mod barrier;
mod outside;
pub use barrier::{Barrier, Verdict};
pub use outside::{DEFAULT_OUTSIDE, OutsideWrites};

/// The channel of the acknowledgements.
pub const ACK_CHANNEL: &str = "hng/clock_ack";

/// Channels an acknowledgement can list as read or as written.
pub const MAX_KEYS: usize = 32;

/// A length of [`ClockAck::inputs`] or [`ClockAck::written`] that means "more than
/// [`MAX_KEYS`]": the participant reads every channel / every reader is pending.
pub const TOO_MANY: u16 = u16::MAX;

/// The channel on which the simulator calls participant `name` to a round.
pub fn round_channel(name: &str) -> String {
    format!("{CLOCK_CHANNEL}/{name}")
}

/// A module has handled everything up to a lockstep round (published on [`ACK_CHANNEL`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/ClockAck/v3")]
pub struct ClockAck {
    /// Header (stamped with the module's simulated clock).
    pub header: Header,
    /// The module's name, NUL-padded UTF-8.
    #[serde(skip)]
    pub name: [u8; MODULE_NAME_LEN],
    /// The round acknowledged ([`msg::Clock::round`]).
    pub round: u64,
    /// The module's simulated clock when it acknowledged, ns.
    pub sim_time_ns: u64,
    /// The module's next deadline in simulated time, ns (`u64::MAX`: none): the simulator
    /// calls it at the first step at or after it even if nothing was written to it.
    pub next_due_ns: u64,
    /// 1 if the module published anything (its report excepted) since its previous
    /// acknowledgement.
    pub busy: u8,
    /// 1: the module takes its rounds from its own [`round_channel`] and reads only
    /// `inputs`, so it is called only when needed; 0: it reads every round on
    /// [`CLOCK_CHANNEL`] and is a member of every round.
    pub selective: u8,
    /// How many of `inputs` are used ([`TOO_MANY`]: more than fit).
    pub inputs_len: u16,
    /// How many of `written` are used ([`TOO_MANY`]: more than fit).
    pub written_len: u16,
    /// The [`channel_key`]s of the channels the module reads.
    #[serde(skip)]
    pub inputs: [u64; MAX_KEYS],
    /// The [`channel_key`]s of the channels it wrote since its previous acknowledgement.
    #[serde(skip)]
    pub written: [u64; MAX_KEYS],
}

crate::impl_message!(ClockAck, ChannelKind::Report);

impl ClockAck {
    /// The module name as text.
    pub fn name(&self) -> &str {
        msg::get_str(&self.name)
    }

    /// Sets the module name (cut to [`MODULE_NAME_LEN`] bytes).
    pub fn set_name(&mut self, name: &str) {
        msg::put_str(&mut self.name, name);
    }

    /// The channels read: `None` when more than fit (or not selective: every round).
    pub fn input_keys(&self) -> Option<&[u64]> {
        keys(&self.inputs, self.inputs_len)
    }

    /// The channels written: `None` when more than fit.
    pub fn written_keys(&self) -> Option<&[u64]> {
        keys(&self.written, self.written_len)
    }
}

fn keys(all: &[u64; MAX_KEYS], len: u16) -> Option<&[u64]> {
    all.get(..usize::from(len))
}

/// Writes `keys` into `out`; returns the length to send ([`TOO_MANY`] if they do not fit).
fn put_keys(out: &mut [u64; MAX_KEYS], keys: &[u64]) -> u16 {
    match out.get_mut(..keys.len()) {
        Some(dst) => {
            dst.copy_from_slice(keys);
            keys.len() as u16
        }
        None => TOO_MANY,
    }
}

/// The answers a round still waits for, shared by the simulator ([`RoundCountdown::arm`]
/// when it opens a round) and the participants ([`Acker`]): only the answer that completes
/// the round wakes the simulator, instead of one wake-up per answer (see [`super`]).
pub struct RoundCountdown(Countdown);

impl std::fmt::Debug for RoundCountdown {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RoundCountdown").finish_non_exhaustive()
    }
}

impl RoundCountdown {
    /// Opens the countdown of `node`'s system.
    pub fn open(node: &Node) -> Result<RoundCountdown, Error> {
        Ok(RoundCountdown(Countdown::open(node.prefix(), ACK_CHANNEL)?))
    }

    /// Round `round` waits for `answers` answers (call before calling its members). Every
    /// last answer wakes the simulator.
    pub fn arm(&self, round: u64, answers: usize) {
        self.arm_paced(round, answers, 0, &ReadFilter::default());
    }

    /// [`RoundCountdown::arm`] for a simulator that, if the round ends quiet before
    /// `quiet_until_ns` (`CLOCK_MONOTONIC`), wakes on its own timer anyway before its next
    /// step is due: the last answer then wakes it only if some answer wrote a channel that
    /// `reads` (what the participants read) may hold. A round that was busy after all (a
    /// member began reading a channel written in the same round) is then seen at the
    /// simulator's next wake-up: later, never wrong.
    pub fn arm_paced(&self, round: u64, answers: usize, quiet_until_ns: u64, reads: &ReadFilter) {
        self.0.arm(
            round,
            u32::try_from(answers).unwrap_or(u32::MAX),
            quiet_until_ns,
            reads,
        );
    }

    /// A participant answered `round` (its answer is out; `written`: the channels it wrote,
    /// `None`: more than could be listed): should it wake the simulator?
    fn answered(&self, round: u64, written: Option<&[u64]>) -> bool {
        let work = written.is_none_or(|w| w.iter().any(|k| self.0.may_be_read(*k)));
        self.0.answered(round, work, crate::clock::monotonic_ns())
    }
}

/// The module side: acknowledges each new round once the executor has handled its inputs.
pub struct Acker {
    publisher: Publisher<ClockAck>,
    countdown: RoundCountdown,
    name: String,
    acked_round: u64,
    busy: bool,
    out_seen: u64,
    /// The channels read (sorted), once declared: the module is called only when needed.
    inputs: Option<Vec<u64>>,
    /// The channels written since the last acknowledgement.
    written: Vec<u64>,
    /// Written channels nobody needs a round for: the report and the acknowledgements.
    ignored: [u64; 2],
}

impl std::fmt::Debug for Acker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Acker")
            .field("name", &self.name)
            .field("acked_round", &self.acked_round)
            .field("busy", &self.busy)
            .finish_non_exhaustive()
    }
}

impl Acker {
    /// Opens the acknowledgement channel on `node`, and notes from now on which channels
    /// the node writes ([`Node::track_writes`]).
    pub fn new(node: &Node) -> Result<Acker, Error> {
        node.track_writes(true);
        let _ = node.take_written();
        Ok(Acker {
            publisher: node.publisher(ACK_CHANNEL)?,
            countdown: RoundCountdown::open(node)?,
            name: node.name().to_owned(),
            acked_round: 0,
            busy: false,
            out_seen: node.counters().msgs_out.get(),
            inputs: None,
            written: Vec::new(),
            ignored: [
                channel_key(crate::module::REPORT_CHANNEL),
                channel_key(ACK_CHANNEL),
            ],
        })
    }

    /// Declares the channels the module reads (their [`channel_key`]s), and that it takes its
    /// rounds from its own [`round_channel`]: from its next acknowledgement on, the barrier
    /// calls it only when one of them was written or its deadline came. Without this, the
    /// participant reads every round on [`CLOCK_CHANNEL`] and is a member of each.
    pub fn declare_inputs(&mut self, keys: impl IntoIterator<Item = u64>) {
        let mut v: Vec<u64> = keys.into_iter().collect();
        v.sort_unstable();
        v.dedup();
        self.inputs = Some(v);
    }

    /// True while the module holds its inputs for the next round: it acknowledged `round`
    /// (the latest it saw, not 0). Inputs that arrive then were published in the round
    /// acknowledged or later, and are handled with the next one, so a module handles a
    /// step's sensor data together, whatever the scheduling.
    pub fn holds(&self, round: u64) -> bool {
        round != 0 && round == self.acked_round
    }

    /// The module did something (handled an input, fired a timer, missed a deadline).
    pub fn note_busy(&mut self) {
        self.busy = true;
    }

    /// The end of an executor iteration: `round` is the latest round the module was called
    /// to (0: no lockstep), `ignored_out` the messages published in this iteration that are
    /// nobody's input in simulated time (the module's report), `next_due_ns` the module's next
    /// deadline (simulated ns, `u64::MAX`: none). Acknowledges a round not acknowledged
    /// yet; a round that differs counts as new, so a restarted simulator (counting from 1
    /// again) is answered.
    pub fn after_iteration(
        &mut self,
        node: &Node,
        round: u64,
        ignored_out: u64,
        next_due_ns: u64,
    ) -> Result<(), Error> {
        let out = node.counters().msgs_out.get();
        if out.saturating_sub(self.out_seen) > ignored_out {
            self.busy = true;
        }
        self.out_seen = out;
        for k in node.take_written() {
            if !self.ignored.contains(&k) && !self.written.contains(&k) {
                self.written.push(k);
            }
        }
        if round == 0 || round == self.acked_round {
            return Ok(());
        }
        let mut ack = ClockAck {
            round,
            sim_time_ns: node.clock().now_ns(),
            busy: u8::from(self.busy),
            next_due_ns,
            selective: u8::from(self.inputs.is_some()),
            ..Default::default()
        };
        ack.set_name(&self.name);
        if let Some(inputs) = &self.inputs {
            ack.inputs_len = put_keys(&mut ack.inputs, inputs);
        }
        ack.written_len = put_keys(&mut ack.written, &self.written);
        let written = (ack.written_len != TOO_MANY).then_some(self.written.as_slice());
        // Only the answer that completes the round wakes the simulator.
        self.publisher
            .publish_gated(ack, || self.countdown.answered(round, written))?;
        let _ = node.take_written();
        self.written.clear();
        self.out_seen = node.counters().msgs_out.get();
        self.acked_round = round;
        self.busy = false;
        Ok(())
    }
}
