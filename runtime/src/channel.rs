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
use crate::wait::Waiter;
use crate::wake::WakeFlag;

mod hanging;

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

/// The iceoryx2 configuration of a prefix: hng's files only, signal handling and log noise off.
pub fn iceoryx_config(prefix: &str) -> Result<iceoryx2::config::Config, Error> {
    let mut config = iceoryx2::config::Config::default();
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
        })
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
                T::KIND.qos(),
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
                H::KIND.qos(),
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

    /// Opens (or creates) a channel and returns a subscriber on it. On state channels the
    /// latest sample published before this call is delivered too.
    pub fn subscriber<T: Message>(&self, channel: &str) -> Result<Subscriber<T>, Error> {
        let (service, name) = self.fixed_service::<T>(channel)?;
        let port = service
            .subscriber_builder()
            .create()
            .map_err(|e| self.port_error(channel, &name, T::KIND, "create subscriber", e))?;
        self.receiver(channel, &name, T::KIND, port)
    }

    /// Opens (or creates) a variable-size channel and returns a publisher whose samples may
    /// hold up to `max_len` elements at first; a longer loan moves the publisher to a
    /// segment twice as large or more (power-of-two steps), so every size can be sent.
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
            port: RefCell::new(Some(port)),
            max_len: Cell::new(max_len),
        };
        let (port, out) = self.outlet(channel, &name, H::KIND, port)?;
        Ok(SlicePublisher { port, out })
    }

    /// Opens (or creates) a variable-size channel and returns a subscriber on it.
    pub fn slice_subscriber<H: SliceMessage>(
        &self,
        channel: &str,
    ) -> Result<SliceSubscriber<H>, Error> {
        let (service, name) = self.slice_service::<H>(channel)?;
        let port = service
            .subscriber_builder()
            .create()
            .map_err(|e| self.port_error(channel, &name, H::KIND, "create subscriber", e))?;
        self.receiver(channel, &name, H::KIND, port)
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
        };
        Ok((port, out))
    }

    fn receiver<K: Kind>(
        &self,
        channel: &str,
        name: &ServiceName,
        kind: ChannelKind,
        port: K::Port,
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
        });
        K::update_connections(&port);
        Ok(Receiver {
            reader: Rc::new(Reader { port, inlet }),
        })
    }
}

