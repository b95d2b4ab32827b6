//! The simulator's side of lockstep ([`hng_runtime::clock::lockstep`]): the barrier, the
//! acknowledgements of the participants, and the supervisor's events that take dead modules
//! out of it and started ones back in.

use std::time::{Duration, Instant};

use hng_runtime::channel::{InputId, Node, Publisher};
use hng_runtime::clock::lockstep::{
    ACK_CHANNEL, Barrier, ClockAck, OutsideWrites, RoundCountdown, Verdict, round_channel,
};
use hng_runtime::clock::monotonic_ns;
use hng_runtime::system::{EventKind, ModuleEvent, SUPERVISOR_EVENTS};
use hng_runtime::{Context, ModuleResult, Subscriber, msg};

use super::{SimulatorModule, TICK_BUDGET};
use crate::pacing::Speed;

/// The barrier with its inputs.
pub(super) struct Lockstep {
    barrier: Barrier,
    acks: Subscriber<ClockAck>,
    events: Subscriber<ModuleEvent>,
    /// Each participant's own round channel, by name.
    calls: Vec<(String, Publisher<msg::Clock>)>,
    /// Channels written from outside the barrier (`lockstep_outside`).
    outside: OutsideWrites,
    /// Scratch: what a step and the outside wrote.
    written: Vec<u64>,
    /// The answers the open round waits for: only the last one wakes us.
    countdown: RoundCountdown,
    /// Members called to the rounds so far (summed over the rounds).
    pub(super) members: u64,
    /// Rounds opened, and of them those opened again at the same time (someone was busy).
    pub(super) rounds: u64,
    pub(super) extra_rounds: u64,
    /// Steps taken without a round (nothing a participant reads, no deadline reached).
    pub(super) steps_without_round: u64,
    /// Rounds opened at the current simulated time.
    same_time: u32,
    warned: bool,
}

/// Rounds at one simulated time after which the simulator steps on even if a module is still
/// busy (modules that keep answering each other at the same time would otherwise stop the
/// world; a chain of modules is far shorter).
const MAX_ROUNDS_AT_ONE_TIME: u32 = 64;

impl Lockstep {
    /// Subscribes to the acknowledgements and the supervisor's events, and opens each
    /// participant's round channel on `node` (the simulator's data node). Every participant
    /// is called at least every `idle_s` of simulated time, and the readers of the
    /// `outside` channels at the first step after one was written.
    pub(super) fn new(
        ctx: &mut Context,
        node: &Node,
        participants: &[String],
        (timeout_s, idle_s): (f64, f64),
        outside: &[String],
    ) -> ModuleResult<Lockstep> {
        let calls = participants
            .iter()
            .map(|n| Ok((n.clone(), node.publisher::<msg::Clock>(&round_channel(n))?)))
            .collect::<ModuleResult<Vec<_>>>()?;
        Ok(Lockstep {
            barrier: Barrier::new(participants, Duration::from_secs_f64(timeout_s))
                .selective(Duration::from_secs_f64(idle_s)),
            acks: ctx.subscribe(ACK_CHANNEL, None)?,
            events: ctx.subscribe(SUPERVISOR_EVENTS, None)?,
            calls,
            outside: OutsideWrites::open(node, outside)?,
            written: Vec::new(),
            countdown: RoundCountdown::open(node)?,
            members: 0,
            rounds: 0,
            extra_rounds: 0,
            steps_without_round: 0,
            same_time: 0,
            warned: false,
        })
    }

    /// True if `input` is one of the barrier's.
    pub(super) fn owns(&self, input: InputId) -> bool {
        input == self.acks.id() || input == self.events.id()
    }

    /// Opens a round at `sim_ns` (`again`: at the same simulated time as the last one) and
    /// calls its members on their own channels; returns its number, for the common clock
    /// sample, which goes out after the calls. A round that ends quiet before `quiet_until_ns`
    /// (`CLOCK_MONOTONIC`; 0: never) does not wake us ([`RoundCountdown::arm_paced`]).
    pub(super) fn open(
        &mut self,
        sim_ns: u64,
        again: bool,
        quiet_until_ns: u64,
    ) -> ModuleResult<u64> {
        self.rounds += 1;
        if again {
            self.extra_rounds += 1;
            self.same_time += 1;
        } else {
            self.same_time = 0;
        }
        let round = self.barrier.open_at(monotonic_ns(), sim_ns, again);
        let members = self.barrier.members();
        self.members += members as u64;
        // Armed before the calls go out: the member whose answer completes the round wakes us
        // (if the round may be busy, or our next step is due).
        self.countdown
            .arm_paced(round, members, quiet_until_ns, &self.barrier.reads());
        let called: Vec<&str> = self.barrier.called().collect();
        tracing::trace!(round, sim_ns, again, ?called, "lockstep: round opened");
        for (name, publisher) in &self.calls {
            if called.contains(&name.as_str()) {
                publisher.publish(msg::Clock {
                    sim_time_ns: sim_ns,
                    round,
                    ..Default::default()
                })?;
            }
        }
        Ok(round)
    }

