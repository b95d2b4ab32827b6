//! The per-module contract agent: a deterministic state machine turning
//! incoming messages and the passage of time into outgoing messages.
//!
//! See the module documentation of [`crate::contract`] for the protocol rules.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use super::priority::MAX_DEPTH;
use super::service::{NeedSpec, ServiceError, ServiceOffer, validate_description};
use super::value::{FeedbackLog, Proposal, ResourceVec, Unavailable, ValueInputs, compute_value};
use super::wire::{
    Accept, BetterOffer, Cancel, ContractUpdate, Destination, DropCounters, DropReason, Envelope,
    MAX_LINEAGE, Message, Outgoing, Propose, Query, QueryKind, Reason, Refuse, Reject, Role,
    Selected, ValueReport,
};
use super::{ModuleId, Priority};

/// Protocol timing. All durations are on the caller's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// How long a client collects replies to a call before deciding (the
    /// `reply_by` deadline). A silent provider therefore delays nothing
    /// beyond this. Default 50 ms.
    pub reply_window: Duration,
    /// Period of a client's refresh query (with the selected provider, its
    /// value and the feedback) and of a provider's value report to each
    /// client. Default 200 ms.
    pub refresh_period: Duration,
    /// A provider that sent no value report, or a client that sent no
    /// refresh, for longer than this is considered gone. Default 1 s.
    pub peer_timeout: Duration,
    /// Delay before re-calling for an unmet optional need or an unmet
    /// objective of the Manager. Default 500 ms.
    pub retry_period: Duration,
    /// Period of the probes of an inactive module whose required need
    /// failed. Default 1 s.
    pub probe_period: Duration,
    /// A client does not take a better offer from the provider it left less
    /// than this long ago (no flapping between two providers whose values
    /// cross back and forth); it goes back at once only when the current
    /// provider is lost (dies, cancels, falls silent). Zero disables it.
    /// Default 1 s.
    pub switch_back_dwell: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            reply_window: Duration::from_millis(50),
            refresh_period: Duration::from_millis(200),
            peer_timeout: Duration::from_secs(1),
            retry_period: Duration::from_millis(500),
            probe_period: Duration::from_secs(1),
            switch_back_dwell: Duration::from_secs(1),
        }
    }
}

/// Static description of a module's agent.
#[derive(Debug, Clone, PartialEq)]
pub struct AgentConfig {
    /// The module.
    pub id: ModuleId,
    /// The Manager: always active, priority [`Priority::ROOT`], its needs
    /// are the mission's objectives in mission order (rank 1 first).
    pub manager: bool,
    /// Services provided.
    pub provides: Vec<ServiceOffer>,
    /// Services needed, each with a unique rank.
    pub needs: Vec<NeedSpec>,
    /// Timing.
    pub timing: Timing,
    /// A non-selected provider offers itself only if its value exceeds the
    /// selected one's by more than this; the client switches only then.
    /// Default 0.1.
    pub hysteresis: f64,
    /// Validity time `τ` of the feedback evaluations. Default 5 s.
    pub tau: Duration,
    /// Maximum number of client contracts held at once (then [`Reason::Overloaded`]).
    pub max_clients: usize,
}

impl AgentConfig {
    /// A module with no service, no need, default timing.
    pub fn new(id: ModuleId) -> Self {
        Self {
            id,
            manager: false,
            provides: Vec::new(),
            needs: Vec::new(),
            timing: Timing::default(),
            hysteresis: 0.1,
            tau: Duration::from_secs(5),
            max_clients: usize::MAX,
        }
    }

    /// The Manager with objectives `objectives` in mission order (ranks 1, 2, …).
    pub fn manager(id: ModuleId, objectives: &[&str]) -> Self {
        let mut c = Self::new(id);
        c.manager = true;
        c.needs = objectives
            .iter()
            .zip(1u16..)
            .map(|(s, rank)| NeedSpec::required(*s, rank))
            .collect();
        c
    }

    /// Adds a provided service.
    #[must_use]
    pub fn provide(mut self, offer: ServiceOffer) -> Self {
        self.provides.push(offer);
        self
    }

    /// Adds a need.
    #[must_use]
    pub fn need(mut self, need: NeedSpec) -> Self {
        self.needs.push(need);
        self
    }

    /// Replaces the timing.
    #[must_use]
    pub fn timing(mut self, timing: Timing) -> Self {
        self.timing = timing;
        self
    }
}

/// Invalid agent configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AgentError {
    /// The service description is invalid.
    #[error("module {id}: {source}")]
    Service {
        /// The module.
        id: ModuleId,
        /// What is wrong.
        source: ServiceError,
    },
    /// A numeric parameter is out of range.
    #[error("module {id}: parameter `{field}` {problem}")]
    Parameter {
        /// The module.
        id: ModuleId,
        /// The field.
        field: &'static str,
        /// What is wrong.
        problem: &'static str,
    },
}

/// Something the module code may want to react to (subscribe to a data
/// channel, start publishing, log…). Drained with [`ContractAgent::drain_events`].
#[derive(Debug, Clone, PartialEq)]
pub enum AgentEvent {
    /// The module now holds a contract (or is the Manager) and works at this priority.
    Activated {
        /// Its priority.
        priority: Priority,
    },
    /// The module's priority changed while active.
    PriorityChanged {
        /// The new priority.
        priority: Priority,
    },
    /// The module holds no contract any more.
    Deactivated,
    /// Need `need` is now served by `provider` on data channel `channel`.
    ProviderSelected {
        /// Need rank.
        need: u16,
        /// Provider.
        provider: ModuleId,
        /// Data channel.
        channel: String,
    },
    /// Need `need` lost its provider.
    ProviderLost {
        /// Need rank.
        need: u16,
        /// The former provider.
        provider: ModuleId,
    },
    /// A client contract started.
    ClientAdded {
        /// Client.
        client: ModuleId,
        /// Client's need rank.
        need: u16,
        /// Contract priority.
        priority: Priority,
    },
    /// A client contract ended.
    ClientRemoved {
        /// Client.
        client: ModuleId,
        /// Client's need rank.
        need: u16,
    },
}