/// The QoS settings every opener of a channel must ask for (see [`crate::qos`]).
fn with_qos<P: fmt::Debug + IceoryxSend + ?Sized, U: fmt::Debug + ZeroCopySend>(
    builder: PsBuilder<P, U, Service>,
    qos: Qos,
) -> PsBuilder<P, U, Service> {
    builder
        .enable_safe_overflow(true)
        .history_size(qos.history)
        .subscriber_max_buffer_size(qos.buffer)
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

/// What the sending side of a channel shares between fixed and slice publishers.
struct Outlet {
    notifier: Notifier<Service>,
    wake: WakeFlag,
    seq: Cell<u64>,
    source: u32,
    clock: Clock,
    channel: Rc<str>,
    counters: Rc<Counters>,
    notified: Cell<u64>,
}

impl Outlet {
    #[inline]
    fn stamp(&self, h: &mut Header) {
        let seq = self.seq.get() + 1;
        self.seq.set(seq);
        h.seq = seq;
        h.stamp_ns = self.clock.now_ns();
        h.source = self.source;
    }

    /// Numbers a recorded header (replay): the sequence is this publisher's, the stamp and
    /// the source are the recording's.
    fn stamp_recorded(&self, h: &mut Header) {
        let seq = self.seq.get() + 1;
        self.seq.set(seq);
        h.seq = seq;
    }

    #[inline]
    fn sent(&self) -> Result<(), Error> {
        Counters::add(&self.counters.msgs_out, 1);
        if self.wake.has_waiters() {
            self.notified.set(self.notified.get() + 1);
            Counters::add(&self.counters.wakeups, 1);
            self.notifier
                .notify()
                .map_err(|e| Error::channel(&self.channel, "notify", e))?;
        }
        Ok(())
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
}

impl Inlet {
    #[inline]
    fn account(&self, h: &Header) {
        let mut stats = self.stats.get();
        stats.received += 1;
        Counters::add(&self.counters.msgs_in, 1);
        let mut seqs = self.last_seq.borrow_mut();
        match seqs.iter_mut().find(|(src, _)| *src == h.source) {
            Some((_, last)) => {
                if h.seq > *last + 1 {
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

/// Anything the executor can wait on.
pub(crate) trait Input {
    fn inlet(&self) -> &Rc<Inlet>;
    fn has_samples(&self) -> bool;
}

/// Publishes fixed-size messages of type `T`.
///
/// After each publish the publisher loans the sample for the next one (its *spare*), while
/// nothing waits for it; see [the spare sample](SlicePublisher#the-spare-sample).
pub struct Publisher<T: Message> {
    /// Declared first: dropped before the port.
    spare: Cell<Option<FixedUninit<T>>>,
    port: Rc<IoxPublisher<Service, T, ()>>,
    out: Outlet,
}

impl<T: Message> fmt::Debug for Publisher<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Publisher")
            .field("channel", &self.out.channel)
            .finish_non_exhaustive()
    }
}

impl<T: Message> Publisher<T> {
    /// The channel's name.
    pub fn channel(&self) -> &str {
        &self.out.channel
    }

    /// Stamps `msg`'s header and publishes a copy of it.
    #[inline]
    pub fn publish(&self, mut msg: T) -> Result<(), Error> {
        self.out.stamp(msg.header_mut());
        self.send(self.uninit()?.write_payload(msg))
    }

    /// Publishes a copy of a recorded message (replay): its time stamp and source stay as
    /// recorded, only the sequence number is this publisher's (so subscribers still count
    /// gaps).
    pub fn publish_recorded(&self, mut msg: T) -> Result<(), Error> {
        self.out.stamp_recorded(msg.header_mut());
        self.send(self.uninit()?.write_payload(msg))
    }

    /// Loans a sample in shared memory, initialised to `T::default()`, to fill in place.
    #[inline]
    pub fn loan(&self) -> Result<Loan<'_, T>, Error> {
        Ok(Loan {
            sample: self.uninit()?.write_payload(T::default()),
            publisher: self,
        })
    }

    /// The spare sample, or a new loan.
    #[inline]
    fn uninit(&self) -> Result<FixedUninit<T>, Error> {
        match self.spare.take() {
            Some(sample) => Ok(sample),
            None => self
                .port
                .loan_uninit()
                .map_err(|e| Error::channel(&self.out.channel, "loan", e)),
        }
    }

    /// Sends a stamped sample, then loans the next spare.
    #[inline]
    fn send(&self, sample: SampleMut<Service, T, ()>) -> Result<(), Error> {
        sample
            .send()
            .map_err(|e| Error::channel(&self.out.channel, "send", e))?;
        let sent = self.out.sent();
        let spare = self.spare.take();
        self.spare
            .set(spare.or_else(|| self.port.loan_uninit().ok()));
        sent
    }

    /// Publishes that had to wake a sleeping subscriber (the rest cost no system call).
    pub fn notifications(&self) -> u64 {
        self.out.notified.get()
    }

    /// Number of messages published so far.
    pub fn published(&self) -> u64 {
        self.out.seq.get()
    }

    /// Connects subscribers that appeared since the last call (done automatically on send,
    /// but a publisher that sends rarely can call it to deliver history to late joiners).
    pub fn update_connections(&self) {
        let _ = self.port.update_connections();
    }
}

/// A sample loaned from a [`Publisher`]: write it in place, then [`Loan::publish`] it.
pub struct Loan<'a, T: Message> {
    sample: SampleMut<Service, T, ()>,
    publisher: &'a Publisher<T>,
}

impl<T: Message> Loan<'_, T> {
    /// Stamps the header and publishes the sample.
    #[inline]
    pub fn publish(mut self) -> Result<(), Error> {
        self.publisher
            .out
            .stamp(self.sample.payload_mut().header_mut());
        self.publisher.send(self.sample)
    }
}

impl<T: Message> Deref for Loan<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        self.sample.payload()
    }
}

impl<T: Message> DerefMut for Loan<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        self.sample.payload_mut()
    }
}

