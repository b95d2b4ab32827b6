//! Typed publish/subscribe channels over iceoryx2 shared memory.
//!
//! A [`Node`] is one participant (one per module process). It opens channels by name at run
//! time: [`Node::publisher`] / [`Node::subscriber`] for fixed-size [`Message`]s,
//! [`Node::slice_publisher`] / [`Node::slice_subscriber`] for variable-size payloads
//! (occupancy grids, images, bytes) described by a [`SliceMessage`] header. The QoS comes from
//! the message type ([`crate::qos`]).
//!
//! Sending is loan, write in place, publish: [`Publisher::loan`] hands out the shared-memory
//! sample itself, so nothing is copied however large the message is. [`Publisher::publish`]
//! is the convenience form that copies a value in. Every publish stamps the header (sequence
//! number, time from the common clock, source module).
//!
//! Beside each data service runs an event service of the same name: a subscriber that has
//! nothing to do can block on it (see [`crate::wait`]) instead of polling. Publishers notify
//! only when a subscriber is actually blocked ([`crate::wake`]).

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::fmt;
use std::mem::MaybeUninit;
use std::ops::{Deref, DerefMut};
use std::rc::{Rc, Weak};

use iceoryx2::node::{Node as IoxNode, NodeBuilder};
use iceoryx2::port::ReceiveError;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample as IoxSample;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;
use iceoryx2::service::builder::publish_subscribe::{
    Builder as PsBuilder, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PsFactory;
use serde::Serialize;

use crate::clock::Clock;
use crate::error::Error;
use crate::msg::{Header, Message, SliceMessage, module_id};
use crate::qos::{ChannelKind, Qos};
use crate::wait::{WaitMode, Waiter};
use crate::wake::WakeFlag;

mod hanging;
mod list;
mod outlet;
mod publish;
mod receive;
mod slice;
mod writes;
pub use list::{ChannelListing, list_channels};
use outlet::Outlet;
use publish::Received;
pub use publish::{Loan, Publisher, Sample};
pub(crate) use receive::Input;
use receive::Reader;
pub use receive::{Fixed, Kind, Receiver, Slice, SliceSubscriber, Subscriber, Waitable};
use slice::SlicePort;
pub use slice::{SliceLoan, SliceLoanUninit, SlicePublisher, SliceSample};
use writes::WriteLog;
pub use writes::channel_key;

use iceoryx2::service::messaging_pattern::MessagingPattern;

/// The iceoryx2 service flavour hng uses (inter-process, single-threaded ports).
pub type Service = ipc::Service;

const PUBSUB: MessagingPattern = MessagingPattern::PublishSubscribe;

/// A publish-subscribe service that hangs in creation (see [`hanging`]).
fn pubsub_hangs(e: &PublishSubscribeOpenOrCreateError) -> bool {
    matches!(
        e,
        PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
            PublishSubscribeOpenError::HangsInCreation
        )
    )
}

type FixedService<T> = PsFactory<Service, T, ()>;
type SliceService<H> = PsFactory<Service, [<H as SliceMessage>::Elem], H>;
type SliceIoxPublisher<H> = IoxPublisher<Service, [<H as SliceMessage>::Elem], H>;
type SliceUninit<H> = SampleMutUninit<Service, [MaybeUninit<<H as SliceMessage>::Elem>], H>;
type FixedUninit<T> = SampleMutUninit<Service, MaybeUninit<T>, ()>;

/// Default prefix of every hng file in `/dev/shm` and iceoryx2's folders.
pub const DEFAULT_PREFIX: &str = "hng_";

/// Message counters of a node, summed over its ports (they feed the module report).
#[derive(Debug, Default)]
pub struct Counters {
    /// Messages received.
    pub msgs_in: Cell<u64>,
    /// Messages published.
    pub msgs_out: Cell<u64>,
    /// Messages lost (sequence gaps).
    pub msgs_dropped: Cell<u64>,
    /// Publishes that had to wake a sleeping subscriber (see [`crate::cpus`]).
    pub wakeups: Cell<u64>,
}

