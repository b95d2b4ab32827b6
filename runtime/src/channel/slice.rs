//! Slice channels' publishing side: a publisher of variable-length payloads (scans, images,
//! maps) on a segment that grows when a loan does not fit.

use super::*;

/// The port of a [`SlicePublisher`]: an iceoryx2 publisher whose data segment grows in
/// power-of-two steps when a loan does not fit (iceoryx2's `AllocationStrategy::PowerOfTwo`).
///
/// The publisher stays the same across a growth: iceoryx2 adds a larger segment and keeps
/// the older one while samples in it are unread, so every subscriber gets every sample in
/// order, including one that had not yet looked at its port when the segment grew. (hng used
/// to grow by replacing a static publisher with a larger one, which lost what the replaced
/// publisher had sent to a subscriber that had not yet connected to it, uncounted; the
/// growing segment costs 5-15 ns per hop in `hng bench ipc` spin mode, docs/data-plane.md.)
pub(super) struct SlicePort<H: SliceMessage> {
    pub(super) service: SliceService<H>,
    /// A sample loaned ahead for the next loan (see [`SlicePublisher`]); declared before
    /// the port so that it is dropped first.
    pub(super) spare: Cell<Option<SliceUninit<H>>>,
    /// Length of the last payload published.
    pub(super) last_len: Cell<usize>,
    pub(super) port: SliceIoxPublisher<H>,
}

impl<H: SliceMessage> SlicePort<H> {
    pub(super) fn create(
        service: &SliceService<H>,
        channel: &str,
        max_len: usize,
    ) -> Result<SliceIoxPublisher<H>, Error> {
        service
            .publisher_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
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
        self.port
            .loan_slice_uninit(len)
            .map_err(|e| Error::channel(channel, "loan", e))
    }

    /// After a publish of `len` elements: loans the spare for a next payload of the same
    /// length, if the length is steady (the same as the publish before) and there is none.
    #[inline]
    fn refill(&self, len: usize) {
        if self.last_len.replace(len) != len {
            return;
        }
        let spare = self
            .spare
            .take()
            .or_else(|| self.port.loan_slice_uninit(len).ok());
        self.spare.set(spare);
    }
}

impl<H: SliceMessage> UpdateConnections for SlicePort<H> {
    fn update_connections(
        &self,
    ) -> Result<(), iceoryx2::port::update_connections::ConnectionFailure> {
        self.port.update_connections()
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
    pub(super) port: Rc<SlicePort<H>>,
    pub(super) out: Outlet,
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

    /// Subscribers connected to the channel now (modules, recorders, live views, tools):
    /// a publisher of costly data (camera images) can skip producing what nobody reads.
    /// A subscriber of a process that died counts until iceoryx2 cleans it up.
    pub fn subscribers(&self) -> usize {
        self.port.service.dynamic_config().number_of_subscribers()
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

/// A received variable-size sample, still in shared memory (or copied out of it, when it
/// was kept for the next lockstep round).
pub struct SliceSample<H: SliceMessage> {
    pub(super) inner: Received<SharedSlice<H>, OwnedSlice<H>>,
}

/// A slice sample in shared memory.
type SharedSlice<H> = IoxSample<Service, [<H as SliceMessage>::Elem], H>;

/// A slice sample copied out of shared memory: its header and payload.
type OwnedSlice<H> = (H, Vec<<H as SliceMessage>::Elem>);

impl<H: SliceMessage> SliceSample<H> {
    /// The header.
    pub fn header(&self) -> &H {
        match &self.inner {
            Received::Shared(s) => s.user_header(),
            Received::Copied((h, _)) => h,
        }
    }

    /// The payload.
    pub fn data(&self) -> &[H::Elem] {
        match &self.inner {
            Received::Shared(s) => s.payload(),
            Received::Copied((_, d)) => d,
        }
    }

    /// The same sample, copied out of shared memory.
    pub(super) fn copied(self) -> SliceSample<H> {
        SliceSample {
            inner: Received::Copied((*self.header(), self.data().to_vec())),
        }
    }
}