/// A received message, still in shared memory; dereferences to the message.
pub struct Sample<T: Message> {
    inner: IoxSample<Service, T, ()>,
}

impl<T: Message> Deref for Sample<T> {
    type Target = T;
    fn deref(&self) -> &T {
        self.inner.payload()
    }
}

impl<T: Message> fmt::Debug for Sample<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.inner.payload().fmt(f)
    }
}

mod sealed {
    pub trait Sealed {}
}

/// The two kinds of subscriber: [`Fixed`] messages and [`Slice`] payloads. Everything else
/// about receiving (sequence accounting, statistics, what the executor watches) is shared
/// by [`Receiver`].
pub trait Kind: sealed::Sealed + 'static {
    /// The iceoryx2 port.
    #[doc(hidden)]
    type Port;
    /// What [`Receiver::receive`] returns.
    type Sample;
    /// The name `Debug` shows.
    #[doc(hidden)]
    const NAME: &'static str;
    #[doc(hidden)]
    fn receive(port: &Self::Port) -> Result<Option<Self::Sample>, ReceiveError>;
    #[doc(hidden)]
    fn has_samples(port: &Self::Port) -> bool;
    #[doc(hidden)]
    fn update_connections(port: &Self::Port);
    #[doc(hidden)]
    fn header(sample: &Self::Sample) -> &Header;
}

/// Fixed-size messages of type `T` (see [`Subscriber`]).
pub struct Fixed<T>(std::marker::PhantomData<T>);

/// Variable-size payloads described by header `H` (see [`SliceSubscriber`]).
pub struct Slice<H>(std::marker::PhantomData<H>);

impl<T: Message> sealed::Sealed for Fixed<T> {}
impl<H: SliceMessage> sealed::Sealed for Slice<H> {}

impl<T: Message> Kind for Fixed<T> {
    type Port = IoxSubscriber<Service, T, ()>;
    type Sample = Sample<T>;
    const NAME: &'static str = "Subscriber";
    #[inline]
    fn receive(port: &Self::Port) -> Result<Option<Sample<T>>, ReceiveError> {
        Ok(port.receive()?.map(|inner| Sample { inner }))
    }
    fn has_samples(port: &Self::Port) -> bool {
        port.has_samples().unwrap_or(false)
    }
    fn update_connections(port: &Self::Port) {
        let _ = port.update_connections();
    }
    fn header(sample: &Sample<T>) -> &Header {
        sample.inner.payload().header()
    }
}

impl<H: SliceMessage> Kind for Slice<H> {
    type Port = IoxSubscriber<Service, [H::Elem], H>;
    type Sample = SliceSample<H>;
    const NAME: &'static str = "SliceSubscriber";
    #[inline]
    fn receive(port: &Self::Port) -> Result<Option<SliceSample<H>>, ReceiveError> {
        Ok(port.receive()?.map(|inner| SliceSample { inner }))
    }
    fn has_samples(port: &Self::Port) -> bool {
        port.has_samples().unwrap_or(false)
    }
    fn update_connections(port: &Self::Port) {
        let _ = port.update_connections();
    }
    fn header(sample: &SliceSample<H>) -> &Header {
        sample.inner.user_header().header()
    }
}

/// The receiving port of either kind and what the executor watches.
struct Reader<K: Kind> {
    port: K::Port,
    inlet: Rc<Inlet>,
}

impl<K: Kind> Input for Reader<K> {
    fn inlet(&self) -> &Rc<Inlet> {
        &self.inlet
    }
    fn has_samples(&self) -> bool {
        K::has_samples(&self.port)
    }
}

/// Receives messages from a channel: [`Subscriber`] for fixed-size ones, [`SliceSubscriber`]
/// for variable-size payloads.
pub struct Receiver<K: Kind> {
    reader: Rc<Reader<K>>,
}

/// Receives fixed-size messages of type `T`.
pub type Subscriber<T> = Receiver<Fixed<T>>;

/// Receives variable-size payloads described by header `H`.
pub type SliceSubscriber<H> = Receiver<Slice<H>>;

impl<K: Kind> fmt::Debug for Receiver<K> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct(K::NAME)
            .field("channel", &self.reader.inlet.channel)
            .finish_non_exhaustive()
    }
}