/// A client contract as seen by its provider.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClientContractView<'a> {
    /// The client.
    pub client: ModuleId,
    /// The client's need rank.
    pub need: u16,
    /// Service provided.
    pub service: &'a str,
    /// Priority of the contract.
    pub priority: Priority,
}

/// A provider contract as seen by its client.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProviderContractView<'a> {
    /// Need rank.
    pub need: u16,
    /// Provider.
    pub provider: ModuleId,
    /// Data channel.
    pub channel: &'a str,
    /// Last value reported by the provider.
    pub value: f64,
    /// Priority of the contract.
    pub priority: Priority,
}

#[derive(Debug, Clone)]
struct ClientContract {
    service: String,
    priority: Priority,
    lineage: Vec<ModuleId>,
    last_heard: Duration,
}

#[derive(Debug, Clone)]
enum NeedState {
    Idle,
    Calling {
        query_id: u64,
        deadline: Duration,
        proposals: Vec<Proposal>,
        /// Providers that answered (proposal or refusal).
        replied: BTreeSet<ModuleId>,
    },
    Contracted {
        provider: ModuleId,
        channel: String,
        value: f64,
        last_heard: Duration,
        next_refresh: Duration,
    },
    Waiting {
        retry_at: Duration,
    },
}

#[derive(Debug, Clone)]
struct NeedSlot {
    spec: NeedSpec,
    state: NeedState,
    /// Proposals of the last call, best first: the next best on failure.
    candidates: Vec<Proposal>,
    /// Explicit evaluation of a given provider by the module code.
    evaluation: Option<(ModuleId, f64)>,
    /// The last attempt to serve this optional need failed.
    optional_unmet: bool,
    /// The provider of the latest contract (kept when it ends).
    last_provider: Option<ModuleId>,
    /// The provider this need last switched away from, and when.
    left: Option<(ModuleId, Duration)>,
    /// False while the module code switched this optional need off
    /// ([`ContractAgent::set_need_enabled`]): no call, no contract, no penalty.
    enabled: bool,
}

#[derive(Debug, Clone)]
struct ProbeRound {
    deadline: Duration,
    queries: BTreeMap<u16, u64>,
    answered: BTreeSet<u16>,
}

/// The contract agent of one module. See [`crate::contract`].
#[derive(Debug, Clone)]
pub struct ContractAgent {
    cfg: AgentConfig,
    inputs: ValueInputs,
    lacking_resources: bool,
    min_priority: Option<Priority>,
    feedback: FeedbackLog,
    clients: BTreeMap<(ModuleId, u16), ClientContract>,
    needs: Vec<NeedSlot>,
    next_query_id: u64,
    next_report: Duration,
    known_unmet: bool,
    next_probe: Duration,
    probe: Option<ProbeRound>,
    priority: Option<Priority>,
    lineage: Vec<ModuleId>,
    drops: DropCounters,
    events: Vec<AgentEvent>,
    /// Number of providers the transport knows for a service (early close of calls).
    expected: BTreeMap<String, usize>,
}

fn sorted_union(a: &[ModuleId], b: &[ModuleId]) -> Vec<ModuleId> {
    let mut s: BTreeSet<ModuleId> = a.iter().copied().collect();
    s.extend(b.iter().copied());
    s.into_iter().collect()
}

fn send(out: &mut Vec<Outgoing>, from: ModuleId, to: Destination, body: Message) {
    out.push(Outgoing {
        to,
        envelope: Envelope { from, body },
    });
}

impl ContractAgent {
    /// Builds an agent. Needs are kept sorted by rank.
    ///
    /// # Errors
    /// [`AgentError`] if the service description or a parameter is invalid.
    pub fn new(mut cfg: AgentConfig) -> Result<Self, AgentError> {
        validate_description(&cfg.provides, &cfg.needs)
            .map_err(|source| AgentError::Service { id: cfg.id, source })?;
        let id = cfg.id;
        let param = |field, problem| AgentError::Parameter { id, field, problem };
        if !(cfg.hysteresis.is_finite() && cfg.hysteresis >= 0.0) {
            return Err(param("hysteresis", "must be finite and >= 0"));
        }
        let t = cfg.timing;
        if t.reply_window.is_zero() || t.refresh_period.is_zero() || t.probe_period.is_zero() {
            return Err(param("timing", "periods must be > 0"));
        }
        if t.peer_timeout <= t.refresh_period {
            return Err(param("timing.peer_timeout", "must exceed refresh_period"));
        }
        if cfg.max_clients == 0 {
            return Err(param("max_clients", "must be >= 1"));
        }
        cfg.needs.sort_by_key(|n| n.rank);
        let needs = cfg
            .needs
            .iter()
            .map(|spec| NeedSlot {
                spec: spec.clone(),
                state: NeedState::Idle,
                candidates: Vec::new(),
                evaluation: None,
                optional_unmet: false,
                last_provider: None,
                left: None,
                enabled: true,
            })
            .collect();
        let (priority, lineage) = if cfg.manager {
            (Some(Priority::ROOT), vec![id])
        } else {
            (None, vec![id])
        };
        Ok(Self {
            feedback: FeedbackLog::new(cfg.tau),
            cfg,
            inputs: ValueInputs::default(),
            lacking_resources: false,
            min_priority: None,
            clients: BTreeMap::new(),
            needs,
            next_query_id: 1,
            next_report: Duration::ZERO,
            known_unmet: false,
            next_probe: Duration::ZERO,
            probe: None,
            priority,
            lineage,
            drops: DropCounters::default(),
            events: Vec::new(),
            expected: BTreeMap::new(),
        })
    }

