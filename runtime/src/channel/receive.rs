//! The receiving side of every channel: subscribers of fixed-size and slice messages, and
//! what the executor waits on.

use super::*;

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
    /// Whether the port holds samples; `None` when iceoryx2 could not tell (a connection to
    /// a publisher, or to a segment it just reallocated, could not be opened yet).
    #[doc(hidden)]
    fn has_samples(port: &Self::Port) -> Option<bool>;
    #[doc(hidden)]
    fn update_connections(port: &Self::Port);
    #[doc(hidden)]
    fn header(sample: &Self::Sample) -> &Header;
    /// The sample copied out of shared memory (kept for the next lockstep round without
    /// borrowing one of the subscriber's few samples).
    #[doc(hidden)]
    fn copied(sample: Self::Sample) -> Self::Sample;
    /// A subscriber of this kind on `channel`.
    #[doc(hidden)]
    fn subscriber(node: &Node, channel: &str) -> Result<Receiver<Self>, Error>
    where
        Self: Sized;
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
        Ok(port.receive()?.map(|s| Sample {
            inner: Received::Shared(s),
        }))
    }
    fn has_samples(port: &Self::Port) -> Option<bool> {
        port.has_samples().ok()
    }
    fn update_connections(port: &Self::Port) {
        let _ = port.update_connections();
    }
    fn header(sample: &Sample<T>) -> &Header {
        (**sample).header()
    }
    fn copied(sample: Sample<T>) -> Sample<T> {
        sample.copied()
    }
    fn subscriber(node: &Node, channel: &str) -> Result<Subscriber<T>, Error> {
        node.subscriber(channel)
    }
}

impl<H: SliceMessage> Kind for Slice<H> {
    type Port = IoxSubscriber<Service, [H::Elem], H>;
    type Sample = SliceSample<H>;
    const NAME: &'static str = "SliceSubscriber";
    #[inline]
    fn receive(port: &Self::Port) -> Result<Option<SliceSample<H>>, ReceiveError> {
        Ok(port.receive()?.map(|s| SliceSample {
            inner: Received::Shared(s),
        }))
    }
    fn has_samples(port: &Self::Port) -> Option<bool> {
        port.has_samples().ok()
    }
    fn update_connections(port: &Self::Port) {
        let _ = port.update_connections();
    }
    fn header(sample: &SliceSample<H>) -> &Header {
        sample.header().header()
    }
    fn copied(sample: SliceSample<H>) -> SliceSample<H> {
        sample.copied()
    }
    fn subscriber(node: &Node, channel: &str) -> Result<SliceSubscriber<H>, Error> {
        node.slice_subscriber(channel)
    }
}

/// Anything the executor can wait on.
pub(crate) trait Input {
    fn inlet(&self) -> &Rc<Inlet>;
    /// A message is waiting (possibly one that waits for the next lockstep round).
    fn has_samples(&self) -> bool;
    /// A message may be handled now: in lockstep, one sent before the current round
    /// (those sent in it are set aside for the next one, see [`crate::clock::lockstep`]).
    fn handleable(&self) -> bool;
}

/// The receiving port of either kind and what the executor watches.
pub(super) struct Reader<K: Kind> {
    pub(super) port: K::Port,
    pub(super) inlet: Rc<Inlet>,
    /// Messages sent in the lockstep round this node is handling, copied out and kept for
    /// the next round (oldest first; see [`Header::round`]).
    pub(super) held: RefCell<VecDeque<K::Sample>>,
    /// A message taken from the port by [`Input::handleable`] to learn that it may be
    /// handled now; the next [`Receiver::receive`] returns it first.
    pub(super) peeked: RefCell<Option<K::Sample>>,
}

impl<K: Kind> Reader<K> {
    /// True if the oldest kept message may be handled now (its round has passed).
    fn held_ready(&self) -> bool {
        self.held
            .borrow()
            .front()
            .is_some_and(|s| !self.inlet.is_current_round(K::header(s)))
    }

    /// The next message that may be handled now: the peeked one, then the kept ones whose
    /// round has passed, then the port's (keeping those sent in the current round).
    /// `counted`: see [`Receiver::receive_counted`].
    #[inline]
    fn next(&self, counted: bool) -> Result<Option<K::Sample>, Error> {
        let peeked = self.peeked.borrow_mut().take();
        let s = match peeked {
            Some(s) => s,
            None if self.held_ready() => return Ok(self.held.borrow_mut().pop_front()),
            None => match self.next_from_port(counted)? {
                Some(s) => s,
                None => return Ok(None),
            },
        };
        self.inlet.account(K::header(&s));
        Ok(Some(s))
    }

    /// The port's next message that may be handled now, not yet counted as received (a
    /// look is not a receipt); those sent in the current round are counted, copied out and
    /// kept for the next one.
    #[inline]
    fn next_from_port(&self, counted: bool) -> Result<Option<K::Sample>, Error> {
        let (published, empty) = if counted {
            self.inlet.known_empty()
        } else {
            (0, false)
        };
        if empty {
            return Ok(None);
        }
        loop {
            let next = K::receive(&self.port)
                .map_err(|e| Error::channel(&self.inlet.channel, "receive", e))?;
            let Some(s) = next else {
                if counted {
                    self.inlet.looked(published, true);
                }
                return Ok(None);
            };
            if counted {
                self.inlet.looked(published, false);
            }
            if self.inlet.is_current_round(K::header(&s)) {
                self.inlet.account(K::header(&s));
                self.held.borrow_mut().push_back(K::copied(s));
                continue;
            }
            return Ok(Some(s));
        }
    }
}

