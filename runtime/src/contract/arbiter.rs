//! Driver arbitration (paper, 5.6 "Drivers"; like ROS `twist_mux`).
//!
//! A driver (e.g. the Robot module's "Robot control") may hold several client
//! contracts at once, but obeys exactly one commanding client at a time: the
//! *live* client with the most important priority. A client is live when it
//! holds a contract with the driver and sent a command less than `freshness`
//! ago. Others are ignored (counted as [`DropReason::Preempted`]) and regain
//! control as soon as the controlling client releases its contract or goes
//! silent for `freshness` (fail safe: a silent controller never blocks the
//! others forever). Commands from a publisher holding no contract are ignored
//! and counted as [`DropReason::NoContract`]. Equal priorities (only possible
//! transiently) go to the smaller module id.

use std::collections::BTreeMap;
use std::time::Duration;

use super::wire::{DropCounters, DropReason};
use super::{ModuleId, Priority};

/// What the driver does with a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Execute it: the sender has control.
    Accept,
    /// Ignore it, for this reason ([`DropReason::NoContract`] or [`DropReason::Preempted`]).
    Ignore(DropReason),
}

#[derive(Debug, Clone, Copy)]
struct Holder {
    priority: Priority,
    last_command: Option<Duration>,
}

/// Chooses which contract holder a driver obeys. Pure logic, time passed in.
#[derive(Debug, Clone)]
pub struct CommandArbiter {
    freshness: Duration,
    holders: BTreeMap<ModuleId, Holder>,
    drops: DropCounters,
}

impl CommandArbiter {
    /// An arbiter whose clients lose control after `freshness` without command.
    pub fn new(freshness: Duration) -> Self {
        Self {
            freshness,
            holders: BTreeMap::new(),
            drops: DropCounters::default(),
        }
    }

    /// `client` holds a contract of priority `priority` (new, or priority changed).
    pub fn offer(&mut self, client: ModuleId, priority: Priority, _now: Duration) {
        self.holders
            .entry(client)
            .and_modify(|h| h.priority = priority)
            .or_insert(Holder {
                priority,
                last_command: None,
            });
    }

    /// `client`'s contract ended: it loses control at once.
    pub fn release(&mut self, client: ModuleId) {
        self.holders.remove(&client);
    }

    /// Replaces the set of contract holders (e.g. from
    /// [`super::ContractAgent::client_contracts`]); holders that stay keep
    /// their command freshness. If a client appears twice, its most important
    /// priority is used.
    pub fn sync<I: IntoIterator<Item = (ModuleId, Priority)>>(&mut self, holders: I) {
        let mut next: BTreeMap<ModuleId, Holder> = BTreeMap::new();
        for (id, priority) in holders {
            let last_command = self.holders.get(&id).and_then(|h| h.last_command);
            next.entry(id)
                .and_modify(|h| h.priority = h.priority.min(priority))
                .or_insert(Holder {
                    priority,
                    last_command,
                });
        }
        self.holders = next;
    }

    fn live(&self, h: &Holder, now: Duration) -> bool {
        h.last_command
            .is_some_and(|t| now.saturating_sub(t) < self.freshness)
    }

    /// A command from `client` arrived at `now`: obey it or not.
    pub fn on_command(&mut self, client: ModuleId, now: Duration) -> Verdict {
        let Some(h) = self.holders.get_mut(&client) else {
            self.drops.record(DropReason::NoContract);
            return Verdict::Ignore(DropReason::NoContract);
        };
        h.last_command = Some(now);
        if self.active(now) == Some(client) {
            Verdict::Accept
        } else {
            self.drops.record(DropReason::Preempted);
            Verdict::Ignore(DropReason::Preempted)
        }
    }

    /// The client in control at `now`, if any live client exists.
    pub fn active(&self, now: Duration) -> Option<ModuleId> {
        self.holders
            .iter()
            .filter(|(_, h)| self.live(h, now))
            .min_by_key(|(id, h)| (h.priority, **id))
            .map(|(id, _)| *id)
    }

    /// Ignored commands, by reason.
    pub fn drops(&self) -> &DropCounters {
        &self.drops
    }

    /// Number of contract holders.
    pub fn holders(&self) -> usize {
        self.holders.len()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // Tests may unwrap.
mod tests {
    use super::*;
    use crate::contract::tests::ms;

    #[test]
    fn contract_arbiter_priority_preemption_and_freshness() {
        let (sec, gui, servo, stranger) = (ModuleId(1), ModuleId(2), ModuleId(3), ModuleId(99));
        let mut a = CommandArbiter::new(ms(300));
        a.offer(sec, "1.1".parse().unwrap(), ms(0));
        a.offer(gui, "2.1".parse().unwrap(), ms(0));
        a.offer(servo, "2.2.1.1".parse().unwrap(), ms(0));
        assert_eq!(a.active(ms(0)), None, "nobody commands yet");
        assert_eq!(a.on_command(servo, ms(10)), Verdict::Accept);
        assert_eq!(
            a.on_command(gui, ms(20)),
            Verdict::Accept,
            "GUI preempts servo"
        );
        assert_eq!(
            a.on_command(servo, ms(30)),
            Verdict::Ignore(DropReason::Preempted)
        );
        assert_eq!(a.on_command(sec, ms(40)), Verdict::Accept);
        assert_eq!(
            a.on_command(gui, ms(50)),
            Verdict::Ignore(DropReason::Preempted)
        );
        assert_eq!(
            a.on_command(stranger, ms(50)),
            Verdict::Ignore(DropReason::NoContract)
        );
        // Security goes silent: GUI regains control after the freshness window.
        assert_eq!(
            a.on_command(gui, ms(339)),
            Verdict::Ignore(DropReason::Preempted)
        );
        assert_eq!(a.on_command(gui, ms(340)), Verdict::Accept);
        // GUI releases: servo (still commanding) takes over at once.
        a.on_command(servo, ms(350));
        a.release(gui);
        assert_eq!(a.active(ms(351)), Some(servo));
        assert_eq!(a.drops().get(DropReason::NoContract), 1);
        assert_eq!(a.drops().get(DropReason::Preempted), 4);
        // Sync drops servo's contract.
        a.sync([(sec, "1.1".parse().unwrap())]);
        assert_eq!(
            a.on_command(servo, ms(360)),
            Verdict::Ignore(DropReason::NoContract)
        );
        assert_eq!(a.holders(), 1);
    }
}
