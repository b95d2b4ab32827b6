//! Lockstep simulation: a barrier on the simulation clock.
//!
//! Without it, a simulator running faster than real time can outrun the modules that follow
//! its clock: at `speed = "max"` it steps on while they are still busy with older sensor
//! data, and what the robot does depends on how the processes were scheduled. In lockstep
//! (as Gazebo's lockstep between physics and sensor consumers) simulated time advances only
//! once every participating module has handled what the previous step caused:
//!
//! 1. The simulator takes a step and publishes [`msg::Clock`] with a new barrier `round`
//!    (then the step's sensor data).
//! 2. Every module on the simulation clock handles its inputs, timers and deadlines at that
//!    time (the executor does this, [`Acker`]) and then acknowledges the round with a
//!    [`ClockAck`] on [`ACK_CHANNEL`]: its name, the round, whether it was busy since its
//!    previous acknowledgement (published a message other than its report), and its next
//!    deadline in simulated time (its next timer, input deadline or contract
//!    deadline; none: `u64::MAX`).
//! 3. The simulator ([`Barrier`]) waits for the acknowledgement of every live participant.
//!    If one of them was busy, its output may be another module's input: the simulator opens
//!    another round at the same time, and so on until a round in which nobody did anything
//!    (the system is quiet). Only then does it take the next step.
//! 4. Steps that publish no data a participant reads and reach no participant's deadline
//!    ([`Barrier::next_due_ns`]) need no round: the simulator takes them one after the other
//!    and opens the next round at the first step that does. A module that acknowledged a
//!    round holds its inputs until the next one, so nothing it could do in between is lost.
//!
//! Why a quiet round proves that nothing is in flight: a message published before round `r`
//! was opened is already in its subscriber's queue when the subscriber reads round `r`, so the
//! subscriber handles it before acknowledging `r`; a message published after round `r` was
//! opened comes from a module that reports itself busy in round `r`. A round with every
//! participant idle therefore leaves no message unhandled behind it. Handling a message
//! without publishing anything gives nobody work, so only publishing makes a module busy
//! (until this version, handling an input or firing a timer did too: one more round per
//! link of every chain of modules).
//!
//! **Two phases: what a round delivers does not depend on scheduling.** A module that answers
//! round `r` quickly could hand its output to another module within `r` (if that one had not
//! read its inputs yet) or in `r + 1` (if it had): the same simulated instant, but the
//! receiver then handled its inputs in different groups and orders, and two runs with one
//! seed drifted apart. So every message carries the round in which it was sent
//! ([`msg::Header::round`], set from [`crate::Node::set_lockstep_round`], which the executor
//! calls with each round it reads), and a subscriber in round `r` keeps a message sent in `r`
//! for round `r + 1` (copied out of shared memory). In round `r` every module thus handles
//! exactly the messages sent before `r` opened, all of which are in its queues then (round
//! `r` opens only after every answer to `r - 1`, and a module answers after publishing): a
//! bulk-synchronous step, whatever the scheduling. The simulator sends a step's data outside
//! any round (0), so every module handles it in the round the step opens.
//!
//! Dead modules never freeze the world: the simulator drops a participant when the supervisor
//! reports it died or was deactivated, takes it back when it is started again (the world then
//! waits for the restarted module, which resumes from its checkpoint), and drops one that has
//! not answered for `timeout` of wall time (logged; it rejoins with its next acknowledgement).

use std::collections::BTreeMap;
use std::time::Duration;

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;

use crate::channel::{Node, Publisher};
use crate::error::Error;
use crate::msg::{self, Header, MODULE_NAME_LEN};
use crate::qos::ChannelKind;

/// The channel of the acknowledgements.
pub const ACK_CHANNEL: &str = "hng/clock_ack";

/// A module has handled everything up to a lockstep round (published on [`ACK_CHANNEL`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng/ClockAck/v2")]
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
    /// 1 if the module did anything since its previous acknowledgement.
    pub busy: u8,
    /// The module's next deadline in simulated time, ns (`u64::MAX`: none): the simulator
    /// opens a round at the first step at or after it even if no data goes out.
    pub next_due_ns: u64,
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
}

/// The module side: acknowledges each new round once the executor has handled its inputs.
pub struct Acker {
    publisher: Publisher<ClockAck>,
    name: String,
    acked_round: u64,
    busy: bool,
    out_seen: u64,
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
    /// Opens the acknowledgement channel on `node`.
    pub fn new(node: &Node) -> Result<Acker, Error> {
        Ok(Acker {
            publisher: node.publisher(ACK_CHANNEL)?,
            name: node.name().to_owned(),
            acked_round: 0,
            busy: false,
            out_seen: node.counters().msgs_out.get(),
        })
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

    /// The end of an executor iteration: `round` is the latest clock sample's round (0: no
    /// lockstep), `ignored_out` the messages published in this iteration that are nobody's
    /// input in simulated time (the module's report), `next_due_ns` the module's next
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
        if round == 0 || round == self.acked_round {
            return Ok(());
        }
        let mut ack = ClockAck {
            round,
            sim_time_ns: node.clock().now_ns(),
            busy: u8::from(self.busy),
            next_due_ns,
            ..Default::default()
        };
        ack.set_name(&self.name);
        self.publisher.publish(ack)?;
        self.out_seen = node.counters().msgs_out.get();
        self.acked_round = round;
        self.busy = false;
        Ok(())
    }
}