    /// The transport knows that `n` modules listen for queries of `service`
    /// (e.g. the subscribers of its query channel). A call for that service
    /// then closes as soon as `n` distinct providers answered (proposal or
    /// refusal) instead of waiting for its whole reply window; a silent
    /// provider still delays the decision by the reply window at most.
    /// Without it (the default) every call waits for its deadline.
    ///
    /// A count that grows means a provider appeared: needs of that service waiting to
    /// retry call again at the next tick, and an inactive module whose required needs
    /// failed probes again, instead of waiting out their retry or probe period.
    pub fn set_provider_count(&mut self, service: &str, n: usize) {
        let old = match self.expected.get_mut(service) {
            Some(v) => std::mem::replace(v, n),
            None => {
                self.expected.insert(service.to_string(), n);
                0
            }
        };
        if n <= old {
            return;
        }
        let mut probe = false;
        for slot in &mut self.needs {
            if slot.spec.service != service {
                continue;
            }
            if let NeedState::Waiting { retry_at } = &mut slot.state {
                *retry_at = Duration::ZERO;
            }
            probe |= slot.spec.is_required();
        }
        if probe && self.known_unmet && self.probe.is_none() {
            self.next_probe = Duration::ZERO;
        }
    }

    /// How many providers of `service` the transport said listen now
    /// ([`Self::set_provider_count`]; `None`: never said). Attention uses it to offer only
    /// the behaviours some module could provide.
    pub fn provider_count(&self, service: &str) -> Option<usize> {
        self.expected.get(service).copied()
    }

    fn all_replied(&self, i: usize, replied: usize) -> bool {
        self.expected
            .get(&self.needs[i].spec.service)
            .is_some_and(|&n| n > 0 && replied >= n)
    }

    /// The module is stopping: ends every contract at once (clients are
    /// told [`Reason::Inactive`], providers [`Reason::NotNeeded`]) so the
    /// tree re-forms without waiting for timeouts. Call it last: the agent is
    /// inactive afterwards (the Manager would call its objectives again at
    /// the next tick).
    pub fn shutdown(&mut self, now: Duration) -> Vec<Outgoing> {
        let mut out = Vec::new();
        let keys: Vec<(ModuleId, u16)> = self.clients.keys().copied().collect();
        for key in keys {
            self.remove_client(key, Some(Reason::Inactive), &mut out);
        }
        self.deactivate_needs(&mut out);
        if !self.cfg.manager {
            self.refresh_identity(now, &mut out);
        }
        out
    }

    // ----- inputs from the module code, the RM and the watchdog -----

    /// Switches an optional need on or off while the module runs (adjustable autonomy: the
    /// Interface asks for "Follow wall" only while that order is in force). Off: a contract
    /// for it is cancelled ([`Reason::NotNeeded`]) and a call in progress dropped at the next
    /// tick, and the need is neither called nor counted unmet; on: it is called at the next
    /// tick like any idle need. Returns false (and changes nothing) for an unknown rank or a
    /// required need (a required need defines whether the module can work at all).
    pub fn set_need_enabled(&mut self, need: u16, enabled: bool) -> bool {
        let Some(i) = self.slot_index(need) else {
            return false;
        };
        let slot = &mut self.needs[i];
        if slot.spec.is_required() {
            return false;
        }
        if slot.enabled != enabled {
            slot.enabled = enabled;
            slot.optional_unmet = false;
            if enabled && matches!(slot.state, NeedState::Waiting { .. }) {
                slot.state = NeedState::Idle;
            }
        }
        true
    }

    /// False while optional need `need` is switched off ([`Self::set_need_enabled`]).
    pub fn need_enabled(&self, need: u16) -> bool {
        self.slot_index(need).is_none_or(|i| self.needs[i].enabled)
    }

    /// Sets the self-evaluated quality `Q` (clamped to `[-1, 1]`; NaN makes
    /// the module unable, as `f = 0`). Takes effect at the next tick.
    pub fn set_quality(&mut self, q: f64) {
        self.inputs.quality = q;
    }

    /// Sets the aptitude `f`. With `f = 0` the module refuses queries and, at
    /// the next tick, cancels its client contracts ([`Reason::Inactive`]).
    pub fn set_aptitude(&mut self, apt: bool) {
        self.inputs.aptitude = apt;
    }

    /// Sets `R_eff` and `C_R` (from the Resource Manager).
    pub fn set_resources(&mut self, r_eff: ResourceVec, cost: ResourceVec) {
        self.inputs.r_eff = r_eff;
        self.inputs.cost = cost;
    }

    /// The RM's most severe degraded mode, "serve nothing" (paper 5.3: as the lack of
    /// resources grows, fewer queries are answered, down to a global stop): every query is
    /// refused with [`Reason::NoResources`] and every client contract is cancelled with the
    /// same reason at the next tick, exactly as [`ContractAgent::set_min_priority`] does
    /// with a minimum priority that admits nothing. `false` ends it; the clients then win
    /// their contracts back by their retries.
    pub fn set_lacking_resources(&mut self, lacking: bool) {
        self.lacking_resources = lacking;
    }

    /// Degraded mode (paper, 5.3): client contracts not admitted by `min`
    /// (see [`Priority::admitted_by`]) are cancelled with
    /// [`Reason::Degraded`] at the next tick and new ones refused. `None` ends it.
    pub fn set_min_priority(&mut self, min: Option<Priority>) {
        self.min_priority = min;
    }

    /// The module code's evaluation `e ∈ [-1, 1]` of `provider` serving need
    /// `need`. Sent as feedback with each refresh while `provider` serves the
    /// need (and ignored after a switch). NaN clears it.
    pub fn evaluate_provider(&mut self, need: u16, provider: ModuleId, e: f64) {
        if let Some(slot) = self.needs.iter_mut().find(|s| s.spec.rank == need) {
            slot.evaluation = (!e.is_nan()).then(|| (provider, e.clamp(-1.0, 1.0)));
        }
    }

    /// The watchdog reports that module `id` died: its client contracts are
    /// dropped and the needs it served are given to the next best provider at once.
    pub fn module_died(&mut self, id: ModuleId, now: Duration) -> Vec<Outgoing> {
        let mut out = Vec::new();
        let gone: Vec<(ModuleId, u16)> = self
            .clients
            .keys()
            .filter(|(c, _)| *c == id)
            .copied()
            .collect();
        for key in gone {
            self.remove_client(key, None, &mut out);
        }
        for i in 0..self.needs.len() {
            self.needs[i].candidates.retain(|p| p.provider != id);
            if let NeedState::Calling { proposals, .. } = &mut self.needs[i].state {
                proposals.retain(|p| p.provider != id);
            }
            if matches!(self.needs[i].state, NeedState::Contracted { provider, .. } if provider == id)
            {
                self.lose_provider(i, now, &mut out);
            }
        }
        self.refresh_identity(now, &mut out);
        self.step(now, &mut out);
        out
    }

