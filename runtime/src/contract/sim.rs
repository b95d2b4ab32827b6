//! In-process deterministic harness: many [`ContractAgent`]s exchanging
//! encoded messages through a time-ordered queue, on a fake clock.
//!
//! Every message goes through [`encode`] and [`decode`], so the harness also
//! exercises the wire format and its size limit. Delivery is FIFO per
//! destination with a fixed latency; all agents are ticked every `tick`, in
//! module-id order, or (with `tick` zero) each agent only at its own
//! [`ContractAgent::next_deadline`], as the module executor does. Identical
//! inputs give identical runs.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use super::agent::ContractAgent;
use super::wire::{Destination, DropCounters, Outgoing, decode, encode};
use super::{ModuleId, Priority};

/// Harness parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SimConfig {
    /// Delay of every message.
    pub latency: Duration,
    /// Period at which every agent is ticked; zero: each agent is ticked only at
    /// its [`ContractAgent::next_deadline`] (and handles messages as they come).
    pub tick: Duration,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            latency: Duration::from_millis(1),
            tick: Duration::from_millis(10),
        }
    }
}

/// A client → provider edge of the contract tree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Edge {
    /// Client.
    pub client: ModuleId,
    /// Client's need rank.
    pub need: u16,
    /// Provider.
    pub provider: ModuleId,
    /// Priority of the contract, as the client sees it.
    pub priority: Priority,
}

/// The harness.
#[derive(Debug, Clone)]
pub struct Sim {
    cfg: SimConfig,
    now: Duration,
    next_tick: Duration,
    agents: BTreeMap<ModuleId, ContractAgent>,
    dead: BTreeSet<ModuleId>,
    queue: BTreeMap<(Duration, u64), (ModuleId, Vec<u8>)>,
    seq: u64,
    drops: DropCounters,
    delivered: u64,
    ticks: u64,
    stuck: u64,
}

impl Sim {
    /// An empty harness at time 0.
    pub fn new(cfg: SimConfig) -> Self {
        Self {
            cfg,
            now: Duration::ZERO,
            next_tick: Duration::ZERO,
            agents: BTreeMap::new(),
            dead: BTreeSet::new(),
            queue: BTreeMap::new(),
            seq: 0,
            drops: DropCounters::default(),
            delivered: 0,
            ticks: 0,
            stuck: 0,
        }
    }

    /// Adds (or restarts) a module.
    pub fn add(&mut self, agent: ContractAgent) {
        self.dead.remove(&agent.id());
        self.agents.insert(agent.id(), agent);
    }

    /// Current time.
    pub fn now(&self) -> Duration {
        self.now
    }

    /// A module's agent.
    pub fn agent(&self, id: ModuleId) -> Option<&ContractAgent> {
        self.agents.get(&id)
    }

