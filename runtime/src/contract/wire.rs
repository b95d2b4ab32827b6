//! Wire messages of the contract protocol, their encoding, and drop counters.
//!
//! Encoding: 3 header bytes `b'H', b'C', WIRE_VERSION`, then the postcard
//! encoding of an [`Envelope`]. A whole encoded message is at most
//! [`MAX_MESSAGE_LEN`] bytes. [`decode`] never panics: malformed, truncated,
//! trailing, oversized, wrong-magic, wrong-version or out-of-range input gives
//! a [`WireError`].

use serde::{Deserialize, Serialize};

use super::service::{MAX_CHANNEL_LEN, MAX_SERVICE_LEN, check_name};
use super::{ModuleId, Priority};

/// Magic bytes starting every encoded contract message.
pub const MAGIC: [u8; 2] = *b"HC";
/// Version of the encoding written by this code; other versions are rejected.
pub const WIRE_VERSION: u8 = 1;
/// Maximum size of an encoded message, header included.
pub const MAX_MESSAGE_LEN: usize = 1024;
/// Maximum number of module ids in a lineage (cycle detection set).
pub const MAX_LINEAGE: usize = 96;

/// Why a query is refused or a contract cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum Reason {
    /// The provider's aptitude is 0 or its quality is invalid.
    Inactive,
    /// Degraded mode: the contract is less important than the minimum priority.
    Degraded,
    /// The provider reports a lack of resources.
    NoResources,
    /// The provider already serves as many clients as it accepts.
    Overloaded,
    /// The provider does not provide this service.
    NotProvided,
    /// A required need of the provider cannot be met.
    NeedsUnmet,
    /// Accepting would close a cycle in the contract tree.
    Cycle,
    /// The contract tree would be deeper than [`super::MAX_DEPTH`] or the
    /// lineage longer than [`MAX_LINEAGE`].
    TooDeep,
    /// The client switched to a better provider.
    Replaced,
    /// The client no longer needs the service (it became inactive).
    NotNeeded,
    /// The peer stopped reporting.
    Timeout,
}

/// Kind of a [`Query`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum QueryKind {
    /// Call for proposals: providers answer [`Message::Propose`] or [`Message::Refuse`].
    Call,
    /// Periodic re-query once a provider is selected (paper, 5.6): carries the
    /// selected provider and its value; the selected one takes it as a
    /// heartbeat (and the feedback), others answer [`Message::BetterOffer`]
    /// only when they beat the selected value by the hysteresis.
    Refresh,
    /// Non-binding survey by an inactive module whose required need failed:
    /// answered like a call, never followed by an accept.
    Probe,
}

/// The currently selected provider of a need and its last known value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Selected {
    /// Selected provider.
    pub provider: ModuleId,
    /// Its last reported value.
    pub value: f64,
}

/// Query / call for proposals. The requester is [`Envelope::from`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Query {
    /// Identifier, unique per requester; replies echo it.
    pub query_id: u64,
    /// Rank of the requester's need.
    pub need: u16,
    /// Requested service.
    pub service: String,
    /// Call, refresh or probe.
    pub kind: QueryKind,
    /// Priority the contract would have (`None` for a probe by an inactive module).
    pub priority: Option<Priority>,
    /// Currently selected provider and its value (refresh).
    pub selected: Option<Selected>,
    /// The requester's evaluation of the selected provider, in `[-1, 1]`.
    pub feedback: Option<f32>,
    /// Replies arriving after this time (ns on the shared clock) are ignored.
    pub reply_by_ns: u64,
    /// The requester and all its ancestors in the contract tree (sorted).
    pub lineage: Vec<ModuleId>,
}

/// A proposal answering a query.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Propose {
    /// The query answered.
    pub query_id: u64,
    /// Rank of the requester's need.
    pub need: u16,
    /// Value `V` of the provider.
    pub value: f64,
    /// Data channel the data will come on.
    pub channel: String,
}

/// A refusal answering a query.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Refuse {
    /// The query answered.
    pub query_id: u64,
    /// Rank of the requester's need.
    pub need: u16,
    /// Why.
    pub reason: Reason,
}

/// The client selects the provider: the contract is established.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Accept {
    /// Rank of the client's need.
    pub need: u16,
    /// Service contracted.
    pub service: String,
    /// Priority of the contract.
    pub priority: Priority,
    /// The client and its ancestors (sorted).
    pub lineage: Vec<ModuleId>,
}

/// The client did not select this proposal (informational).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Reject {
    /// The query.
    pub query_id: u64,
    /// Rank of the client's need.
    pub need: u16,
}