impl Counters {
    fn add(cell: &Cell<u64>, n: u64) {
        cell.set(cell.get().wrapping_add(n));
    }
}

/// Options of a [`Node`].
#[derive(Debug, Clone)]
pub struct NodeOptions {
    /// The node's (module's) name.
    pub name: String,
    /// The prefix that isolates one system (or one test) from another.
    pub prefix: String,
    /// The clock that stamps messages.
    pub clock: Clock,
}

impl NodeOptions {
    /// Options with the default prefix and the wall clock.
    pub fn new(name: &str) -> NodeOptions {
        NodeOptions {
            name: name.to_string(),
            prefix: DEFAULT_PREFIX.to_string(),
            clock: Clock::wall(),
        }
    }

    /// Sets the prefix.
    #[must_use]
    pub fn prefix(mut self, prefix: &str) -> NodeOptions {
        self.prefix = prefix.to_string();
        self
    }

    /// Sets the clock.
    #[must_use]
    pub fn clock(mut self, clock: Clock) -> NodeOptions {
        self.clock = clock;
        self
    }
}

/// The iceoryx2 configuration of a prefix: files named with it, its own root folder on tmpfs
/// ([`crate::shm::iox_root`]); a prefix longer than [`crate::shm::MAX_PREFIX_LEN`] is refused.
pub fn iceoryx_config(prefix: &str) -> Result<iceoryx2::config::Config, Error> {
    let root = crate::shm::iox_root_path(prefix)?;
    let mut config = iceoryx2::config::Config::default();
    config.global.set_root_path(&root);
    config.global.prefix = FileName::new(prefix.as_bytes()).map_err(|e| {
        Error::Config(format!(
            "prefix {prefix:?} is not a valid file-name prefix: {e:?}"
        ))
    })?;
    Ok(config)
}

/// Silences iceoryx2's own logging (warnings about missing config files and the like),
/// unless `HNG_IOX_LOG` asks for a level (`trace`, `debug`, `info`, `warn`, `error`).
pub fn silence_iceoryx_log() {
    let level = match std::env::var("HNG_IOX_LOG").as_deref() {
        Ok("trace") => LogLevel::Trace,
        Ok("debug") => LogLevel::Debug,
        Ok("info") => LogLevel::Info,
        Ok("warn") => LogLevel::Warn,
        _ => LogLevel::Fatal,
    };
    set_log_level(level);
}

/// One participant in the data plane: a module process, a tool, a test.
pub struct Node {
    inner: IoxNode<Service>,
    name: String,
    id: u32,
    prefix: String,
    clock: Clock,
    config: iceoryx2::config::Config,
    counters: Rc<Counters>,
    state_publishers: RefCell<Vec<Weak<dyn UpdateConnections>>>,
    /// The lockstep round the node is handling (0: none), shared with its ports.
    round: Rc<Cell<u32>>,
    /// The channels written (lockstep participants only), shared with its publishers.
    writes: Rc<WriteLog>,
}

impl fmt::Debug for Node {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Node")
            .field("name", &self.name)
            .field("prefix", &self.prefix)
            .finish_non_exhaustive()
    }
}

impl Node {
    /// Creates a node. Stale resources of dead nodes under the same prefix are cleaned on the
    /// way (iceoryx2's dead-node cleanup).
    pub fn new(opts: NodeOptions) -> Result<Node, Error> {
        silence_iceoryx_log();
        crate::qos::ChannelLimits::from_env().map_err(Error::Config)?;
        let config = iceoryx_config(&opts.prefix)?;
        let node_name = NodeName::new(&opts.name).map_err(|e| Error::Node {
            name: opts.name.clone(),
            detail: format!("invalid node name: {e:?}"),
        })?;
        let inner = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Service>()
            .map_err(|e| Error::Node {
                name: opts.name.clone(),
                detail: format!("{e:?}"),
            })?;
        Ok(Node {
            inner,
            id: module_id(&opts.name),
            name: opts.name,
            prefix: opts.prefix,
            clock: opts.clock,
            config,
            counters: Rc::new(Counters::default()),
            state_publishers: RefCell::new(Vec::new()),
            round: Rc::new(Cell::new(0)),
            writes: Rc::new(WriteLog::default()),
        })
    }