impl<K: Kind> Receiver<K> {
    /// The channel's name.
    pub fn channel(&self) -> &str {
        &self.reader.inlet.channel
    }

    /// The next message, or `None` when there is none.
    #[inline]
    pub fn receive(&self) -> Result<Option<K::Sample>, Error> {
        let r = &*self.reader;
        let next =
            K::receive(&r.port).map_err(|e| Error::channel(&r.inlet.channel, "receive", e))?;
        if let Some(s) = &next {
            r.inlet.account(K::header(s));
        }
        Ok(next)
    }

    /// The next message, waiting for it with `waiter` for at most `timeout`; `None` when none
    /// came in time. The way to wait on one channel: `waiter` should watch this receiver
    /// alone ([`Waiter::attach`]); another watched input with unread data would make every
    /// wait return at once. In spin mode it polls this receiver directly and takes the
    /// message the moment it lands (see [`Waiter::wait_for`]).
    #[inline]
    pub fn receive_timeout(
        &self,
        waiter: &mut Waiter,
        timeout: std::time::Duration,
    ) -> Result<Option<K::Sample>, Error> {
        waiter.wait_for(timeout, || self.receive())
    }

    /// Drains the channel and returns only the newest message.
    pub fn latest(&self) -> Result<Option<K::Sample>, Error> {
        let mut last = None;
        while let Some(s) = self.receive()? {
            last = Some(s);
        }
        Ok(last)
    }

    /// True if a message is waiting.
    pub fn has_samples(&self) -> bool {
        K::has_samples(&self.reader.port)
    }

    /// This subscriber's statistics.
    pub fn stats(&self) -> ChannelStats {
        self.reader.inlet.stats.get()
    }

    /// The id the executor reports when this input has data or misses its deadline.
    pub fn id(&self) -> InputId {
        InputId(Rc::as_ptr(&self.reader.inlet) as usize)
    }

    pub(crate) fn as_input(&self) -> Rc<dyn Input> {
        self.reader.clone()
    }
}

/// Identifies an input (a subscriber) in executor callbacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct InputId(usize);

/// The port of a [`SlicePublisher`]: an iceoryx2 publisher with a static segment, replaced
/// by one with a larger segment when a loan does not fit.
///
/// iceoryx2's own growing segments (`AllocationStrategy::PowerOfTwo`) cost about 30 ns per
/// message in translating offsets between segments (measured on this project's machine,
/// publisher and subscriber together), on every message and not only after growing. A
/// static segment has one offset base. The replaced publisher's unread samples are still
/// delivered (iceoryx2 keeps a disconnected publisher's samples for its subscribers), and
/// the sequence numbers go on, so subscribers see no gap.
struct SlicePort<H: SliceMessage> {
    service: SliceService<H>,
    /// A sample loaned ahead for the next loan (see [`SlicePublisher`]); declared before
    /// the port, and dropped before it is replaced, so that it never keeps an old
    /// publisher alive.
    spare: Cell<Option<SliceUninit<H>>>,
    /// Length of the last payload published.
    last_len: Cell<usize>,
    /// `None` only while being replaced.
    port: RefCell<Option<SliceIoxPublisher<H>>>,
    max_len: Cell<usize>,
}