impl Inlet {
    /// The publish count to read before looking at the port, and whether the port is known
    /// empty at that count (nothing published since it was found empty): then there is no
    /// need to ask iceoryx2, whose look walks every publisher slot of the channel (128 on the
    /// report and control channels). Always `false` on a channel with history.
    #[inline]
    fn known_empty(&self) -> (u32, bool) {
        if !self.counted {
            return (0, false);
        }
        let published = self.wake.published();
        (published, self.empty_at.get() == Some(published))
    }

    /// What a look at the port found, at the count [`Inlet::known_empty`] read before it.
    #[inline]
    fn looked(&self, published: u32, empty: bool) {
        if self.counted {
            self.empty_at.set(empty.then_some(published));
        }
    }
}

impl<K: Kind> Input for Reader<K> {
    fn inlet(&self) -> &Rc<Inlet> {
        &self.inlet
    }
    fn has_samples(&self) -> bool {
        if self.peeked.borrow().is_some() || self.held_ready() {
            return true;
        }
        // The count first: a sample published after this read moves it (see crate::wake).
        let (published, empty) = self.inlet.known_empty();
        if empty {
            return false;
        }
        // A look that failed proves nothing: the port is not marked empty, so the next
        // look (and `receive`) asks iceoryx2 again.
        match K::has_samples(&self.port) {
            Some(has) => {
                self.inlet.looked(published, !has);
                has
            }
            None => false,
        }
    }
    fn handleable(&self) -> bool {
        if self.peeked.borrow().is_some() || self.held_ready() {
            return true;
        }
        match self.next_from_port(true) {
            Ok(Some(s)) => {
                *self.peeked.borrow_mut() = Some(s);
                true
            }
            Ok(None) => false,
            // Let the handler's own receive meet the error.
            Err(_) => true,
        }
    }
}

/// Receives messages from a channel: [`Subscriber`] for fixed-size ones, [`SliceSubscriber`]
/// for variable-size payloads.
pub struct Receiver<K: Kind> {
    pub(super) reader: Rc<Reader<K>>,
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
    ///
    /// In lockstep ([`Node::set_lockstep_round`]), a message sent in the round this node is
    /// handling is not returned now: it is copied out, kept, and returned in the next round
    /// before anything newer, so what a module handles in a round never depends on whether
    /// another module answered the same round before or after it.
    #[inline]
    pub fn receive(&self) -> Result<Option<K::Sample>, Error> {
        self.receive_counted(true)
    }

    /// [`Receiver::receive`]; `counted`: read the channel's publish count first and skip the
    /// port while nothing was published since it was last found empty. A spin leaves the
    /// count out: reading it on every poll keeps its cache line moving between the
    /// publisher's core and the spinning one, which the publisher's count update then waits
    /// for, on the message's path (30 ns of a 64-byte hop in `hng bench ipc`, spin mode).
    #[inline]
    fn receive_counted(&self, counted: bool) -> Result<Option<K::Sample>, Error> {
        self.reader.next(counted)
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
        let counted = waiter.mode() != WaitMode::Spin;
        waiter.wait_for(timeout, || self.receive_counted(counted))
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
        K::has_samples(&self.reader.port).unwrap_or(false)
    }

    /// This subscriber's statistics.
    pub fn stats(&self) -> ChannelStats {
        self.reader.inlet.stats.get()
    }

    /// The id the executor reports when this input has data or misses its deadline.
    pub fn id(&self) -> InputId {
        InputId(Rc::as_ptr(&self.reader.inlet) as usize)
    }

    /// Marks this receiver a polled input ([`crate::Context::subscribe_polled`]): a sequence
    /// gap (samples overwritten between two reads) is then not counted as a loss.
    pub(crate) fn set_polled(&self) {
        self.reader.inlet.polled.set(true);
    }