    /// All live agents, by id.
    pub fn agents(&self) -> impl Iterator<Item = &ContractAgent> + '_ {
        self.agents.values()
    }

    /// Runs `f` on a module's agent at the current time and sends what it returns.
    pub fn with<F>(&mut self, id: ModuleId, f: F)
    where
        F: FnOnce(&mut ContractAgent, Duration) -> Vec<Outgoing>,
    {
        let now = self.now;
        if let Some(a) = self.agents.get_mut(&id) {
            let out = f(a, now);
            self.route(id, out);
        }
    }

    /// Kills a module. With `watchdog`, every other module is told at once
    /// ([`ContractAgent::module_died`]); otherwise peers find out by timeout.
    pub fn kill(&mut self, id: ModuleId, watchdog: bool) {
        if self.agents.remove(&id).is_none() {
            return;
        }
        self.dead.insert(id);
        if watchdog {
            let ids: Vec<ModuleId> = self.agents.keys().copied().collect();
            for other in ids {
                self.with(other, |a, now| a.module_died(id, now));
            }
        }
    }

    /// Transport-level drops (encoding, decoding, dead destination).
    pub fn drops(&self) -> &DropCounters {
        &self.drops
    }

    /// Agent ticks so far (one per agent ticked).
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// Deadline-driven mode: times an agent, just ticked, still said it had something
    /// due at once (it would spin; the harness moved it on by a millisecond).
    pub fn stuck(&self) -> u64 {
        self.stuck
    }

    /// Messages delivered so far.
    pub fn delivered(&self) -> u64 {
        self.delivered
    }

    fn push(&mut self, to: ModuleId, bytes: Vec<u8>) {
        self.seq += 1;
        self.queue
            .insert((self.now + self.cfg.latency, self.seq), (to, bytes));
    }

    fn route(&mut self, from: ModuleId, out: Vec<Outgoing>) {
        for o in out {
            let bytes = match encode(&o.envelope) {
                Ok(b) => b,
                Err(e) => {
                    self.drops.record_error(&e);
                    continue;
                }
            };
            match &o.to {
                Destination::Module(to) => self.push(*to, bytes),
                Destination::Providers(service) => {
                    let targets: Vec<ModuleId> = self
                        .agents
                        .values()
                        .filter(|a| {
                            a.id() != from
                                && a.config().provides.iter().any(|p| &p.service == service)
                        })
                        .map(ContractAgent::id)
                        .collect();
                    for t in targets {
                        self.push(t, bytes.clone());
                    }
                }
            }
        }
    }

    /// Runs until `until` (inclusive), delivering messages and ticking agents.
    pub fn run_until(&mut self, until: Duration) {
        if self.cfg.tick.is_zero() {
            self.run_by_deadlines(until);
            return;
        }
        loop {
            let next_msg = self.queue.keys().next().map(|&(t, _)| t);
            let msg_first = next_msg.is_some_and(|t| t <= self.next_tick);
            let at = if msg_first {
                next_msg.unwrap_or(self.next_tick)
            } else {
                self.next_tick
            };
            if !self.reach(at, until) {
                break;
            }
            if msg_first {
                self.deliver_first();
            } else {
                let ids: Vec<ModuleId> = self.agents.keys().copied().collect();
                for id in ids {
                    self.ticks += 1;
                    self.with(id, |a, now| a.tick(now));
                }
                self.next_tick += self.cfg.tick;
            }
        }
        self.now = self.now.max(until);
    }

    /// Moves the clock to `at`; false if `at` is past `until` (the run ends first).
    fn reach(&mut self, at: Duration, until: Duration) -> bool {
        if at > until {
            return false;
        }
        self.now = self.now.max(at);
        true
    }

    /// Delivers the first queued message.
    fn deliver_first(&mut self) {
        if let Some((_, (to, bytes))) = self.queue.pop_first() {
            self.deliver(to, &bytes);
        }
    }

    /// Deadline-driven: every agent runs when a message comes and at its next deadline.
    fn run_by_deadlines(&mut self, until: Duration) {
        // When each agent is due (never earlier than now).
        let due = |a: &ContractAgent, now: Duration| a.next_deadline().map(|d| d.max(now));
        loop {
            let next_msg = self.queue.keys().next().map(|&(t, _)| t);
            let next_agent = self
                .agents
                .values()
                .filter_map(|a| due(a, self.now).map(|d| (d, a.id())))
                .min();
            let msg_first = match (next_msg, next_agent) {
                (Some(m), Some((d, _))) => m <= d,
                (Some(_), None) => true,
                _ => false,
            };
            let at = match (msg_first, next_msg, next_agent) {
                (true, Some(m), _) => m,
                (false, _, Some((d, _))) => d,
                _ => break,
            };
            if !self.reach(at, until) {
                break;
            }
            if msg_first {
                self.deliver_first();
            } else if let Some((_, id)) = next_agent {
                self.ticks += 1;
                self.with(id, |a, now| a.tick(now));
                if self
                    .agents
                    .get(&id)
                    .and_then(|a| a.next_deadline())
                    .is_some_and(|d| d <= self.now)
                {
                    // It would be ticked again at once, for nothing: move on.
                    self.stuck += 1;
                    self.now += Duration::from_millis(1);
                }
            }
        }
        self.now = self.now.max(until);
    }

    /// Runs for `d`.
    pub fn run_for(&mut self, d: Duration) {
        self.run_until(self.now + d);
    }

    fn deliver(&mut self, to: ModuleId, bytes: &[u8]) {
        if !self.agents.contains_key(&to) {
            self.drops.record(super::DropReason::UnknownContract);
            return;
        }
        match decode(bytes) {
            Ok(env) => {
                self.delivered += 1;
                self.with(to, |a, now| a.handle(&env, now));
            }
            Err(e) => self.drops.record_error(&e),
        }
    }

    /// The contract tree as the clients see it.
    pub fn edges(&self) -> Vec<Edge> {
        let mut v = Vec::new();
        for a in self.agents.values() {
            for c in a.provider_contracts() {
                v.push(Edge {
                    client: a.id(),
                    need: c.need,
                    provider: c.provider,
                    priority: c.priority,
                });
            }
        }
        v
    }

    /// Edges on which client and provider agree (same contract, same priority).
    pub fn agreed_edges(&self) -> Vec<Edge> {
        self.edges()
            .into_iter()
            .filter(|e| {
                self.agents.get(&e.provider).is_some_and(|p| {
                    p.client_contracts().any(|c| {
                        c.client == e.client && c.need == e.need && c.priority == e.priority
                    })
                })
            })
            .collect()
    }

    /// The provider serving `client`'s need `need`, if any.
    pub fn provider_of(&self, client: ModuleId, need: u16) -> Option<ModuleId> {
        self.agents.get(&client).and_then(|a| a.provider(need))
    }
}
