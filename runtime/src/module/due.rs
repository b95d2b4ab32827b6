//! When a module has something to do next, on its clock: the executor sleeps until then (wall
//! clock) or tells the lockstep simulator (simulated clock, [`crate::clock::lockstep`]).

use super::Context;

impl Context {
    /// The earliest clock time (ns) at which a timer fires, an input deadline is missed or the
    /// contract plane has something due; `u64::MAX` when nothing is scheduled. Inputs are not
    /// counted: they wake the module when they come.
    pub(super) fn next_due_ns(&self) -> u64 {
        let timers = self.timers.iter().map(|t| t.next_ns);
        // A deadline is missed once strictly more than `deadline_ns` passed.
        let deadlines = self
            .deadlines
            .iter()
            .filter(|d| !d.missed)
            .map(|d| d.last_ns.saturating_add(d.deadline_ns).saturating_add(1));
        let plane = self
            .plane
            .as_ref()
            .map(|p| u64::try_from(p.next_wake().as_nanos()).unwrap_or(u64::MAX));
        timers
            .chain(deadlines)
            .chain(plane)
            .min()
            .unwrap_or(u64::MAX)
    }
}
