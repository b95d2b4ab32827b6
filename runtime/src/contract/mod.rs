//! Contract-Net protocol logic (transport-free).
//!
//! This module decides which modules work for whom (HNG paper, sections 4.2,
//! 5.5, 5.6 and 5.8). It is pure, deterministic logic: no thread, no clock,
//! no I/O. Time is passed in as `now: Duration` on a clock shared by all
//! modules; messages go in and out as plain enums ([`Envelope`],
//! [`Outgoing`]), encoded with [`encode`] / [`decode`] by the transport.
//!
//! ```
//! use std::time::Duration;
//! use hng_runtime::contract::{AgentConfig, ContractAgent, ModuleId, NeedSpec, ServiceOffer};
//!
//! let cfg = AgentConfig::new(ModuleId(4))
//!     .provide(ServiceOffer::new("Localization", "Position"))
//!     .need(NeedSpec::required("Odometry", 1))
//!     .need(NeedSpec::required("LIDAR data", 2));
//! let mut slam = ContractAgent::new(cfg)?;
//! slam.set_quality(0.8);
//! // Transport loop: for each received envelope `env`
//! //     for o in slam.handle(&env, now) { send(o) }
//! // and every few milliseconds
//! let out = slam.tick(Duration::from_millis(10));
//! assert!(out.is_empty(), "inactive: no contract yet, nothing to ask");
//! # Ok::<(), hng_runtime::contract::AgentError>(())
//! ```
//!
//! # Pieces
//!
//! - [`Priority`]: hierarchical priorities (5.5).
//! - [`compute_value`], [`FeedbackLog`], [`ResourceVec`]: the value function, eq. (3).
//! - [`ServiceOffer`], [`NeedSpec`]: what a module provides and needs (4.2, Table 1).
//! - [`Message`] and friends, [`encode`], [`decode`], [`DropCounters`]: the wire.
//! - [`ContractAgent`]: one state machine per module (`handle`, `tick`).
//! - [`CommandArbiter`]: which client a driver obeys (5.6).
//! - [`select_best`]: deciding one query among N proposals (`decide_N` bench).
//! - [`sim`]: an in-process harness running many agents on a fake clock.
//!
//! # Rules decided here
//!
//! ## Priorities (paper 5.5)
//!
//! - A priority is a sequence of integers `>= 1` (`1.2.5`), at most
//!   [`MAX_DEPTH`] long. Comparison is lexicographic and **smaller is more
//!   important**: `1.2.5` beats `1.3.2`, `1.1` beats `2.1`.
//! - **A prefix beats its extensions**: `1.2` beats `1.2.1`. A module is thus
//!   more important than the contracts it derives for its own needs, and an
//!   ancestor commanding a driver beats its descendants.
//! - The Manager's priority is [`Priority::ROOT`] (no component, displayed
//!   `root`); its objectives, in mission order, are its needs of rank 1, 2, …
//!   so they get priorities `1`, `2`, … (the paper's 4.1 numbering is
//!   reversed: here objective 1 is the most important).
//! - Contract for need of rank `i` of module `m`: `P(r_i) = P(m).i` where
//!   `P(m)` = the most important priority among `m`'s client contracts. A
//!   module never chooses its own priority: it derives only from the contract
//!   tree, and changes travel down with [`Message::Update`].
//! - Display `1.2.5`, parse with [`str::parse`]; errors say which component
//!   is wrong ([`PriorityError`]).
//! - Degraded mode admission ([`Priority::admitted_by`]): a contract is
//!   cut to the depth of the RM's minimum priority and compared, so the
//!   minimum `2` keeps the whole subtrees of objectives 1 and 2.
//!
//! ## Value (paper eq. (3))
//!
//! `V = Q − R_eff·C_R + Σ E_n·exp(−(t−T_n)/τ)`, with the dot product over
//! CPU, memory and communication. `Q` is clamped to `[-1, 1]`; NaN `Q`,
//! `f = 0`, or non-finite resources make the module unable to propose
//! ([`Unavailable`]), and an active module then cancels its client contracts
//! ([`Reason::Inactive`]). Negative resource components are clamped to 0.
//! Evaluations `E` are clamped to `[-1, 1]` (NaN rejected), kept in a
//! [`FeedbackLog`] that forgets weights below 1e-4 and keeps at most 1024.
//! Each unmet optional need lowers `Q` by its declared penalty.
//!
//! ## Protocol
//!
//! - **Activation.** A module is active when it holds a client contract or is
//!   the Manager. Only active modules query their needs (recursive
//!   establishment down the tree); an inactive module proposes on the
//!   strength of its own `f`, `Q` (optimistic about its needs).
//! - **Call.** A client broadcasts a [`Query`] (`Call`) to the providers of
//!   the service, with the contract priority, its lineage (itself and all its
//!   ancestors) and a `reply_by` deadline `now + reply_window`. Replies
//!   arriving after that are ignored, so a silent provider stalls nothing.
//!   At the deadline the client picks the greatest `V` ([`select_best`]: ties
//!   to the smaller module id), sends [`Message::Accept`] to it and
//!   [`Message::Reject`] to the others, and keeps all proposals, best first,
//!   as the candidates for a replacement.
//! - **Accept.** The provider re-checks it can serve (it may answer
//!   [`Message::Cancel`] with a reason), records the contract and answers at
//!   once with a [`Message::Value`] report.
//! - **Unmet need.** No proposal for a required need: the module cancels all
//!   its client contracts ([`Reason::NeedsUnmet`]), deactivates (cancelling
//!   its own provider contracts) and refuses queries with `NeedsUnmet` until a
//!   non-binding `Probe` of its required needs, every `probe_period`, gets a
//!   proposal for each. Optional needs and the Manager's objectives are
//!   simply re-called every `retry_period`.
//! - **Re-negotiation (5.8).** Every `refresh_period` each provider sends its
//!   `V` to each client ([`Message::Value`], also its heartbeat) and each
//!   client re-broadcasts a `Refresh` query carrying the selected provider,
//!   its last value and the client's feedback. The selected provider takes it
//!   as the client's heartbeat; a non-selected provider whose `V` exceeds the
//!   selected value by more than `hysteresis` sends [`Message::BetterOffer`];
//!   the client re-checks against the same threshold, cancels the old
//!   contract ([`Reason::Replaced`]) and accepts the new provider.
//! - **Replacement.** A provider that dies ([`ContractAgent::module_died`]),
//!   cancels, refuses an accept, or sends no value for `peer_timeout` is
//!   replaced at once by the best remaining candidate (a new call when none
//!   is left). A client silent for `peer_timeout` loses its contract.
//! - **Feedback (4.2).** The feedback a client sends its provider with each
//!   refresh is the module code's own evaluation of that provider
//!   ([`ContractAgent::evaluate_provider`]) if it gave one, otherwise the
//!   weighted mean of the feedback the module itself received from its
//!   clients: evaluations flow down the tree. A stand-alone
//!   [`Message::Feedback`] is accepted too.
//! - **Cycles.** Queries, accepts and updates carry the client's lineage; a
//!   module refuses ([`Reason::Cycle`]) a client whose lineage contains it,
//!   and cancels a client contract when a lineage update shows a cycle
//!   formed by a race. The contract graph is therefore a forest rooted at the
//!   Manager once messages have settled.
//! - **Degraded mode (5.3).** [`ContractAgent::set_min_priority`]: client
//!   contracts not admitted are cancelled with [`Reason::Degraded`] and new
//!   ones refused; a module whose contracts are all shed stops (deactivates).
//! - **Ghosts.** A refresh naming a provider that holds no such contract gets
//!   a `Cancel` back; a value report from a provider that is not selected
//!   gets a `Cancel` back; a refresh naming another provider ends the stale
//!   contract. Lost messages therefore heal within a refresh period.
//! - **Drivers (5.6).** A driver may hold several client contracts; the
//!   [`CommandArbiter`] obeys the live client with the most important
//!   priority (see its docs).
//!
//! ## Wire
//!
//! 3-byte header `HC` + version [`WIRE_VERSION`], then postcard; at most
//! [`MAX_MESSAGE_LEN`] bytes; lineages at most [`MAX_LINEAGE`] ids. [`decode`]
//! checks size, header, body, trailing bytes and ranges and never panics.