impl<H: SliceMessage> SlicePort<H> {
    fn create(
        service: &SliceService<H>,
        channel: &str,
        max_len: usize,
    ) -> Result<SliceIoxPublisher<H>, Error> {
        service
            .publisher_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::Static)
            .create()
            .map_err(|e| Error::channel(channel, "create publisher", e))
    }

    #[inline]
    fn loan(&self, channel: &str, len: usize) -> Result<SliceUninit<H>, Error> {
        if let Some(spare) = self.spare.take()
            && spare.payload().len() == len
        {
            return Ok(spare);
        }
        if len > self.max_len.get() {
            self.grow(channel, len)?;
        }
        let port = self.port.borrow();
        let port = port
            .as_ref()
            .ok_or_else(|| Error::channel(channel, "loan", "publisher lost while growing"))?;
        port.loan_slice_uninit(len)
            .map_err(|e| Error::channel(channel, "loan", e))
    }

    /// After a publish of `len` elements: loans the spare for a next payload of the same
    /// length, if the length is steady (the same as the publish before) and there is none.
    #[inline]
    fn refill(&self, len: usize) {
        if self.last_len.replace(len) != len {
            return;
        }
        let spare = self.spare.take().or_else(|| {
            let port = self.port.borrow();
            port.as_ref()?.loan_slice_uninit(len).ok()
        });
        self.spare.set(spare);
    }

    #[cold]
    fn grow(&self, channel: &str, len: usize) -> Result<(), Error> {
        drop(self.spare.take());
        let old = self.max_len.get();
        let new = len.checked_next_power_of_two().unwrap_or(len);
        let fresh = match Self::create(&self.service, channel, new) {
            Ok(p) => p,
            Err(_) => {
                // No publisher slot to spare on the channel: give this one up first.
                drop(self.port.borrow_mut().take());
                match Self::create(&self.service, channel, new) {
                    Ok(p) => p,
                    Err(e) => {
                        *self.port.borrow_mut() = Self::create(&self.service, channel, old).ok();
                        return Err(e);
                    }
                }
            }
        };
        let _ = fresh.update_connections();
        *self.port.borrow_mut() = Some(fresh);
        self.max_len.set(new);
        tracing::debug!(channel, from = old, to = new, "slice publisher grew");
        Ok(())
    }
}

impl<H: SliceMessage> UpdateConnections for SlicePort<H> {
    fn update_connections(
        &self,
    ) -> Result<(), iceoryx2::port::update_connections::ConnectionFailure> {
        match self.port.borrow().as_ref() {
            Some(p) => p.update_connections(),
            None => Ok(()),
        }
    }
}

/// Publishes variable-size payloads: a header `H` plus a slice of `H::Elem`.
///
/// # The spare sample
/// Publishers of both kinds loan the sample for their next message right after a publish
/// (a slice publisher only once two payloads in a row had the same length, and only for
/// that length), and hand it out at the next loan. Loaning from iceoryx2 takes a chunk,
/// writes its headers and so takes ownership of its cache lines from the core that read
/// them last; done at send time, the publish waits for that. Done ahead, while the
/// publisher waits anyway, it is off the message's path: in `hng bench ipc` spin mode one
/// hop went from 521-536 ns to 416-436 ns, below raw iceoryx2 loaning at send time (see
/// `docs/data-plane.md`). The spare is one of iceoryx2's loans per publisher (two by
/// default) and is always handed out first, so a module can still hold as many loans at
/// once as before.
pub struct SlicePublisher<H: SliceMessage> {
    port: Rc<SlicePort<H>>,
    out: Outlet,
}

impl<H: SliceMessage> fmt::Debug for SlicePublisher<H> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SlicePublisher")
            .field("channel", &self.out.channel)
            .finish_non_exhaustive()
    }
}

impl<H: SliceMessage> SlicePublisher<H> {
    /// The channel's name.
    pub fn channel(&self) -> &str {
        &self.out.channel
    }

    /// Publishes that had to wake a sleeping subscriber (the rest cost no system call).
    pub fn notifications(&self) -> u64 {
        self.out.notified.get()
    }

    /// The longest payload that fits the current segment (it grows on demand).
    pub fn capacity(&self) -> usize {
        self.port.max_len.get()
    }

    /// Loans `len` uninitialised elements in shared memory.
    #[inline]
    pub fn loan_uninit(&self, len: usize) -> Result<SliceLoanUninit<'_, H>, Error> {
        let sample = self.port.loan(&self.out.channel, len)?;
        Ok(SliceLoanUninit {
            sample,
            publisher: self,
        })
    }

    /// Publishes a copy of a recorded payload (replay): the header's time stamp and source
    /// stay as recorded, only the sequence number is this publisher's.
    pub fn publish_recorded(&self, header: H, data: &[H::Elem]) -> Result<(), Error> {
        let mut loan = self.loan_uninit(data.len())?;
        *loan.header_mut() = header;
        let mut loan = loan.write_from_slice(data);
        let out = &self.out;
        out.stamp_recorded(loan.sample.user_header_mut().header_mut());
        loan.sample
            .send()
            .map_err(|e| Error::channel(&out.channel, "send", e))?;
        let sent = out.sent();
        self.port.refill(data.len());
        sent
    }

    /// Publishes a copy of `data` with header `header`.
    pub fn publish_copy(&self, header: H, data: &[H::Elem]) -> Result<(), Error> {
        let mut loan = self.loan_uninit(data.len())?;
        *loan.header_mut() = header;
        loan.write_from_slice(data).publish()
    }
}