    pub(crate) fn as_input(&self) -> Rc<dyn Input> {
        self.reader.clone()
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

#[cfg(test)]
mod tests {
    use crate::channel::{Node, NodeOptions};
    use crate::msg::{GridInfo, Twist};
    use crate::shm;

    #[test]
    fn in_lockstep_a_message_sent_in_the_current_round_waits_for_the_next() {
        let prefix = shm::unique_prefix("holdround");
        let a = Node::new(NodeOptions::new("a").prefix(&prefix)).expect("node a");
        let b = Node::new(NodeOptions::new("b").prefix(&prefix)).expect("node b");
        let publisher = a.publisher::<Twist>("t/cmd").expect("publisher");
        let subscriber = b.subscriber::<Twist>("t/cmd").expect("subscriber");
        let grids = a.slice_publisher::<GridInfo>("t/grid", 16).expect("grids");
        let grid_sub = b.slice_subscriber::<GridInfo>("t/grid").expect("grid sub");

        // Outside lockstep nothing is held.
        publisher.publish(Twist::new(1.0, 0.0)).expect("publish");
        assert_eq!(
            subscriber.receive().expect("rx").expect("outside").linear_x,
            1.0
        );

        // Round 5: `a` sends one message before the round (4) and two in it.
        a.set_lockstep_round(4);
        publisher.publish(Twist::new(2.0, 0.0)).expect("publish");
        a.set_lockstep_round(5);
        b.set_lockstep_round(5);
        publisher.publish(Twist::new(3.0, 0.0)).expect("publish");
        publisher.publish(Twist::new(4.0, 0.0)).expect("publish");
        grids
            .publish_copy(GridInfo::default(), &[7, 8, 9])
            .expect("grid");
        let got = subscriber
            .receive()
            .expect("rx")
            .expect("sent before the round");
        assert_eq!((got.linear_x, got.header.round), (2.0, 4));
        assert!(
            subscriber.receive().expect("rx").is_none(),
            "sent in round 5: held"
        );
        assert!(grid_sub.receive().expect("rx").is_none(), "held");
        assert!(
            !subscriber.has_samples(),
            "nothing to hand out in this round"
        );

        // Round 6: the held messages come first, in order, copied out of shared memory
        // (more of them than the subscriber may borrow at once).
        b.set_lockstep_round(6);
        a.set_lockstep_round(6);
        publisher.publish(Twist::new(5.0, 0.0)).expect("publish");
        assert!(subscriber.has_samples());
        let x: Vec<f64> = std::iter::from_fn(|| subscriber.receive().expect("rx"))
            .map(|s| s.linear_x)
            .collect();
        assert_eq!(x, [3.0, 4.0], "round 6's own message waits for round 7");
        let g = grid_sub
            .receive()
            .expect("rx")
            .expect("grid in the next round");
        assert_eq!(g.data(), &[7, 8, 9]);
        b.set_lockstep_round(7);
        assert_eq!(subscriber.latest().expect("rx").expect("5").linear_x, 5.0);
        drop((publisher, subscriber, grids, grid_sub, a, b));
        shm::remove_prefix_files(&prefix);
    }

    /// The executor calls a handler for the inputs [`crate::wait::Waiter::ready`] lists: an
    /// input holding only messages of the current round is not among them (a handler called
    /// for it would find nothing, yet run; whether it did depended on how fast the writer
    /// answered the round: two runs with one seed drifted apart).
    #[test]
    fn in_lockstep_an_input_with_only_current_round_messages_is_not_ready() {
        let prefix = shm::unique_prefix("readyround");
        let a = Node::new(NodeOptions::new("a").prefix(&prefix)).expect("node a");
        let b = Node::new(NodeOptions::new("b").prefix(&prefix)).expect("node b");
        let publisher = a.publisher::<Twist>("t/cmd").expect("publisher");
        let subscriber = b.subscriber::<Twist>("t/cmd").expect("subscriber");
        let mut waiter = crate::wait::Waiter::new(crate::wait::WaitMode::SLEEP).expect("waiter");
        waiter.attach(&subscriber).expect("attach");

        a.set_lockstep_round(5);
        b.set_lockstep_round(5);
        publisher.publish(Twist::new(1.0, 0.0)).expect("publish");
        assert!(waiter.any_ready(), "a message is there");
        assert_eq!(waiter.ready().count(), 0, "but it is round 5's: not now");
        assert!(
            !waiter.any_ready(),
            "set aside for round 6, it wakes nobody"
        );

        // Round 6: ready, and the sample peeked at is the one received, once.
        b.set_lockstep_round(6);
        a.set_lockstep_round(6);
        publisher.publish(Twist::new(2.0, 0.0)).expect("publish");
        assert_eq!(waiter.ready().collect::<Vec<_>>(), [subscriber.id()]);
        let a_sample = subscriber.receive().expect("rx").expect("round 5's");
        assert_eq!(a_sample.linear_x, 1.0);
        assert!(
            subscriber.receive().expect("rx").is_none(),
            "round 6's waits"
        );
        assert_eq!(waiter.ready().count(), 0);

        // Outside lockstep, a message is ready at once; peeking loses nothing.
        b.set_lockstep_round(0);
        a.set_lockstep_round(0);
        publisher.publish(Twist::new(3.0, 0.0)).expect("publish");
        assert_eq!(waiter.ready().count(), 1);
        assert_eq!(
            waiter.ready().count(),
            1,
            "peeking twice takes nothing more"
        );
        assert_eq!(
            subscriber.stats().received,
            2,
            "1 and the kept 2; a look at 3 is not a receipt"
        );
        let x: Vec<f64> = std::iter::from_fn(|| subscriber.receive().expect("rx"))
            .map(|s| s.linear_x)
            .collect();
        assert_eq!(x, [2.0, 3.0]);
        assert_eq!(subscriber.stats().received, 3);
        drop((waiter, publisher, subscriber, a, b));
        shm::remove_prefix_files(&prefix);
    }
}
