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
pub(super) struct Reader<K: Kind> {
    pub(super) port: K::Port,
    pub(super) inlet: Rc<Inlet>,
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