/// An uninitialised slice loan; fill it with [`SliceLoanUninit::write_from_slice`] or
/// [`SliceLoanUninit::write_from_fn`].
pub struct SliceLoanUninit<'a, H: SliceMessage> {
    sample: SliceUninit<H>,
    publisher: &'a SlicePublisher<H>,
}

impl<'a, H: SliceMessage> SliceLoanUninit<'a, H> {
    /// The header (default-initialised).
    pub fn header_mut(&mut self) -> &mut H {
        self.sample.user_header_mut()
    }

    /// The payload memory, to write element by element.
    pub fn payload_mut(&mut self) -> &mut [MaybeUninit<H::Elem>] {
        self.sample.payload_mut()
    }

    /// Copies `data` in (its length must equal the loan's).
    pub fn write_from_slice(self, data: &[H::Elem]) -> SliceLoan<'a, H> {
        SliceLoan {
            sample: self.sample.write_from_slice(data),
            publisher: self.publisher,
        }
    }

    /// Fills element `i` with `f(i)`.
    pub fn write_from_fn(self, f: impl FnMut(usize) -> H::Elem) -> SliceLoan<'a, H> {
        SliceLoan {
            sample: self.sample.write_from_fn(f),
            publisher: self.publisher,
        }
    }

    /// Declares the payload initialised.
    ///
    /// # Safety
    /// Every element must have been written through [`SliceLoanUninit::payload_mut`] (or the
    /// reader must not care about stale contents, as in a latency benchmark of plain bytes).
    #[inline]
    pub unsafe fn assume_init(self) -> SliceLoan<'a, H> {
        SliceLoan {
            // SAFETY: forwarded to the caller.
            sample: unsafe { self.sample.assume_init() },
            publisher: self.publisher,
        }
    }
}

/// An initialised slice loan, ready to publish.
pub struct SliceLoan<'a, H: SliceMessage> {
    sample: SampleMut<Service, [H::Elem], H>,
    publisher: &'a SlicePublisher<H>,
}

impl<H: SliceMessage> SliceLoan<'_, H> {
    /// The header.
    pub fn header_mut(&mut self) -> &mut H {
        self.sample.user_header_mut()
    }

    /// The payload.
    pub fn payload_mut(&mut self) -> &mut [H::Elem] {
        self.sample.payload_mut()
    }

    /// Stamps the header and publishes.
    #[inline]
    pub fn publish(mut self) -> Result<(), Error> {
        let out = &self.publisher.out;
        let len = self.sample.payload().len();
        out.stamp(self.sample.user_header_mut().header_mut());
        self.sample
            .send()
            .map_err(|e| Error::channel(&out.channel, "send", e))?;
        let sent = out.sent();
        self.publisher.port.refill(len);
        sent
    }
}

/// A received variable-size sample, still in shared memory.
pub struct SliceSample<H: SliceMessage> {
    inner: IoxSample<Service, [H::Elem], H>,
}

impl<H: SliceMessage> SliceSample<H> {
    /// The header.
    pub fn header(&self) -> &H {
        self.inner.user_header()
    }

    /// The payload.
    pub fn data(&self) -> &[H::Elem] {
        self.inner.payload()
    }
}

/// Anything that can be waited on by the executor: fixed or slice subscribers.
pub trait Waitable {
    /// The input id.
    fn input_id(&self) -> InputId;
    #[doc(hidden)]
    #[allow(private_interfaces)]
    fn erased(&self) -> Rc<dyn Input>;
}

impl<K: Kind> Waitable for Receiver<K> {
    fn input_id(&self) -> InputId {
        self.id()
    }
    #[allow(private_interfaces)]
    fn erased(&self) -> Rc<dyn Input> {
        self.as_input()
    }
}