/// Which side of a contract sends a message that both sides may send.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Role {
    /// The sender is the client of the contract.
    Client,
    /// The sender is the provider of the contract.
    Provider,
}

/// End of the contract `(client, need)`, sent by either party. After an
/// [`Accept`] the provider answers `Cancel` (role `Provider`) to refuse it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Cancel {
    /// Rank of the client's need.
    pub need: u16,
    /// Why.
    pub reason: Reason,
    /// Which side cancels.
    pub sender: Role,
}

/// A non-selected provider now beats the selected one by more than the hysteresis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BetterOffer {
    /// Rank of the client's need.
    pub need: u16,
    /// Value of the offering provider.
    pub value: f64,
    /// Data channel the data would come on.
    pub channel: String,
}

/// Evaluation of the provider by the client.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Feedback {
    /// Rank of the client's need.
    pub need: u16,
    /// Evaluation `E ∈ [-1, 1]`.
    pub evaluation: f32,
}

/// Periodic value republication of a provider to one client (also a heartbeat).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValueReport {
    /// Rank of the client's need.
    pub need: u16,
    /// Current value `V`.
    pub value: f64,
}

/// The client's priority or lineage changed: the contract follows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContractUpdate {
    /// Rank of the client's need.
    pub need: u16,
    /// New priority of the contract.
    pub priority: Priority,
    /// New lineage of the client (sorted).
    pub lineage: Vec<ModuleId>,
}

/// Every contract-protocol message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Message {
    /// Client → providers of a service.
    Query(Query),
    /// Provider → client.
    Propose(Propose),
    /// Provider → client.
    Refuse(Refuse),
    /// Client → provider.
    Accept(Accept),
    /// Client → provider.
    Reject(Reject),
    /// Either way.
    Cancel(Cancel),
    /// Non-selected provider → client.
    BetterOffer(BetterOffer),
    /// Client → provider.
    Feedback(Feedback),
    /// Provider → client.
    Value(ValueReport),
    /// Client → provider.
    Update(ContractUpdate),
}

/// A message and its sender.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// Sending module.
    pub from: ModuleId,
    /// The message.
    pub body: Message,
}

/// Where an outgoing message goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Destination {
    /// One module.
    Module(ModuleId),
    /// Every module providing this service (the service's query channel).
    Providers(String),
}

/// A message to send.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    /// Destination.
    pub to: Destination,
    /// What to send.
    pub envelope: Envelope,
}

/// Errors of [`encode`] / [`decode`] and message validation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    /// Fewer bytes than the header.
    #[error("truncated contract message: {len} bytes, the header alone is 3")]
    Truncated {
        /// Length received.
        len: usize,
    },
    /// Longer than [`MAX_MESSAGE_LEN`].
    #[error("contract message of {len} bytes exceeds the maximum {MAX_MESSAGE_LEN}")]
    Oversized {
        /// Length.
        len: usize,
    },
    /// Wrong magic bytes: not a contract message.
    #[error("not a contract message: magic {found:02x?}, expected {MAGIC:02x?}")]
    BadMagic {
        /// Bytes found.
        found: [u8; 2],
    },
    /// Another encoding version.
    #[error("contract message version {found}, this build speaks version {WIRE_VERSION}")]
    WrongVersion {
        /// Version found.
        found: u8,
    },
    /// Postcard could not decode the body.
    #[error("malformed contract message body: {0}")]
    Malformed(String),
    /// Bytes left after the body.
    #[error("{extra} trailing bytes after the contract message body")]
    Trailing {
        /// How many.
        extra: usize,
    },
    /// Decoded but a field is out of range.
    #[error("invalid contract message: field `{field}`: {problem}")]
    Invalid {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        problem: String,
    },
    /// Postcard could not encode (should not happen).
    #[error("cannot encode contract message: {0}")]
    Encode(String),
}

fn invalid(field: &'static str, problem: impl Into<String>) -> WireError {
    WireError::Invalid {
        field,
        problem: problem.into(),
    }
}

fn check_value(field: &'static str, v: f64) -> Result<(), WireError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(field, format!("{v} is not finite")))
    }
}

fn check_lineage(l: &[ModuleId]) -> Result<(), WireError> {
    if l.len() > MAX_LINEAGE {
        return Err(invalid(
            "lineage",
            format!("{} ids, maximum {MAX_LINEAGE}", l.len()),
        ));
    }
    if l.windows(2).any(|w| w[0] >= w[1]) {
        return Err(invalid("lineage", "not strictly sorted"));
    }
    Ok(())
}