pub mod agent;
pub mod arbiter;
pub mod priority;
pub mod service;
pub mod sim;
pub mod value;
pub mod wire;

#[cfg(test)]
#[allow(clippy::unwrap_used)] // Tests may unwrap.
mod tests;

use std::fmt;

use serde::{Deserialize, Serialize};

pub use agent::{
    AgentConfig, AgentError, AgentEvent, ClientContractView, ContractAgent, ProviderContractView,
    Timing,
};
pub use arbiter::{CommandArbiter, Verdict};
pub use priority::{MAX_DEPTH, Priority, PriorityError, dotted};
pub use service::{NeedSpec, Requirement, ServiceError, ServiceOffer};
pub use value::{
    FeedbackLog, Proposal, ResourceVec, Unavailable, ValueInputs, best_of, compute_value,
    select_best,
};
pub use wire::{
    Accept, BetterOffer, Cancel, ContractUpdate, Destination, DropCounters, DropReason, Envelope,
    Feedback, MAX_LINEAGE, MAX_MESSAGE_LEN, Message, Outgoing, Propose, Query, QueryKind, Reason,
    Refuse, Reject, Role, Selected, ValueReport, WIRE_VERSION, WireError, decode, encode,
};

/// Identifier of a module (small, `Copy`, cheap to compare).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
)]
pub struct ModuleId(pub u32);

impl fmt::Display for ModuleId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "m{}", self.0)
    }
}