    /// Same as [`ContractAgent::module_died`] (the watchdog's name for it).
    pub fn provider_died(&mut self, id: ModuleId, now: Duration) -> Vec<Outgoing> {
        self.module_died(id, now)
    }

    // ----- observation -----

    /// The module.
    pub fn id(&self) -> ModuleId {
        self.cfg.id
    }

    /// The configuration.
    pub fn config(&self) -> &AgentConfig {
        &self.cfg
    }

    /// True when the module holds a client contract or is the Manager.
    pub fn is_active(&self) -> bool {
        self.cfg.manager || !self.clients.is_empty()
    }

    /// The module's priority: the most important of its client contracts
    /// ([`Priority::ROOT`] for the Manager, `None` when inactive).
    pub fn priority(&self) -> Option<Priority> {
        self.priority
    }

    /// The module and all its ancestors in the contract tree, sorted.
    pub fn lineage(&self) -> &[ModuleId] {
        &self.lineage
    }

    /// The priority of the contract for need `need`: `P(module).need`.
    pub fn need_priority(&self, need: u16) -> Option<Priority> {
        self.priority.and_then(|p| p.child(need).ok())
    }

    /// Current value `V` (eq. (3)), including the penalty of unmet optional needs.
    ///
    /// # Errors
    /// [`Unavailable`] when the module cannot propose.
    pub fn value(&self, now: Duration) -> Result<f64, Unavailable> {
        let penalty: f64 = self
            .needs
            .iter()
            .filter(|s| s.optional_unmet && s.enabled)
            .map(|s| match s.spec.requirement {
                super::service::Requirement::Optional { penalty } => penalty.clamp(0.0, 2.0),
                super::service::Requirement::Required => 0.0,
            })
            .sum();
        let mut inputs = self.inputs;
        inputs.quality -= penalty;
        compute_value(&inputs, &self.feedback, now)
    }