fn check_service(s: &str) -> Result<(), WireError> {
    check_name("service name", s, MAX_SERVICE_LEN).map_err(|e| invalid("service", e.to_string()))
}

fn check_channel(s: &str) -> Result<(), WireError> {
    if s.len() > MAX_CHANNEL_LEN {
        return Err(invalid(
            "channel",
            format!("{} bytes, maximum {MAX_CHANNEL_LEN}", s.len()),
        ));
    }
    Ok(())
}

fn check_need(n: u16) -> Result<(), WireError> {
    if n == 0 {
        Err(invalid("need", "rank 0 (ranks start at 1)"))
    } else {
        Ok(())
    }
}

impl Envelope {
    /// Checks ranges the type system does not: finite values, evaluations in
    /// `[-1, 1]`, name lengths, sorted bounded lineages, ranks >= 1.
    ///
    /// # Errors
    /// [`WireError::Invalid`] naming the field.
    pub fn validate(&self) -> Result<(), WireError> {
        match &self.body {
            Message::Query(q) => {
                check_need(q.need)?;
                check_service(&q.service)?;
                check_lineage(&q.lineage)?;
                if let Some(s) = q.selected {
                    check_value("selected.value", s.value)?;
                }
                if let Some(f) = q.feedback
                    && !(-1.0..=1.0).contains(&f)
                {
                    return Err(invalid("feedback", format!("{f} is outside [-1, 1]")));
                }
                Ok(())
            }
            Message::Propose(p) => {
                check_need(p.need)?;
                check_value("value", p.value)?;
                check_channel(&p.channel)
            }
            Message::BetterOffer(b) => {
                check_need(b.need)?;
                check_value("value", b.value)?;
                check_channel(&b.channel)
            }
            Message::Refuse(r) => check_need(r.need),
            Message::Accept(a) => {
                check_need(a.need)?;
                check_service(&a.service)?;
                check_lineage(&a.lineage)
            }
            Message::Reject(r) => check_need(r.need),
            Message::Cancel(c) => check_need(c.need),
            Message::Feedback(f) => {
                check_need(f.need)?;
                if (-1.0..=1.0).contains(&f.evaluation) {
                    Ok(())
                } else {
                    Err(invalid(
                        "evaluation",
                        format!("{} is outside [-1, 1]", f.evaluation),
                    ))
                }
            }
            Message::Value(v) => {
                check_need(v.need)?;
                check_value("value", v.value)
            }
            Message::Update(u) => {
                check_need(u.need)?;
                check_lineage(&u.lineage)
            }
        }
    }
}

/// Encodes a message (header + postcard).
///
/// # Errors
/// [`WireError::Invalid`] if the message does not validate,
/// [`WireError::Oversized`] if it would exceed [`MAX_MESSAGE_LEN`].
pub fn encode(env: &Envelope) -> Result<Vec<u8>, WireError> {
    env.validate()?;
    let out = postcard::to_extend(env, vec![MAGIC[0], MAGIC[1], WIRE_VERSION])
        .map_err(|e| WireError::Encode(e.to_string()))?;
    if out.len() > MAX_MESSAGE_LEN {
        return Err(WireError::Oversized { len: out.len() });
    }
    Ok(out)
}

/// Decodes and validates a message.
///
/// # Errors
/// Any [`WireError`] but `Encode`; never panics.
pub fn decode(bytes: &[u8]) -> Result<Envelope, WireError> {
    if bytes.len() > MAX_MESSAGE_LEN {
        return Err(WireError::Oversized { len: bytes.len() });
    }
    let [m0, m1, version, body @ ..] = bytes else {
        return Err(WireError::Truncated { len: bytes.len() });
    };
    if [*m0, *m1] != MAGIC {
        return Err(WireError::BadMagic { found: [*m0, *m1] });
    }
    if *version != WIRE_VERSION {
        return Err(WireError::WrongVersion { found: *version });
    }
    let (env, rest): (Envelope, &[u8]) =
        postcard::take_from_bytes(body).map_err(|e| WireError::Malformed(e.to_string()))?;
    if !rest.is_empty() {
        return Err(WireError::Trailing { extra: rest.len() });
    }
    env.validate()?;
    Ok(env)
}