    /// Starts (or stops) noting which channels this node writes ([`Node::take_written`]): a
    /// lockstep participant tells the barrier, so only their subscribers get the next round.
    pub fn track_writes(&self, on: bool) {
        self.writes.set_enabled(on);
    }

    /// The keys ([`channel_key`]) of the channels written since the last call (each once;
    /// empty unless [`Node::track_writes`] is on).
    pub fn take_written(&self) -> Vec<u64> {
        self.writes.take()
    }

    /// Lets this node's state-channel publishers hand their latest sample to subscribers that
    /// joined since the last call. iceoryx2 delivers history only when the publisher updates
    /// its connections; the module executor calls this at every wake-up (it costs one counter
    /// comparison per publisher when nothing changed). Tools without an executor call it
    /// themselves.
    pub fn update_connections(&self) {
        self.state_publishers
            .borrow_mut()
            .retain(|w| match w.upgrade() {
                Some(p) => {
                    let _ = p.update_connections();
                    true
                }
                None => false,
            });
    }

    fn track_state<P: UpdateConnections + 'static>(
        &self,
        kind: crate::qos::ChannelKind,
        port: &Rc<P>,
    ) {
        use crate::qos::ChannelKind;
        if matches!(kind, ChannelKind::State | ChannelKind::StateBulk) {
            let weak: Weak<dyn UpdateConnections> =
                Rc::downgrade(port) as Weak<dyn UpdateConnections>;
            self.state_publishers.borrow_mut().push(weak);
        }
    }

    /// The node's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The node's module id (stamped into every header it publishes).
    pub fn id(&self) -> u32 {
        self.id
    }

    /// The prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The clock.
    pub fn clock(&self) -> &Clock {
        &self.clock
    }

    /// Sets the lockstep round this node is handling (0: none). From then on its messages
    /// carry it ([`Header::round`]), and its subscribers keep a message sent in this round
    /// for the next one (the executor calls this for a module on the simulation clock; see
    /// [`crate::clock::lockstep`]).
    pub fn set_lockstep_round(&self, round: u64) {
        // Rounds only ever need telling apart from the next one: the low 32 bits do.
        self.round.set(round as u32);
    }

    /// The lockstep round this node is handling (low 32 bits; 0: none).
    pub fn lockstep_round(&self) -> u32 {
        self.round.get()
    }

    /// Message counters summed over this node's ports.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    pub(crate) fn shared_counters(&self) -> Rc<Counters> {
        self.counters.clone()
    }

    /// The underlying iceoryx2 node (for tools that need raw access).
    pub fn iceoryx(&self) -> &IoxNode<Service> {
        &self.inner
    }

    /// The iceoryx2 configuration.
    pub fn iceoryx_config(&self) -> &iceoryx2::config::Config {
        &self.config
    }

    fn service_name(channel: &str) -> Result<ServiceName, Error> {
        ServiceName::new(channel).map_err(|e| Error::InvalidChannelName {
            channel: channel.to_string(),
            reason: format!("{e:?}"),
        })
    }

    fn open_error(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
        expected: String,
        e: PublishSubscribeOpenOrCreateError,
    ) -> Error {
        if let PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
            PublishSubscribeOpenError::IncompatibleTypes,
        ) = e
        {
            let found = match <Service as iceoryx2::service::Service>::details(
                name,
                &self.config,
                MessagingPattern::PublishSubscribe,
            ) {
                Ok(Some(d)) => {
                    let t = d.static_details.publish_subscribe().message_type_details();
                    describe_type(
                        t.payload.type_name().to_string(),
                        t.user_header.type_name().to_string(),
                    )
                }
                _ => "an unknown type".to_string(),
            };
            return Error::TypeMismatch {
                channel: channel.to_string(),
                expected,
                found,
            };
        }
        self.port_error(channel, name, kind, "open", e)
    }

    fn events(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<Service>, Error> {
        use iceoryx2::service::builder::event::{EventOpenError as O, EventOpenOrCreateError as E};
        let qos = kind.qos();
        let open = || {
            self.inner
                .service_builder(name)
                .event()
                .max_notifiers(qos.max_publishers)
                .max_listeners(qos.max_subscribers)
                .max_nodes(qos.max_publishers + qos.max_subscribers)
                .open_or_create()
        };
        let hanging = |e: &E| matches!(e, E::EventOpenError(O::HangsInCreation));
        let pattern = MessagingPattern::Event;
        hanging::retry_if_hanging(&self.config, name, pattern, hanging, open)
            .map_err(|e| self.port_error(channel, name, kind, "open event service", e))
    }

    /// The error of a failed open or port creation: [`Error::ChannelFull`] naming the channel
    /// and its limit when a limit was hit (iceoryx2's `ExceedsMaxSupportedSubscribers`,
    /// `ExceedsMaxNumberOfNodes`, ...), else the operation and iceoryx2's error.
    fn port_error(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
        op: &'static str,
        e: impl fmt::Debug,
    ) -> Error {
        let detail = format!("{e:?}");
        let hit = if detail.contains("ExceedsMaxSupportedSubscribers")
            || detail.contains("ExceedsMaxSupportedListeners")
        {
            Some(("subscribers", "subscribers"))
        } else if detail.contains("ExceedsMaxSupportedPublishers")
            || detail.contains("ExceedsMaxSupportedNotifiers")
        {
            Some(("publishers", "publishers"))
        } else if detail.contains("ExceedsMaxNumberOfNodes") {
            Some(("processes (publishers + subscribers)", "subscribers"))
        } else {
            None
        };
        let Some((what, key)) = hit else {
            return Error::channel(channel, op, e);
        };
        let qos = kind.qos();
        // The limits the channel was created with (its creator's), if it can be read.
        let actual = <Service as iceoryx2::service::Service>::details(
            name,
            &self.config,
            MessagingPattern::PublishSubscribe,
        )
        .ok()
        .flatten()
        .map(|d| {
            let ps = d.static_details.publish_subscribe();
            (ps.max_publishers(), ps.max_subscribers(), ps.max_nodes())
        });
        let (pubs, subs, nodes) = actual.unwrap_or((
            qos.max_publishers,
            qos.max_subscribers,
            qos.max_publishers + qos.max_subscribers,
        ));
        let limit = match what {
            "subscribers" => subs,
            "publishers" => pubs,
            _ => nodes,
        };
        Error::ChannelFull {
            channel: channel.to_string(),
            kind: kind.name(),
            what,
            key,
            limit,
            env: crate::qos::LIMITS_ENV,
        }
    }

    fn fixed_service<T: Message>(
        &self,
        channel: &str,
    ) -> Result<(FixedService<T>, ServiceName), Error> {
        let name = Self::service_name(channel)?;
        let open = || {
            with_qos(
                self.inner.service_builder(&name).publish_subscribe::<T>(),
                T::KIND.qos_of(channel),
            )
            .open_or_create()
        };
        let service = hanging::retry_if_hanging(&self.config, &name, PUBSUB, pubsub_hangs, open)
            .map_err(|e| self.open_error(channel, &name, T::KIND, type_name::<T>(), e))?;
        Ok((service, name))
    }

    fn slice_service<H: SliceMessage>(
        &self,
        channel: &str,
    ) -> Result<(SliceService<H>, ServiceName), Error> {
        let name = Self::service_name(channel)?;
        let open = || {
            with_qos(
                self.inner
                    .service_builder(&name)
                    .publish_subscribe::<[H::Elem]>()
                    .user_header::<H>(),
                H::KIND.qos_of(channel),
            )
            .open_or_create()
        };
        let service = hanging::retry_if_hanging(&self.config, &name, PUBSUB, pubsub_hangs, open)
            .map_err(|e| self.open_error(channel, &name, H::KIND, slice_type_name::<H>(), e))?;
        Ok((service, name))
    }

    /// Opens (or creates) a channel and returns a publisher on it.
    pub fn publisher<T: Message>(&self, channel: &str) -> Result<Publisher<T>, Error> {
        let (service, name) = self.fixed_service::<T>(channel)?;
        let port = service
            .publisher_builder()
            .create()
            .map_err(|e| self.port_error(channel, &name, T::KIND, "create publisher", e))?;
        let (port, out) = self.outlet(channel, &name, T::KIND, port)?;
        Ok(Publisher {
            spare: Cell::new(None),
            port,
            out,
        })
    }

    /// Opens (or creates) a channel and returns a subscriber on it, holding the channel
    /// kind's buffer of unread samples ([`crate::qos`]). On state channels the latest sample
    /// published before this call is delivered too.
    pub fn subscriber<T: Message>(&self, channel: &str) -> Result<Subscriber<T>, Error> {
        self.subscriber_holding::<T>(channel, false)
    }

    /// A subscriber for a recorder (`hng record`, the live view): it holds the channel's
    /// recorder's buffer ([`crate::qos::Qos::record_buffer`]), so a reader that polls loses
    /// nothing between two polls at the rates the buffer was sized for.
    pub fn tap_subscriber<T: Message>(&self, channel: &str) -> Result<Subscriber<T>, Error> {
        self.subscriber_holding::<T>(channel, true)
    }

    fn subscriber_holding<T: Message>(
        &self,
        channel: &str,
        tap: bool,
    ) -> Result<Subscriber<T>, Error> {
        let (service, name) = self.fixed_service::<T>(channel)?;
        self.open_receiver(channel, &name, T::KIND, &service, tap)
    }

    /// Opens (or creates) a variable-size channel and returns a publisher whose samples may
    /// hold up to `max_len` elements at first; a longer loan grows the publisher's segment
    /// (power-of-two steps), so every size can be sent and no subscriber misses a sample.
    pub fn slice_publisher<H: SliceMessage>(
        &self,
        channel: &str,
        max_len: usize,
    ) -> Result<SlicePublisher<H>, Error> {
        let (service, name) = self.slice_service::<H>(channel)?;
        let max_len = max_len.max(1);
        let port = SlicePort::create(&service, channel, max_len).map_err(|e| match e {
            Error::Channel { detail, .. } if detail.contains("ExceedsMax") => {
                self.port_error(channel, &name, H::KIND, "create publisher", detail)
            }
            e => e,
        })?;
        let port = SlicePort {
            service,
            spare: Cell::new(None),
            last_len: Cell::new(0),
            port,
        };
        let (port, out) = self.outlet(channel, &name, H::KIND, port)?;
        Ok(SlicePublisher { port, out })
    }

    /// Opens (or creates) a variable-size channel and returns a subscriber on it.
    pub fn slice_subscriber<H: SliceMessage>(
        &self,
        channel: &str,
    ) -> Result<SliceSubscriber<H>, Error> {
        self.slice_subscriber_holding::<H>(channel, false)
    }

    /// [`Node::tap_subscriber`] for a variable-size channel.
    pub fn slice_tap_subscriber<H: SliceMessage>(
        &self,
        channel: &str,
    ) -> Result<SliceSubscriber<H>, Error> {
        self.slice_subscriber_holding::<H>(channel, true)
    }

    fn slice_subscriber_holding<H: SliceMessage>(
        &self,
        channel: &str,
        tap: bool,
    ) -> Result<SliceSubscriber<H>, Error> {
        let (service, name) = self.slice_service::<H>(channel)?;
        self.open_receiver(channel, &name, H::KIND, &service, tap)
    }

    /// A subscriber port on `service` holding the channel kind's buffer (a recorder's with
    /// `tap`), with its listener: both subscriber kinds.
    fn open_receiver<K, P, U>(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
        service: &PsFactory<Service, P, U>,
        tap: bool,
    ) -> Result<Receiver<K>, Error>
    where
        K: Kind<Port = IoxSubscriber<Service, P, U>>,
        P: fmt::Debug + IceoryxSend + ?Sized + 'static,
        U: fmt::Debug + ZeroCopySend + 'static,
    {
        let buffer = buffer_for(
            kind.qos_of(channel),
            service.static_config().subscriber_max_buffer_size(),
            tap,
        );
        let port = service
            .subscriber_builder()
            .buffer_size(buffer)
            .create()
            .map_err(|e| self.port_error(channel, name, kind, "create subscriber", e))?;
        // Without history every sample reaches the port through a publish, which the wake
        // word counts: an empty port is known empty while the count stands (crate::wake).
        let counted = service.static_config().history_size() == 0;
        self.receiver(channel, name, kind, port, counted)
    }

    /// The sending side shared by both publisher kinds: notifier, wake flag, header stamping.
    fn outlet<P: UpdateConnections + 'static>(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
        port: P,
    ) -> Result<(Rc<P>, Outlet), Error> {
        let notifier = self
            .events(channel, name, kind)?
            .notifier_builder()
            .create()
            .map_err(|e| self.port_error(channel, name, kind, "create notifier", e))?;
        let _ = port.update_connections();
        let port = Rc::new(port);
        self.track_state(kind, &port);
        let out = Outlet {
            notifier,
            wake: WakeFlag::open(&self.prefix, channel)?,
            seq: Cell::new(0),
            source: self.id,
            clock: self.clock.clone(),
            channel: channel.into(),
            counters: self.counters.clone(),
            notified: Cell::new(0),
            round: self.round.clone(),
            key: channel_key(channel),
            writes: self.writes.clone(),
        };
        Ok((port, out))
    }

    fn receiver<K: Kind>(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
        port: K::Port,
        counted: bool,
    ) -> Result<Receiver<K>, Error> {
        let listener = self
            .events(channel, name, kind)?
            .listener_builder()
            .create()
            .map_err(|e| self.port_error(channel, name, kind, "create listener", e))?;
        let inlet = Rc::new(Inlet {
            listener,
            wake: WakeFlag::open(&self.prefix, channel)?,
            channel: channel.into(),
            last_seq: RefCell::new(Vec::new()),
            stats: Cell::new(ChannelStats::default()),
            counters: self.counters.clone(),
            round: self.round.clone(),
            key: channel_key(channel),
            counted,
            empty_at: Cell::new(None),
            polled: Cell::new(false),
        });
        K::update_connections(&port);
        Ok(Receiver {
            reader: Rc::new(Reader {
                port,
                inlet,
                held: RefCell::new(VecDeque::new()),
                peeked: RefCell::new(None),
            }),
        })
    }
}