    /// What a step wrote (the keys of its channels), with what was written from outside
    /// the barrier since the last step: does it need a round? `data`: it published more
    /// than ground truth.
    pub(super) fn step_wants_round(&mut self, sim_ns: u64, written: &[u64], data: bool) -> bool {
        self.written.clear();
        self.written.extend_from_slice(written);
        self.outside.written_since(&mut self.written);
        self.barrier.written(Some(&self.written));
        self.barrier.wants_round(sim_ns, data)
    }

    /// The round of the clock samples published now (0 when no round is open).
    pub(super) fn round(&self) -> u64 {
        if self.barrier.is_open() {
            self.barrier.round()
        } else {
            0
        }
    }

    /// Reads the acknowledgements and the supervisor's events.
    pub(super) fn read(&mut self, ctx: &Context) -> ModuleResult {
        while let Some(a) = self.acks.receive()? {
            if self.barrier.ack(&a) {
                tracing::info!(
                    module = ctx.name(),
                    participant = a.name(),
                    "lockstep: answering again, waited for"
                );
            }
        }
        while let Some(e) = self.events.receive()? {
            let name = e.module();
            match e.kind() {
                Some(EventKind::Died | EventKind::Deactivated | EventKind::Stopped)
                    if self.barrier.left(name) =>
                {
                    tracing::info!(
                        module = ctx.name(),
                        participant = name,
                        "lockstep: not waited for (it stopped)"
                    );
                }
                Some(EventKind::Started) if self.barrier.joined(name) => {
                    tracing::info!(
                        module = ctx.name(),
                        participant = name,
                        "lockstep: started again, waited for"
                    );
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// The verdict on the open round (participants silent too long are left out, logged).
    pub(super) fn poll(&mut self, ctx: &Context) -> Verdict {
        let (mut verdict, dropped) = self.barrier.poll(monotonic_ns());
        if verdict == Verdict::Busy && self.same_time >= MAX_ROUNDS_AT_ONE_TIME {
            if !self.warned {
                self.warned = true;
                tracing::warn!(
                    module = ctx.name(),
                    rounds = self.same_time,
                    "lockstep: modules still busy after this many rounds at one simulated \
                     time (they keep answering each other): stepping on (logged once)"
                );
            }
            verdict = Verdict::Quiet;
        }
        for name in dropped {
            tracing::warn!(
                module = ctx.name(),
                participant = %name,
                "lockstep: no answer within lockstep_timeout_s, not waited for until it answers"
            );
        }
        verdict
    }
}

/// How long before the next step is due a quiet round's last answer wakes us all the same
/// (the clocks of two processes agree, but the margin keeps the step's timing as it was).
const QUIET_MARGIN_NS: u64 = 500_000;

impl SimulatorModule {
    /// Until when (`CLOCK_MONOTONIC` ns) a round that ends quiet need not wake us: a paced
    /// simulator woken before its next step is due would only look at the answers and sleep
    /// again until its timer; it reads them at that timer instead, before it steps (one
    /// wake-up a step fewer at 1x). 0 (always wake us) at `max` or when the step is due.
    pub(super) fn quiet_until_ns(&self) -> u64 {
        if self.speed == Speed::Unlimited {
            return 0;
        }
        let next = self.sim.now_ns().saturating_add(self.sim.dt_ns());
        let delay = u64::try_from(self.pacer.delay_until(next).as_nanos()).unwrap_or(u64::MAX);
        if delay <= QUIET_MARGIN_NS {
            return 0;
        }
        monotonic_ns().saturating_add(delay - QUIET_MARGIN_NS)
    }

    /// Lockstep: looks at the open round; opens another one at the same time when someone
    /// was busy, and takes the next step (if it is due) when everyone was quiet.
    pub(super) fn lockstep_advance(&mut self, ctx: &mut Context) -> ModuleResult {
        if self.waiting.is_some() {
            return Ok(());
        }
        let quiet_until = self.quiet_until_ns();
        let Some(l) = self.lockstep.as_mut() else {
            return Ok(());
        };
        match l.poll(ctx) {
            Verdict::Waiting => Ok(()),
            Verdict::Busy => {
                l.open(self.sim.now_ns(), true, quiet_until)?;
                self.publish_clock()
            }
            Verdict::Quiet => {
                // Every command of the quiet round applies from the next step on, whatever
                // order the executor handed us the inputs in.
                self.read_commands(ctx)?;
                // Steps that need no round follow each other at once (within the pace, at
                // most `max_steps_per_tick` and the tick budget; the timer brings us back).
                let started = Instant::now();
                for _ in 0..self.max_steps.max(1) {
                    if self.end_ns.is_some_and(|end| self.sim.now_ns() >= end) {
                        tracing::info!(module = ctx.name(), "duration reached: stopping");
                        ctx.request_stop();
                        return Ok(());
                    }
                    let next = self.sim.now_ns().saturating_add(self.sim.dt_ns());
                    if !self.pacer.delay_until(next).is_zero() {
                        break;
                    }
                    self.step_and_publish()?;
                    if self.lockstep.as_ref().is_some_and(|l| l.round() != 0)
                        || started.elapsed() >= TICK_BUDGET
                    {
                        break;
                    }
                }
                Ok(())
            }
        }
    }
}