/// What a [`Barrier`] says about the open round.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Some participant has not answered yet.
    Waiting,
    /// Everyone answered and someone was busy: open another round at the same time.
    Busy,
    /// Everyone answered idle: the system is quiet, take the next step.
    Quiet,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Membership {
    /// Answers are waited for.
    Live,
    /// Dead, deactivated or silent: not waited for until it comes back.
    Out,
}

#[derive(Debug, Clone)]
struct Participant {
    membership: Membership,
    /// Round of the last acknowledgement.
    acked: u64,
    busy: bool,
    /// Its next deadline (simulated ns) as of its last acknowledgement; 0 until it answered.
    next_due_ns: u64,
}

/// The simulator side: which participants answered the open round. Transport-free; times are
/// wall-clock nanoseconds passed in.
#[derive(Debug, Clone)]
pub struct Barrier {
    participants: BTreeMap<String, Participant>,
    round: u64,
    open: bool,
    opened_ns: u64,
    timeout_ns: u64,
    /// Highest simulated clock any participant reported, ns.
    max_sim_ns: u64,
}

impl Barrier {
    /// A barrier over the named modules; one that stays silent for `timeout` (wall time) is
    /// left out until it answers again.
    pub fn new<S: AsRef<str>>(participants: &[S], timeout: Duration) -> Barrier {
        Barrier {
            participants: participants
                .iter()
                .map(|n| {
                    (
                        n.as_ref().to_owned(),
                        Participant {
                            membership: Membership::Live,
                            acked: 0,
                            busy: false,
                            next_due_ns: 0,
                        },
                    )
                })
                .collect(),
            round: 0,
            open: false,
            opened_ns: 0,
            timeout_ns: u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX),
            max_sim_ns: 0,
        }
    }

    /// Opens a new round (at `now_ns` wall time) and returns its number (never 0).
    pub fn open(&mut self, now_ns: u64) -> u64 {
        self.round += 1;
        self.open = true;
        self.opened_ns = now_ns;
        self.round
    }

    /// True while a round waits for answers.
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The last round opened.
    pub fn round(&self) -> u64 {
        self.round
    }

    /// The highest simulated time a participant reported, ns.
    pub fn max_reported_sim_ns(&self) -> u64 {
        self.max_sim_ns
    }

    /// An acknowledgement arrived. Returns true if it brought a participant back.
    pub fn ack(&mut self, a: &ClockAck) -> bool {
        self.max_sim_ns = self.max_sim_ns.max(a.sim_time_ns);
        let Some(p) = self.participants.get_mut(a.name()) else {
            return false;
        };
        if a.round != self.round {
            return false; // an answer to an older round (or an older simulator)
        }
        p.acked = a.round;
        p.busy = a.busy != 0;
        p.next_due_ns = a.next_due_ns;
        let back = p.membership == Membership::Out;
        p.membership = Membership::Live;
        back
    }

    /// The supervisor reports the module died or was deactivated: not waited for.
    pub fn left(&mut self, name: &str) -> bool {
        match self.participants.get_mut(name) {
            Some(p) if p.membership == Membership::Live => {
                p.membership = Membership::Out;
                true
            }
            _ => false,
        }
    }

    /// The supervisor started the module (again): waited for from now on.
    pub fn joined(&mut self, name: &str) -> bool {
        match self.participants.get_mut(name) {
            Some(p) if p.membership == Membership::Out => {
                p.membership = Membership::Live;
                p.next_due_ns = 0;
                true
            }
            _ => false,
        }
    }

    /// The earliest next deadline (simulated ns) of the participants waited for, as of their
    /// last acknowledgements: the latest simulated time the world may reach without a round
    /// (0 while one has not answered yet; `u64::MAX` when none has anything scheduled).
    pub fn next_due_ns(&self) -> u64 {
        self.participants
            .values()
            .filter(|p| p.membership == Membership::Live)
            .map(|p| p.next_due_ns)
            .min()
            .unwrap_or(u64::MAX)
    }

    /// The participants not waited for.
    pub fn left_out(&self) -> impl Iterator<Item = &str> + '_ {
        self.participants
            .iter()
            .filter(|(_, p)| p.membership == Membership::Out)
            .map(|(n, _)| n.as_str())
    }

    /// The verdict on the open round at `now_ns` (wall). Participants silent longer than the
    /// timeout are left out first; their names are returned.
    pub fn poll(&mut self, now_ns: u64) -> (Verdict, Vec<String>) {
        let mut dropped = Vec::new();
        if !self.open {
            return (Verdict::Quiet, dropped);
        }
        let timed_out = now_ns.saturating_sub(self.opened_ns) > self.timeout_ns;
        let mut waiting = false;
        let mut busy = false;
        for (name, p) in &mut self.participants {
            if p.membership == Membership::Out {
                continue;
            }
            if p.acked != self.round {
                if timed_out {
                    p.membership = Membership::Out;
                    dropped.push(name.clone());
                } else {
                    waiting = true;
                }
                continue;
            }
            busy |= p.busy;
        }
        let verdict = if waiting {
            Verdict::Waiting
        } else if busy {
            Verdict::Busy
        } else {
            Verdict::Quiet
        };
        if verdict != Verdict::Waiting {
            self.open = false;
        }
        (verdict, dropped)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ack(name: &str, round: u64, busy: bool) -> ClockAck {
        let mut a = ClockAck {
            round,
            busy: u8::from(busy),
            sim_time_ns: round * 10,
            next_due_ns: u64::MAX,
            ..Default::default()
        };
        a.set_name(name);
        a
    }

    const T: Duration = Duration::from_secs(5);

    #[test]
    fn a_round_closes_when_everyone_answered_and_is_quiet_only_when_nobody_was_busy() {
        let mut b = Barrier::new(&["laser", "slam"], T);
        let r = b.open(0);
        assert_eq!(r, 1);
        b.ack(&ack("laser", r, true));
        assert_eq!(b.poll(1).0, Verdict::Waiting);
        assert!(b.is_open());
        b.ack(&ack("slam", r, false));
        assert_eq!(b.poll(2).0, Verdict::Busy, "laser was busy: another round");
        assert!(!b.is_open());
        let r = b.open(3);
        b.ack(&ack("slam", r, true));
        b.ack(&ack("laser", r, false));
        assert_eq!(b.poll(4).0, Verdict::Busy);
        let r = b.open(5);
        b.ack(&ack("slam", r, false));
        assert_eq!(b.poll(6).0, Verdict::Waiting);
        b.ack(&ack("laser", r - 1, false));
        assert_eq!(
            b.poll(6).0,
            Verdict::Waiting,
            "an old round's answer counts for nothing"
        );
        b.ack(&ack("laser", r, false));
        assert_eq!(b.poll(7).0, Verdict::Quiet);
        assert_eq!(b.max_reported_sim_ns(), r * 10);
    }

    #[test]
    fn strangers_are_ignored_and_the_dead_are_not_waited_for() {
        let mut b = Barrier::new(&["laser", "slam"], T);
        let r = b.open(0);
        b.ack(&ack("monitor", r, true));
        b.ack(&ack("laser", r, false));
        assert_eq!(b.poll(1).0, Verdict::Waiting);
        assert!(b.left("slam"));
        assert_eq!(
            b.poll(2).0,
            Verdict::Quiet,
            "a dead module never freezes the world"
        );
        assert_eq!(b.left_out().collect::<Vec<_>>(), ["slam"]);
        // Started again: waited for.
        assert!(b.joined("slam"));
        let r = b.open(3);
        b.ack(&ack("laser", r, false));
        assert_eq!(b.poll(4).0, Verdict::Waiting);
        b.ack(&ack("slam", r, false));
        assert_eq!(b.poll(5).0, Verdict::Quiet);
    }

    #[test]
    fn a_silent_participant_is_left_out_after_the_timeout_and_rejoins_when_it_answers() {
        let mut b = Barrier::new(&["laser", "slam"], Duration::from_nanos(100));
        let r = b.open(0);
        b.ack(&ack("laser", r, false));
        assert_eq!(b.poll(50).0, Verdict::Waiting);
        let (v, dropped) = b.poll(101);
        assert_eq!((v, dropped), (Verdict::Quiet, vec!["slam".to_owned()]));
        let r = b.open(200);
        assert!(b.ack(&ack("slam", r, true)), "back");
        b.ack(&ack("laser", r, false));
        assert_eq!(b.poll(201).0, Verdict::Busy);
    }

    #[test]
    fn the_world_may_run_without_a_round_until_the_earliest_deadline_of_the_live() {
        let mut b = Barrier::new(&["laser", "slam"], T);
        assert_eq!(
            b.next_due_ns(),
            0,
            "nobody answered yet: a round at every step"
        );
        let r = b.open(0);
        let mut a = ack("laser", r, false);
        a.next_due_ns = 300;
        b.ack(&a);
        assert_eq!(b.next_due_ns(), 0, "slam has not answered");
        let mut a = ack("slam", r, false);
        a.next_due_ns = 200;
        b.ack(&a);
        assert_eq!(b.poll(1).0, Verdict::Quiet);
        assert_eq!(b.next_due_ns(), 200);
        assert!(b.left("slam"));
        assert_eq!(b.next_due_ns(), 300, "the dead are not waited for");
        assert!(b.joined("slam"));
        assert_eq!(
            b.next_due_ns(),
            0,
            "started again: unknown until it answers"
        );
        let r = b.open(2);
        b.ack(&ack("laser", r, false));
        b.ack(&ack("slam", r, false));
        assert_eq!(b.next_due_ns(), u64::MAX, "nothing scheduled");
    }
}