/// A subscriber's buffer: the kind's (a module's) or the recorder's, within the bound the
/// channel was created with (by a process that may have had other limits).
fn buffer_for(qos: Qos, channel_bound: usize, tap: bool) -> usize {
    let want = if tap { qos.max_buffer() } else { qos.buffer };
    want.clamp(1, channel_bound.max(1))
}

/// The QoS settings every opener of a channel must ask for (see [`crate::qos`]).
fn with_qos<P: fmt::Debug + IceoryxSend + ?Sized, U: fmt::Debug + ZeroCopySend>(
    builder: PsBuilder<P, U, Service>,
    qos: Qos,
) -> PsBuilder<P, U, Service> {
    builder
        .enable_safe_overflow(true)
        .history_size(qos.history)
        .subscriber_max_buffer_size(qos.max_buffer())
        .subscriber_max_borrowed_samples(qos.borrowed)
        .max_publishers(qos.max_publishers)
        .max_subscribers(qos.max_subscribers)
        .max_nodes(qos.max_publishers + qos.max_subscribers)
}

fn type_name<T: ZeroCopySend>() -> String {
    // SAFETY: `type_name` is only unsafe because implementors may lie; ours are derived.
    unsafe { <T as ZeroCopySend>::type_name() }.to_string()
}

fn slice_type_name<H: SliceMessage>() -> String {
    describe_type(type_name::<H::Elem>(), type_name::<H>())
}