/// Why an incoming message was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum DropReason {
    /// Decode: truncated.
    Truncated,
    /// Decode: too long.
    Oversized,
    /// Decode: wrong magic.
    BadMagic,
    /// Decode: other version.
    WrongVersion,
    /// Decode: malformed body or trailing bytes.
    Malformed,
    /// Decoded but a field is out of range.
    Invalid,
    /// A reply to a query that is closed or unknown.
    StaleReply,
    /// A message about a contract that does not exist.
    UnknownContract,
    /// A query for a service this module does not provide.
    NotProvided,
    /// A message from this module to itself.
    FromSelf,
    /// A command from a publisher holding no contract with the driver.
    NoContract,
    /// A command from a contract holder while a more important one has control.
    Preempted,
    /// Encoding failed on the sending side.
    EncodeFailed,
    /// The envelope's sender is not the module that published it (transport check).
    Spoofed,
}

impl DropReason {
    const ALL: [DropReason; 14] = [
        DropReason::Truncated,
        DropReason::Oversized,
        DropReason::BadMagic,
        DropReason::WrongVersion,
        DropReason::Malformed,
        DropReason::Invalid,
        DropReason::StaleReply,
        DropReason::UnknownContract,
        DropReason::NotProvided,
        DropReason::FromSelf,
        DropReason::NoContract,
        DropReason::Preempted,
        DropReason::EncodeFailed,
        DropReason::Spoofed,
    ];