    /// The provider contract serving need `need`, if any.
    pub fn contract(&self, need: u16) -> Option<ProviderContractView<'_>> {
        let slot = self.needs.iter().find(|s| s.spec.rank == need)?;
        match &slot.state {
            NeedState::Contracted {
                provider,
                channel,
                value,
                ..
            } => Some(ProviderContractView {
                need,
                provider: *provider,
                channel,
                value: *value,
                priority: self.need_priority(need)?,
            }),
            _ => None,
        }
    }

    /// The provider serving need `need`, if any.
    pub fn provider(&self, need: u16) -> Option<ModuleId> {
        self.contract(need).map(|c| c.provider)
    }

    /// All provider contracts, by need rank.
    pub fn provider_contracts(&self) -> impl Iterator<Item = ProviderContractView<'_>> + '_ {
        self.needs.iter().filter_map(|s| self.contract(s.spec.rank))
    }

    /// All client contracts, ordered by (client, need).
    pub fn client_contracts(&self) -> impl Iterator<Item = ClientContractView<'_>> + '_ {
        self.clients
            .iter()
            .map(|(&(client, need), c)| ClientContractView {
                client,
                need,
                service: &c.service,
                priority: c.priority,
            })
    }

    /// The needs, sorted by rank.
    pub fn needs(&self) -> impl Iterator<Item = &NeedSpec> + '_ {
        self.needs.iter().map(|s| &s.spec)
    }

    /// True while a call for one of the needs is collecting proposals.
    pub fn calling(&self) -> bool {
        self.needs
            .iter()
            .any(|n| matches!(n.state, NeedState::Calling { .. }))
    }

    /// True when a required need failed and the module refuses queries until
    /// a probe finds providers again.
    pub fn needs_unmet(&self) -> bool {
        self.known_unmet
    }

    /// Messages this agent dropped, by reason.
    pub fn drops(&self) -> &DropCounters {
        &self.drops
    }

    /// Takes the events produced since the last call.
    pub fn drain_events(&mut self) -> Vec<AgentEvent> {
        std::mem::take(&mut self.events)
    }

    // ----- the state machine -----

    /// Periodic work: deadlines, refreshes, value reports, timeouts, probes.
    /// Call it often (e.g. every 10 ms); it only acts on what is due.
    pub fn tick(&mut self, now: Duration) -> Vec<Outgoing> {
        let mut out = Vec::new();
        self.step(now, &mut out);
        out
    }

    /// Handles one incoming message, then does what is due at `now`.
    pub fn handle(&mut self, env: &Envelope, now: Duration) -> Vec<Outgoing> {
        self.handle_all(std::slice::from_ref(env), now)
    }

    /// Handles every message of a batch (all that arrived since the last wake-up), then
    /// does what is due at `now` once. A transport that was descheduled past a reply
    /// deadline thus still counts the replies that arrived before it ran again.
    pub fn handle_all(&mut self, envs: &[Envelope], now: Duration) -> Vec<Outgoing> {
        let mut out = Vec::new();
        for env in envs {
            self.receive(env, now, &mut out);
        }
        self.step(now, &mut out);
        out
    }

    fn receive(&mut self, env: &Envelope, now: Duration, out: &mut Vec<Outgoing>) {
        let from = env.from;
        if from == self.cfg.id {
            self.drops.record(DropReason::FromSelf);
            return;
        }
        match &env.body {
            Message::Query(q) => self.on_query(from, q, now, out),
            Message::Propose(p) => self.on_propose(from, p),
            Message::Refuse(r) => self.on_refuse(from, r),
            Message::Accept(a) => self.on_accept(from, a, now, out),
            Message::Reject(_) => {}
            Message::Cancel(c) => self.on_cancel(from, c, now, out),
            Message::BetterOffer(b) => self.on_better_offer(from, b, now, out),
            Message::Feedback(f) => match self.clients.get_mut(&(from, f.need)) {
                Some(c) => {
                    c.last_heard = now;
                    self.feedback.record(f64::from(f.evaluation), now);
                }
                None => self.drops.record(DropReason::UnknownContract),
            },
            Message::Value(v) => self.on_value(from, v, now, out),
            Message::Update(u) => self.on_update(from, u, now, out),
        }
    }

    fn offer_for(&self, service: &str) -> Option<&ServiceOffer> {
        self.cfg.provides.iter().find(|o| o.service == service)
    }

    /// Can this module serve `client` for `service` at `priority` with the
    /// client's `lineage`? Returns the value to propose.
    fn can_serve(
        &self,
        client: ModuleId,
        service: &str,
        priority: Option<Priority>,
        lineage: &[ModuleId],
        existing: bool,
        now: Duration,
    ) -> Result<f64, Reason> {
        if self.offer_for(service).is_none() {
            return Err(Reason::NotProvided);
        }
        let value = self.value(now).map_err(|_| Reason::Inactive)?;
        if client == self.cfg.id || lineage.binary_search(&self.cfg.id).is_ok() {
            return Err(Reason::Cycle);
        }
        if self.known_unmet {
            return Err(Reason::NeedsUnmet);
        }
        if self.lacking_resources {
            return Err(Reason::NoResources);
        }
        if let (Some(min), Some(p)) = (self.min_priority, priority)
            && !p.admitted_by(&min)
        {
            return Err(Reason::Degraded);
        }
        if let Some(p) = priority
            && p.len() >= MAX_DEPTH
            && !self.needs.is_empty()
        {
            return Err(Reason::TooDeep);
        }
        if sorted_union(&self.lineage, lineage).len() > MAX_LINEAGE {
            return Err(Reason::TooDeep);
        }
        if !existing && self.clients.len() >= self.cfg.max_clients {
            return Err(Reason::Overloaded);
        }
        Ok(value)
    }

    fn channel_for(&self, service: &str) -> String {
        self.offer_for(service)
            .map(|o| o.channel_for(self.cfg.id))
            .unwrap_or_default()
    }

    fn on_query(&mut self, from: ModuleId, q: &Query, now: Duration, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        let key = (from, q.need);
        if q.kind == QueryKind::Refresh {
            let selected_is_me = q.selected.is_some_and(|s| s.provider == id);
            if selected_is_me {
                match self.clients.get_mut(&key) {
                    Some(c) => {
                        c.last_heard = now;
                        if let Some(e) = q.feedback {
                            self.feedback.record(f64::from(e), now);
                        }
                    }
                    None => {
                        // The client believes in a contract we do not hold.
                        self.drops.record(DropReason::UnknownContract);
                        let body = Message::Cancel(Cancel {
                            need: q.need,
                            reason: Reason::Timeout,
                            sender: Role::Provider,
                        });
                        send(out, id, Destination::Module(from), body);
                    }
                }
                return;
            }
            if self.clients.contains_key(&key) {
                // The client moved on without us hearing its cancel.
                self.remove_client(key, None, out);
                self.refresh_identity(now, out);
            }
            let Some(sel) = q.selected else { return };
            if let Ok(v) = self.can_serve(from, &q.service, q.priority, &q.lineage, false, now)
                && v > sel.value + self.cfg.hysteresis
            {
                let body = Message::BetterOffer(BetterOffer {
                    need: q.need,
                    value: v,
                    channel: self.channel_for(&q.service),
                });
                send(out, id, Destination::Module(from), body);
            }
            return;
        }
        if self.offer_for(&q.service).is_none() {
            self.drops.record(DropReason::NotProvided);
        }
        let existing = self.clients.contains_key(&key);
        let body = match self.can_serve(from, &q.service, q.priority, &q.lineage, existing, now) {
            Ok(value) => Message::Propose(Propose {
                query_id: q.query_id,
                need: q.need,
                value,
                channel: self.channel_for(&q.service),
            }),
            Err(reason) => Message::Refuse(Refuse {
                query_id: q.query_id,
                need: q.need,
                reason,
            }),
        };
        send(out, id, Destination::Module(from), body);
    }

    fn slot_index(&self, need: u16) -> Option<usize> {
        self.needs.iter().position(|s| s.spec.rank == need)
    }

    fn on_propose(&mut self, from: ModuleId, p: &Propose) {
        if let Some(round) = &mut self.probe
            && round.queries.get(&p.need) == Some(&p.query_id)
        {
            round.answered.insert(p.need);
            return;
        }
        let Some(i) = self.slot_index(p.need) else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        match &mut self.needs[i].state {
            NeedState::Calling {
                query_id,
                proposals,
                replied,
                ..
            } if *query_id == p.query_id => {
                replied.insert(from);
                // Duplicates are resolved at the deadline (the last one counts).
                proposals.push(Proposal {
                    provider: from,
                    value: p.value,
                    channel: p.channel.clone(),
                });
            }
            _ => self.drops.record(DropReason::StaleReply),
        }
    }

    fn on_refuse(&mut self, from: ModuleId, r: &Refuse) {
        if self
            .probe
            .as_ref()
            .is_some_and(|round| round.queries.get(&r.need) == Some(&r.query_id))
        {
            return;
        }
        let Some(i) = self.slot_index(r.need) else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        match &mut self.needs[i].state {
            NeedState::Calling {
                query_id,
                proposals,
                replied,
                ..
            } if *query_id == r.query_id => {
                replied.insert(from);
                proposals.retain(|x| x.provider != from);
            }
            _ => self.drops.record(DropReason::StaleReply),
        }
        self.needs[i].candidates.retain(|x| x.provider != from);
    }

    fn on_accept(&mut self, from: ModuleId, a: &Accept, now: Duration, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        let key = (from, a.need);
        let existing = self.clients.contains_key(&key);
        match self.can_serve(
            from,
            &a.service,
            Some(a.priority),
            &a.lineage,
            existing,
            now,
        ) {
            Ok(value) => {
                let was_active = self.is_active();
                self.clients.insert(
                    key,
                    ClientContract {
                        service: a.service.clone(),
                        priority: a.priority,
                        lineage: a.lineage.clone(),
                        last_heard: now,
                    },
                );
                if !existing {
                    self.events.push(AgentEvent::ClientAdded {
                        client: from,
                        need: a.need,
                        priority: a.priority,
                    });
                }
                // Immediate value report: confirms the contract.
                let body = Message::Value(ValueReport {
                    need: a.need,
                    value,
                });
                send(out, id, Destination::Module(from), body);
                if !was_active {
                    self.next_probe = now;
                    self.probe = None;
                }
                self.refresh_identity(now, out);
            }
            Err(reason) => {
                if existing {
                    self.remove_client(key, Some(reason), out);
                    self.refresh_identity(now, out);
                } else {
                    let body = Message::Cancel(Cancel {
                        need: a.need,
                        reason,
                        sender: Role::Provider,
                    });
                    send(out, id, Destination::Module(from), body);
                }
            }
        }
    }

    fn on_cancel(&mut self, from: ModuleId, c: &Cancel, now: Duration, out: &mut Vec<Outgoing>) {
        match c.sender {
            Role::Client => {
                let key = (from, c.need);
                if self.clients.contains_key(&key) {
                    self.remove_client(key, None, out);
                    self.refresh_identity(now, out);
                } else {
                    self.drops.record(DropReason::UnknownContract);
                }
            }
            Role::Provider => {
                let Some(i) = self.slot_index(c.need) else {
                    self.drops.record(DropReason::UnknownContract);
                    return;
                };
                self.needs[i].candidates.retain(|p| p.provider != from);
                match self.needs[i].state {
                    NeedState::Contracted { provider, .. } if provider == from => {
                        self.lose_provider(i, now, out);
                    }
                    _ => self.drops.record(DropReason::UnknownContract),
                }
            }
        }
    }

    fn on_better_offer(
        &mut self,
        from: ModuleId,
        b: &BetterOffer,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let Some(i) = self.slot_index(b.need) else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        let hysteresis = self.cfg.hysteresis;
        let NeedState::Contracted {
            provider, value, ..
        } = self.needs[i].state
        else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        if provider == from || b.value <= value + hysteresis {
            self.drops.record(DropReason::StaleReply);
            return;
        }
        let dwell = self.cfg.timing.switch_back_dwell;
        if self.needs[i]
            .left
            .is_some_and(|(left, at)| left == from && now < at + dwell)
        {
            // Just left it: stay at least the dwell time (the offer comes again with the
            // next refresh).
            return;
        }
        let id = self.cfg.id;
        let body = Message::Cancel(Cancel {
            need: b.need,
            reason: Reason::Replaced,
            sender: Role::Client,
        });
        send(out, id, Destination::Module(provider), body);
        self.events.push(AgentEvent::ProviderLost {
            need: b.need,
            provider,
        });
        let slot = &mut self.needs[i];
        for c in &mut slot.candidates {
            if c.provider == provider {
                c.value = value;
            }
        }
        slot.candidates.retain(|c| c.provider != from);
        slot.candidates.push(Proposal {
            provider: from,
            value: b.value,
            channel: b.channel.clone(),
        });
        sort_best_first(&mut slot.candidates);
        let chosen = Proposal {
            provider: from,
            value: b.value,
            channel: b.channel.clone(),
        };
        self.contract_with(i, chosen, now, out);
    }

    fn on_value(
        &mut self,
        from: ModuleId,
        v: &ValueReport,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let Some(i) = self.slot_index(v.need) else {
            self.drops.record(DropReason::UnknownContract);
            return;
        };
        if let NeedState::Contracted {
            provider,
            value,
            last_heard,
            ..
        } = &mut self.needs[i].state
            && *provider == from
        {
            *value = v.value;
            *last_heard = now;
            return;
        }
        // The provider believes in a contract we do not hold.
        self.drops.record(DropReason::UnknownContract);
        let body = Message::Cancel(Cancel {
            need: v.need,
            reason: Reason::NotNeeded,
            sender: Role::Client,
        });
        send(out, self.cfg.id, Destination::Module(from), body);
    }

    fn on_update(
        &mut self,
        from: ModuleId,
        u: &ContractUpdate,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let key = (from, u.need);
        let Some(service) = self.clients.get(&key).map(|c| c.service.clone()) else {
            self.drops.record(DropReason::UnknownContract);
            return;
        };
        match self.can_serve(from, &service, Some(u.priority), &u.lineage, true, now) {
            Ok(_) => {
                if let Some(c) = self.clients.get_mut(&key) {
                    c.priority = u.priority;
                    c.lineage = u.lineage.clone();
                    c.last_heard = now;
                }
            }
            Err(reason) => self.remove_client(key, Some(reason), out),
        }
        self.refresh_identity(now, out);
    }

    /// Removes a client contract; with `Some(reason)` tells the client.
    fn remove_client(
        &mut self,
        key: (ModuleId, u16),
        reason: Option<Reason>,
        out: &mut Vec<Outgoing>,
    ) {
        if self.clients.remove(&key).is_none() {
            return;
        }
        self.events.push(AgentEvent::ClientRemoved {
            client: key.0,
            need: key.1,
        });
        if let Some(reason) = reason {
            let body = Message::Cancel(Cancel {
                need: key.1,
                reason,
                sender: Role::Provider,
            });
            send(out, self.cfg.id, Destination::Module(key.0), body);
        }
    }

    /// Recomputes the priority and lineage from the client contracts and
    /// propagates changes to the providers; deactivates when no contract is left.
    fn refresh_identity(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        let (priority, lineage) = if self.cfg.manager {
            (Some(Priority::ROOT), vec![id])
        } else {
            let p = Priority::most_important(self.clients.values().map(|c| c.priority));
            let mut set: BTreeSet<ModuleId> = BTreeSet::new();
            set.insert(id);
            for c in self.clients.values() {
                set.extend(c.lineage.iter().copied());
            }
            (p, set.into_iter().collect())
        };
        let was = self.priority;
        let lineage_changed = lineage != self.lineage;
        self.priority = priority;
        self.lineage = lineage;
        match (was, priority) {
            (None, Some(p)) => self.events.push(AgentEvent::Activated { priority: p }),
            (Some(_), None) => {
                self.events.push(AgentEvent::Deactivated);
                self.deactivate_needs(out);
                return;
            }
            (Some(a), Some(b)) if a != b => self
                .events
                .push(AgentEvent::PriorityChanged { priority: b }),
            _ => {}
        }
        if (was != priority || lineage_changed)
            && let Some(p) = priority
        {
            for i in 0..self.needs.len() {
                let rank = self.needs[i].spec.rank;
                if let NeedState::Contracted { provider, .. } = self.needs[i].state {
                    match p.child(rank) {
                        Ok(np) => {
                            let body = Message::Update(ContractUpdate {
                                need: rank,
                                priority: np,
                                lineage: self.lineage.clone(),
                            });
                            send(out, id, Destination::Module(provider), body);
                        }
                        Err(_) => self.lose_provider(i, now, out),
                    }
                }
            }
        }
    }

    /// The module became inactive: cancel its own provider contracts.
    fn deactivate_needs(&mut self, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        for slot in &mut self.needs {
            if let NeedState::Contracted { provider, .. } = slot.state {
                let body = Message::Cancel(Cancel {
                    need: slot.spec.rank,
                    reason: Reason::NotNeeded,
                    sender: Role::Client,
                });
                send(out, id, Destination::Module(provider), body);
                self.events.push(AgentEvent::ProviderLost {
                    need: slot.spec.rank,
                    provider,
                });
            }
            slot.state = NeedState::Idle;
            slot.candidates.clear();
        }
    }

    /// Need `i` is switched off: end its contract or call.
    fn switch_off(&mut self, i: usize, out: &mut Vec<Outgoing>) {
        let slot = &mut self.needs[i];
        match std::mem::replace(&mut slot.state, NeedState::Idle) {
            NeedState::Contracted { provider, .. } => {
                let body = Message::Cancel(Cancel {
                    need: slot.spec.rank,
                    reason: Reason::NotNeeded,
                    sender: Role::Client,
                });
                self.events.push(AgentEvent::ProviderLost {
                    need: slot.spec.rank,
                    provider,
                });
                send(out, self.cfg.id, Destination::Module(provider), body);
            }
            NeedState::Calling { .. } | NeedState::Waiting { .. } | NeedState::Idle => {}
        }
        self.needs[i].candidates.clear();
        self.needs[i].optional_unmet = false;
    }

    /// Need `i` lost its provider (dead, cancelled, silent): next best at once.
    fn lose_provider(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        if let NeedState::Contracted { provider, .. } = self.needs[i].state {
            self.needs[i].candidates.retain(|c| c.provider != provider);
            self.events.push(AgentEvent::ProviderLost {
                need: self.needs[i].spec.rank,
                provider,
            });
        }
        self.needs[i].state = NeedState::Idle;
        if self.priority.is_none() || !self.needs[i].enabled {
            return;
        }
        match self.needs[i].candidates.first().cloned() {
            Some(next) => self.contract_with(i, next, now, out),
            None => self.start_call(i, now, out),
        }
    }

    fn contract_with(&mut self, i: usize, p: Proposal, now: Duration, out: &mut Vec<Outgoing>) {
        let rank = self.needs[i].spec.rank;
        let priority = match self.need_priority(rank) {
            Some(p) if self.needs[i].enabled => p,
            _ => {
                self.needs[i].state = NeedState::Idle;
                return;
            }
        };
        let id = self.cfg.id;
        let body = Message::Accept(Accept {
            need: rank,
            service: self.needs[i].spec.service.clone(),
            priority,
            lineage: self.lineage.clone(),
        });
        send(out, id, Destination::Module(p.provider), body);
        self.events.push(AgentEvent::ProviderSelected {
            need: rank,
            provider: p.provider,
            channel: p.channel.clone(),
        });
        let slot = &mut self.needs[i];
        slot.optional_unmet = false;
        if let Some(prev) = slot.last_provider
            && prev != p.provider
        {
            slot.left = Some((prev, now));
        }
        slot.last_provider = Some(p.provider);
        slot.state = NeedState::Contracted {
            provider: p.provider,
            channel: p.channel,
            value: p.value,
            last_heard: now,
            next_refresh: now + self.cfg.timing.refresh_period,
        };
    }

    fn fresh_query_id(&mut self) -> u64 {
        let q = self.next_query_id;
        self.next_query_id = self.next_query_id.wrapping_add(1);
        q
    }

    fn start_call(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        let rank = self.needs[i].spec.rank;
        let Some(priority) = self.need_priority(rank) else {
            // Too deep (or inactive): the need cannot be contracted.
            self.need_unmet(i, now, out);
            return;
        };
        let query_id = self.fresh_query_id();
        let deadline = now + self.cfg.timing.reply_window;
        let body = Message::Query(Query {
            query_id,
            need: rank,
            service: self.needs[i].spec.service.clone(),
            kind: QueryKind::Call,
            priority: Some(priority),
            selected: None,
            feedback: None,
            reply_by_ns: duration_ns(deadline),
            lineage: self.lineage.clone(),
        });
        let to = Destination::Providers(self.needs[i].spec.service.clone());
        send(out, self.cfg.id, to, body);
        self.needs[i].state = NeedState::Calling {
            query_id,
            deadline,
            proposals: Vec::new(),
            replied: BTreeSet::new(),
        };
    }

    fn close_call(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        let NeedState::Calling {
            query_id,
            proposals,
            ..
        } = std::mem::replace(&mut self.needs[i].state, NeedState::Idle)
        else {
            return;
        };
        // Keep the last proposal of each provider.
        let mut seen = BTreeSet::new();
        let mut proposals: Vec<Proposal> = proposals
            .into_iter()
            .rev()
            .filter(|p| p.value.is_finite() && seen.insert(p.provider))
            .collect();
        sort_best_first(&mut proposals);
        let Some(best) = proposals.first().cloned() else {
            self.needs[i].candidates.clear();
            self.need_unmet(i, now, out);
            return;
        };
        let rank = self.needs[i].spec.rank;
        for other in proposals.iter().skip(1) {
            let body = Message::Reject(Reject {
                query_id,
                need: rank,
            });
            send(out, self.cfg.id, Destination::Module(other.provider), body);
        }
        self.needs[i].candidates = proposals;
        self.contract_with(i, best, now, out);
    }

    fn need_unmet(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        let retry_at = now + self.cfg.timing.retry_period;
        if !self.needs[i].spec.is_required() {
            self.needs[i].optional_unmet = true;
            self.needs[i].state = NeedState::Waiting { retry_at };
            return;
        }
        if self.cfg.manager {
            self.needs[i].state = NeedState::Waiting { retry_at };
            return;
        }
        // A required need cannot be met: the module cannot work. Cancel upward.
        self.needs[i].state = NeedState::Idle;
        self.known_unmet = true;
        self.next_probe = now + self.cfg.timing.probe_period;
        self.probe = None;
        let keys: Vec<(ModuleId, u16)> = self.clients.keys().copied().collect();
        for key in keys {
            self.remove_client(key, Some(Reason::NeedsUnmet), out);
        }
        self.refresh_identity(now, out);
    }

    fn outgoing_feedback(&self, i: usize, provider: ModuleId, now: Duration) -> Option<f32> {
        match self.needs[i].evaluation {
            Some((p, e)) if p == provider => Some(e as f32),
            _ => self.feedback.mean(now).map(|m| m as f32),
        }
    }

    fn step(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        let t = self.cfg.timing;
        self.feedback.prune(now);

        // Provider side: silent clients, degraded mode (serve nothing included), lost
        // aptitude.
        let unavailable = self.value(now).is_err();
        let min = self.min_priority;
        let serve_nothing = self.lacking_resources;
        let drop: Vec<((ModuleId, u16), Option<Reason>)> = self
            .clients
            .iter()
            .filter_map(|(k, c)| {
                if now.saturating_sub(c.last_heard) > t.peer_timeout {
                    Some((*k, Some(Reason::Timeout)))
                } else if unavailable {
                    Some((*k, Some(Reason::Inactive)))
                } else if serve_nothing {
                    Some((*k, Some(Reason::NoResources)))
                } else if min.is_some_and(|m| !c.priority.admitted_by(&m)) {
                    Some((*k, Some(Reason::Degraded)))
                } else {
                    None
                }
            })
            .collect();
        if !drop.is_empty() {
            for (k, r) in drop {
                self.remove_client(k, r, out);
            }
            self.refresh_identity(now, out);
        }

        // Provider side: periodic value reports (heartbeats).
        if now >= self.next_report {
            self.next_report = now + t.refresh_period;
            if let Ok(value) = self.value(now) {
                for &(client, need) in self.clients.keys() {
                    let body = Message::Value(ValueReport { need, value });
                    send(out, id, Destination::Module(client), body);
                }
            }
        }

        // Client side.
        if self.priority.is_some() {
            for i in 0..self.needs.len() {
                if !self.needs[i].enabled {
                    self.switch_off(i, out);
                    continue;
                }
                match &self.needs[i].state {
                    NeedState::Idle => self.start_call(i, now, out),
                    NeedState::Calling {
                        deadline, replied, ..
                    } if now >= *deadline || self.all_replied(i, replied.len()) => {
                        self.close_call(i, now, out)
                    }
                    NeedState::Waiting { retry_at } if now >= *retry_at => {
                        self.start_call(i, now, out)
                    }
                    &NeedState::Contracted {
                        provider,
                        value,
                        last_heard,
                        next_refresh,
                        ..
                    } => {
                        if now.saturating_sub(last_heard) > t.peer_timeout {
                            self.lose_provider(i, now, out);
                        } else if now >= next_refresh {
                            self.send_refresh(i, provider, value, now, out);
                        }
                    }
                    _ => {}
                }
                if self.priority.is_none() {
                    // A required need failed and the module deactivated.
                    break;
                }
            }
        }

        // Inactive module whose required need failed: probe.
        if self.known_unmet && !self.is_active() {
            self.step_probe(now, out);
        }
    }

    fn send_refresh(
        &mut self,
        i: usize,
        provider: ModuleId,
        value: f64,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let rank = self.needs[i].spec.rank;
        let feedback = self.outgoing_feedback(i, provider, now);
        let query_id = self.fresh_query_id();
        let t = self.cfg.timing;
        let body = Message::Query(Query {
            query_id,
            need: rank,
            service: self.needs[i].spec.service.clone(),
            kind: QueryKind::Refresh,
            priority: self.need_priority(rank),
            selected: Some(Selected { provider, value }),
            feedback,
            reply_by_ns: duration_ns(now + t.reply_window),
            lineage: self.lineage.clone(),
        });
        let to = Destination::Providers(self.needs[i].spec.service.clone());
        send(out, self.cfg.id, to, body);
        if let NeedState::Contracted { next_refresh, .. } = &mut self.needs[i].state {
            *next_refresh = now + t.refresh_period;
        }
    }

    fn step_probe(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let t = self.cfg.timing;
        if let Some(round) = &self.probe {
            if now < round.deadline {
                return;
            }
            let all = round.queries.keys().all(|n| round.answered.contains(n));
            self.probe = None;
            if all {
                self.known_unmet = false;
            } else {
                self.next_probe = now + t.probe_period;
            }
            return;
        }
        if now < self.next_probe {
            return;
        }
        let mut queries = BTreeMap::new();
        for i in 0..self.needs.len() {
            if !self.needs[i].spec.is_required() {
                continue;
            }
            let query_id = self.fresh_query_id();
            let rank = self.needs[i].spec.rank;
            queries.insert(rank, query_id);
            let body = Message::Query(Query {
                query_id,
                need: rank,
                service: self.needs[i].spec.service.clone(),
                kind: QueryKind::Probe,
                priority: None,
                selected: None,
                feedback: None,
                reply_by_ns: duration_ns(now + t.reply_window),
                lineage: self.lineage.clone(),
            });
            let to = Destination::Providers(self.needs[i].spec.service.clone());
            send(out, self.cfg.id, to, body);
        }
        self.probe = Some(ProbeRound {
            deadline: now + t.reply_window,
            queries,
            answered: BTreeSet::new(),
        });
    }
}

fn sort_best_first(v: &mut [Proposal]) {
    v.sort_by(|a, b| {
        b.value
            .total_cmp(&a.value)
            .then_with(|| a.provider.cmp(&b.provider))
    });
}

/// Nanoseconds of a duration, saturating at `u64::MAX`.
pub fn duration_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}