fn describe_type(payload: String, user_header: String) -> String {
    if user_header == "()" || user_header.is_empty() {
        payload
    } else {
        format!("[{payload}] with header {user_header}")
    }
}

/// Statistics of one subscriber.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ChannelStats {
    /// Messages received.
    pub received: u64,
    /// Messages lost before they were read (sequence gaps: overflow, or a slow reader).
    pub dropped: u64,
    /// Publishers that restarted their sequence (a restarted module).
    pub restarts: u64,
}

/// What the receiving side of a channel shares between fixed and slice subscribers; the
/// executor keeps a handle to it to wait and to watch deadlines.
pub(crate) struct Inlet {
    pub(crate) listener: Listener<Service>,
    pub(crate) wake: WakeFlag,
    pub(crate) channel: Rc<str>,
    last_seq: RefCell<Vec<(u32, u64)>>,
    stats: Cell<ChannelStats>,
    counters: Rc<Counters>,
    /// The node's lockstep round (see [`Header::round`]).
    round: Rc<Cell<u32>>,
    /// [`channel_key`] of the channel.
    pub(crate) key: u64,
    /// Every sample reaches the port through a counted publish (a channel without history):
    /// [`Inlet::empty_at`] is then exact. A channel with history also gets samples when a
    /// publisher hands its history to a late joiner, which no publish counts.
    counted: bool,
    /// The channel's publish count ([`WakeFlag::published`]) when the port was last found
    /// empty (`None`: not empty, or not looked at).
    empty_at: Cell<Option<u32>>,
    /// A polled input: only its newest sample matters, so a gap is no loss.
    pub(super) polled: Cell<bool>,
}

impl Inlet {
    /// True if `h` was sent in the lockstep round this node is handling (never outside
    /// lockstep): it waits for the next round.
    #[inline]
    fn is_current_round(&self, h: &Header) -> bool {
        let r = self.round.get();
        r != 0 && h.round == r
    }

    #[inline]
    fn account(&self, h: &Header) {
        let mut stats = self.stats.get();
        stats.received += 1;
        Counters::add(&self.counters.msgs_in, 1);
        let mut seqs = self.last_seq.borrow_mut();
        match seqs.iter_mut().find(|(src, _)| *src == h.source) {
            Some((_, last)) => {
                if h.seq > *last + 1 && !self.polled.get() {
                    let lost = h.seq - *last - 1;
                    stats.dropped += lost;
                    Counters::add(&self.counters.msgs_dropped, lost);
                } else if h.seq <= *last {
                    stats.restarts += 1;
                }
                *last = h.seq;
            }
            None => seqs.push((h.source, h.seq)),
        }
        self.stats.set(stats);
    }

    /// Consumes pending event notifications without blocking.
    pub(crate) fn drain_events(&self) {
        let _ = self.listener.try_wait(|_| {});
    }
}

/// Identifies an input (a subscriber) in executor callbacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct InputId(usize);
