//! Fixed-size channels' publishing side: publishers, loans and received samples.

use super::*;

/// Publishes fixed-size messages of type `T`.
///
/// After each publish the publisher loans the sample for the next one (its *spare*), while
/// nothing waits for it; see [the spare sample](SlicePublisher#the-spare-sample).
pub struct Publisher<T: Message> {
    /// Declared first: dropped before the port.
    pub(super) spare: Cell<Option<FixedUninit<T>>>,
    pub(super) port: Rc<IoxPublisher<Service, T, ()>>,
    pub(super) out: Outlet,
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

    /// [`Publisher::publish`], waking a sleeping subscriber only if `gate` (called once the
    /// sample is out) says so: lockstep answers wake the simulator once per round.
    pub(crate) fn publish_gated(
        &self,
        mut msg: T,
        gate: impl FnOnce() -> bool,
    ) -> Result<(), Error> {
        self.out.stamp(msg.header_mut());
        self.send_gated(self.uninit()?.write_payload(msg), gate)
    }

    /// Sends a stamped sample, then loans the next spare.
    #[inline]
    fn send(&self, sample: SampleMut<Service, T, ()>) -> Result<(), Error> {
        self.send_gated(sample, || true)
    }

    #[inline]
    fn send_gated(
        &self,
        sample: SampleMut<Service, T, ()>,
        gate: impl FnOnce() -> bool,
    ) -> Result<(), Error> {
        sample
            .send()
            .map_err(|e| Error::channel(&self.out.channel, "send", e))?;
        let sent = self.out.sent_gated(gate);
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

/// A received message, still in shared memory (or copied out of it, when it was kept for the
/// next lockstep round); dereferences to the message.
pub struct Sample<T: Message> {
    pub(super) inner: Received<IoxSample<Service, T, ()>, T>,
}

/// A received sample in shared memory, or copied out of it (it then borrows no sample of
/// the subscriber's few, see [`crate::qos::Qos::borrowed`]).
pub(super) enum Received<S, C> {
    Shared(S),
    Copied(C),
}

impl<T: Message> Sample<T> {
    /// The same message, copied out of shared memory.
    pub(super) fn copied(self) -> Sample<T> {
        Sample {
            inner: Received::Copied(*self),
        }
    }
}

impl<T: Message> Deref for Sample<T> {
    type Target = T;
    fn deref(&self) -> &T {
        match &self.inner {
            Received::Shared(s) => s.payload(),
            Received::Copied(c) => c,
        }
    }
}

impl<T: Message> fmt::Debug for Sample<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        (**self).fmt(f)
    }
}