    /// The drop reason counting a decode/encode error.
    pub fn of(err: &WireError) -> DropReason {
        match err {
            WireError::Truncated { .. } => DropReason::Truncated,
            WireError::Oversized { .. } => DropReason::Oversized,
            WireError::BadMagic { .. } => DropReason::BadMagic,
            WireError::WrongVersion { .. } => DropReason::WrongVersion,
            WireError::Malformed(_) | WireError::Trailing { .. } => DropReason::Malformed,
            WireError::Invalid { .. } => DropReason::Invalid,
            WireError::Encode(_) => DropReason::EncodeFailed,
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// Counters of dropped messages, by reason.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DropCounters {
    counts: [u64; DropReason::ALL.len()],
}

impl DropCounters {
    /// Counts one drop.
    pub fn record(&mut self, reason: DropReason) {
        let c = &mut self.counts[reason.index()];
        *c = c.saturating_add(1);
    }

    /// Counts one decode/encode error.
    pub fn record_error(&mut self, err: &WireError) {
        self.record(DropReason::of(err));
    }

    /// Drops counted for `reason`.
    pub fn get(&self, reason: DropReason) -> u64 {
        self.counts[reason.index()]
    }

    /// All drops.
    pub fn total(&self) -> u64 {
        self.counts.iter().fold(0u64, |a, &c| a.saturating_add(c))
    }

    /// Non-zero counters, in a fixed order.
    pub fn iter(&self) -> impl Iterator<Item = (DropReason, u64)> + '_ {
        DropReason::ALL
            .iter()
            .map(|&r| (r, self.get(r)))
            .filter(|&(_, c)| c > 0)
    }

    /// Adds another set of counters.
    pub fn merge(&mut self, other: &DropCounters) {
        for (a, b) in self.counts.iter_mut().zip(other.counts.iter()) {
            *a = a.saturating_add(*b);
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // Tests may unwrap.
mod tests {
    use super::*;

    fn sample_query() -> Envelope {
        Envelope {
            from: ModuleId(3),
            body: Message::Query(Query {
                query_id: 42,
                need: 2,
                service: "Localization".into(),
                kind: QueryKind::Refresh,
                priority: Some("2.2.1.2".parse().unwrap()),
                selected: Some(Selected {
                    provider: ModuleId(9),
                    value: 0.7,
                }),
                feedback: Some(-0.25),
                reply_by_ns: 1_000_000_000,
                lineage: vec![ModuleId(0), ModuleId(1), ModuleId(3)],
            }),
        }
    }

    fn all_messages() -> Vec<Envelope> {
        let from = ModuleId(1);
        let p: Priority = "1.2".parse().unwrap();
        [
            sample_query().body,
            Message::Propose(Propose {
                query_id: 1,
                need: 1,
                value: -0.5,
                channel: "9/Localization".into(),
            }),
            Message::Refuse(Refuse {
                query_id: 1,
                need: 1,
                reason: Reason::Degraded,
            }),
            Message::Accept(Accept {
                need: 1,
                service: "Robot control".into(),
                priority: p,
                lineage: vec![ModuleId(0)],
            }),
            Message::Reject(Reject {
                query_id: 1,
                need: 1,
            }),
            Message::Cancel(Cancel {
                need: 3,
                reason: Reason::Replaced,
                sender: Role::Client,
            }),
            Message::BetterOffer(BetterOffer {
                need: 1,
                value: 0.9,
                channel: "c".into(),
            }),
            Message::Feedback(Feedback {
                need: 1,
                evaluation: 1.0,
            }),
            Message::Value(ValueReport {
                need: 1,
                value: 0.1,
            }),
            Message::Update(ContractUpdate {
                need: 1,
                priority: p,
                lineage: vec![],
            }),
        ]
        .into_iter()
        .map(|body| Envelope { from, body })
        .collect()
    }

    #[test]
    fn contract_wire_roundtrip_all_messages() {
        for env in all_messages() {
            let bytes = encode(&env).unwrap();
            assert!(bytes.len() <= MAX_MESSAGE_LEN);
            assert_eq!(decode(&bytes).unwrap(), env);
        }
    }

    #[test]
    fn contract_wire_rejects_bad_input() {
        let bytes = encode(&sample_query()).unwrap();
        assert_eq!(decode(&[]), Err(WireError::Truncated { len: 0 }));
        assert_eq!(decode(&bytes[..2]), Err(WireError::Truncated { len: 2 }));
        for cut in 3..bytes.len() {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut v = bytes.clone();
        v[2] = 2;
        assert_eq!(decode(&v), Err(WireError::WrongVersion { found: 2 }));
        let mut v = bytes.clone();
        v[0] = b'X';
        assert!(matches!(decode(&v), Err(WireError::BadMagic { .. })));
        let mut v = bytes.clone();
        v.push(0);
        assert_eq!(decode(&v), Err(WireError::Trailing { extra: 1 }));
        let big = vec![0u8; MAX_MESSAGE_LEN + 1];
        assert!(matches!(decode(&big), Err(WireError::Oversized { .. })));
        // Unknown enum variant index.
        assert!(matches!(
            decode(&[b'H', b'C', WIRE_VERSION, 1, 200]),
            Err(WireError::Malformed(_))
        ));
    }

    #[test]
    fn contract_wire_validation() {
        let mut env = all_messages()[1].clone();
        if let Message::Propose(p) = &mut env.body {
            p.value = f64::NAN;
        }
        assert!(matches!(
            encode(&env),
            Err(WireError::Invalid { field: "value", .. })
        ));
        let env = Envelope {
            from: ModuleId(1),
            body: Message::Feedback(Feedback {
                need: 1,
                evaluation: 1.5,
            }),
        };
        assert!(matches!(
            encode(&env),
            Err(WireError::Invalid {
                field: "evaluation",
                ..
            })
        ));
        let mut env = sample_query();
        if let Message::Query(q) = &mut env.body {
            q.lineage = vec![ModuleId(3), ModuleId(1)];
        }
        assert!(encode(&env).is_err());
        // A priority with a 0 component on the wire is rejected.
        assert!(postcard::from_bytes::<Priority>(&[1, 0]).is_err());
        assert!(postcard::from_bytes::<Priority>(&[1, 1]).is_ok());
        let too_deep: Vec<u16> = vec![1; super::super::MAX_DEPTH + 1];
        let bytes = postcard::to_allocvec(&too_deep).unwrap();
        assert!(postcard::from_bytes::<Priority>(&bytes).is_err());
    }

    #[test]
    fn contract_wire_max_size_fits() {
        let deep: Priority = vec!["65535"; super::super::MAX_DEPTH]
            .join(".")
            .parse()
            .unwrap();
        let env = Envelope {
            from: ModuleId(u32::MAX),
            body: Message::Query(Query {
                query_id: u64::MAX,
                need: u16::MAX,
                service: "s".repeat(MAX_SERVICE_LEN),
                kind: QueryKind::Refresh,
                priority: Some(deep),
                selected: Some(Selected {
                    provider: ModuleId(u32::MAX),
                    value: 1.0,
                }),
                feedback: Some(1.0),
                reply_by_ns: u64::MAX,
                lineage: (0..MAX_LINEAGE as u32)
                    .map(|i| ModuleId(u32::MAX - 200 + i))
                    .collect(),
            }),
        };
        let bytes = encode(&env).unwrap();
        assert!(bytes.len() <= MAX_MESSAGE_LEN, "{}", bytes.len());
    }

    #[test]
    fn contract_drop_counters() {
        let mut c = DropCounters::default();
        c.record_error(&WireError::WrongVersion { found: 9 });
        c.record(DropReason::NoContract);
        c.record(DropReason::NoContract);
        assert_eq!(c.get(DropReason::WrongVersion), 1);
        assert_eq!(c.get(DropReason::NoContract), 2);
        assert_eq!(c.total(), 3);
        assert_eq!(c.iter().count(), 2);
    }
}
