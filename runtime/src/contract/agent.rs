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

mod calls;
mod messages;

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
    /// Explicit evaluation of a given provider by the module code, and whether it was sent.
    evaluation: Option<(ModuleId, f64, bool)>,
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
    /// `need`. Sent once, as feedback with the next refresh while `provider`
    /// serves the need (one judgement is one `E_n` of eq. 3: re-sent with every
    /// refresh, a mild −0.1 piled up to −2.7 and took "Track beacon" from a
    /// tracker that was merely biased; refreshes after it carry no evaluation
    /// until the next one); ignored after a switch, and forgotten when a new
    /// contract is made. NaN clears it.
    pub fn evaluate_provider(&mut self, need: u16, provider: ModuleId, e: f64) {
        if let Some(slot) = self.needs.iter_mut().find(|s| s.spec.rank == need) {
            slot.evaluation = (!e.is_nan()).then(|| (provider, e.clamp(-1.0, 1.0), false));
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
