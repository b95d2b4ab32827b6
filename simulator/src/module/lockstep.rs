//! The simulator's side of lockstep ([`hng_runtime::clock::lockstep`]): the barrier, the
//! acknowledgements of the participants, and the supervisor's events that take dead modules
//! out of it and started ones back in.

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::clock::lockstep::{ACK_CHANNEL, Barrier, ClockAck, Verdict};
use hng_runtime::clock::monotonic_ns;
use hng_runtime::system::{EventKind, ModuleEvent, SUPERVISOR_EVENTS};
use hng_runtime::{Context, ModuleResult, Subscriber};

/// The barrier with its inputs.
pub(super) struct Lockstep {
    barrier: Barrier,
    acks: Subscriber<ClockAck>,
    events: Subscriber<ModuleEvent>,
    /// Rounds opened, and of them those opened again at the same time (someone was busy).
    pub(super) rounds: u64,
    pub(super) extra_rounds: u64,
    /// Rounds opened at the current simulated time.
    same_time: u32,
    warned: bool,
}

/// Rounds at one simulated time after which the simulator steps on even if a module is still
/// busy (modules that keep answering each other at the same time would otherwise stop the
/// world; a chain of modules is far shorter).
const MAX_ROUNDS_AT_ONE_TIME: u32 = 64;

impl Lockstep {
    /// Subscribes to the acknowledgements and the supervisor's events.
    pub(super) fn new(
        ctx: &mut Context,
        participants: &[String],
        timeout_s: f64,
    ) -> ModuleResult<Lockstep> {
        Ok(Lockstep {
            barrier: Barrier::new(participants, Duration::from_secs_f64(timeout_s)),
            acks: ctx.subscribe(ACK_CHANNEL, None)?,
            events: ctx.subscribe(SUPERVISOR_EVENTS, None)?,
            rounds: 0,
            extra_rounds: 0,
            same_time: 0,
            warned: false,
        })
    }

    /// True if `input` is one of the barrier's.
    pub(super) fn owns(&self, input: InputId) -> bool {
        input == self.acks.id() || input == self.events.id()
    }

    /// Opens a round (`again`: at the same simulated time as the last one); returns its
    /// number, for the clock sample.
    pub(super) fn open(&mut self, again: bool) -> u64 {
        self.rounds += 1;
        if again {
            self.extra_rounds += 1;
            self.same_time += 1;
        } else {
            self.same_time = 0;
        }
        self.barrier.open(monotonic_ns())
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
