//! The raw iceoryx2 ends of `hng bench ipc`: the same ping-pong through the iceoryx2 API
//! directly (no header, hng's header, or hng's header with the next sample loaned ahead).

use std::mem::MaybeUninit;
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use hng_runtime::channel::{Service, iceoryx_config};
use hng_runtime::clock::monotonic_ns;
use hng_runtime::msg::BytesInfo;
use iceoryx2::prelude::*;

use super::{Endpoint, Mode, read_stamp, stamp};

/// The user header of a raw iceoryx2 end: none, or hng's.
pub(super) trait RawHeader: std::fmt::Debug + Default + ZeroCopySend + 'static {
    /// Fills the header of the sample for `round`.
    fn stamp(&mut self, round: u64);
    /// What a receiver reads of it.
    fn seq(&self) -> u64;
}

impl RawHeader for () {
    fn stamp(&mut self, _: u64) {}
    fn seq(&self) -> u64 {
        0
    }
}

impl RawHeader for BytesInfo {
    fn stamp(&mut self, round: u64) {
        self.header.seq = round;
        self.header.stamp_ns = monotonic_ns();
        self.header.source = 1;
    }
    fn seq(&self) -> u64 {
        self.header.seq ^ u64::from(self.header.source)
    }
}

pub(super) struct RawEnd<U: RawHeader> {
    _node: iceoryx2::node::Node<Service>,
    tx: iceoryx2::port::publisher::Publisher<Service, [u8], U>,
    rx: iceoryx2::port::subscriber::Subscriber<Service, [u8], U>,
    notifier: iceoryx2::port::notifier::Notifier<Service>,
    listener: iceoryx2::port::listener::Listener<Service>,
    size: usize,
    mode: Mode,
    /// Loan the next sample right after a send (`iceoryx2-spare`).
    loan_ahead: bool,
    spare: Option<iceoryx2::sample_mut_uninit::SampleMutUninit<Service, [MaybeUninit<u8>], U>>,
}

impl<U: RawHeader> RawEnd<U> {
    pub(super) fn new(
        prefix: &str,
        name: &str,
        tx: &str,
        rx: &str,
        size: usize,
        mode: Mode,
        loan_ahead: bool,
    ) -> Result<RawEnd<U>> {
        let config = iceoryx_config(prefix)?;
        let node = NodeBuilder::new()
            .name(&NodeName::new(name).map_err(|e| anyhow!("{e:?}"))?)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Service>()
            .map_err(|e| anyhow!("iceoryx2 node: {e:?}"))?;
        let open = |n: &str| -> Result<_> {
            let sn = ServiceName::new(n).map_err(|e| anyhow!("{e:?}"))?;
            let ps = node
                .service_builder(&sn)
                .publish_subscribe::<[u8]>()
                .user_header::<U>()
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(2)
                .open_or_create()
                .map_err(|e| anyhow!("iceoryx2 service {n}: {e:?}"))?;
            let ev = node
                .service_builder(&sn)
                .event()
                .open_or_create()
                .map_err(|e| anyhow!("iceoryx2 event {n}: {e:?}"))?;
            Ok((ps, ev))
        };
        let (tx_ps, tx_ev) = open(&format!("{tx}_raw"))?;
        let (rx_ps, rx_ev) = open(&format!("{rx}_raw"))?;
        let txp = tx_ps
            .publisher_builder()
            .initial_max_slice_len(size)
            .create()
            .map_err(|e| anyhow!("iceoryx2 publisher: {e:?}"))?;
        let rxs = rx_ps
            .subscriber_builder()
            .create()
            .map_err(|e| anyhow!("iceoryx2 subscriber: {e:?}"))?;
        let notifier = tx_ev
            .notifier_builder()
            .create()
            .map_err(|e| anyhow!("iceoryx2 notifier: {e:?}"))?;
        let listener = rx_ev
            .listener_builder()
            .create()
            .map_err(|e| anyhow!("iceoryx2 listener: {e:?}"))?;
        Ok(RawEnd {
            _node: node,
            tx: txp,
            rx: rxs,
            notifier,
            listener,
            size,
            mode,
            loan_ahead,
            spare: None,
        })
    }
}

impl<U: RawHeader> Endpoint for RawEnd<U> {
    fn send(&mut self, round: u64) -> Result<()> {
        let loan = match self.spare.take() {
            Some(loan) => loan,
            None => self
                .tx
                .loan_slice_uninit(self.size)
                .map_err(|e| anyhow!("loan: {e:?}"))?,
        };
        // SAFETY: plain bytes; only the stamp is meaningful to the reader.
        let mut s = unsafe { loan.assume_init() };
        stamp(s.payload_mut(), round);
        s.user_header_mut().stamp(round);
        s.send().map_err(|e| anyhow!("send: {e:?}"))?;
        if self.mode.sleeps() {
            self.notifier
                .notify()
                .map_err(|e| anyhow!("notify: {e:?}"))?;
        }
        if self.loan_ahead {
            self.spare = self.tx.loan_slice_uninit(self.size).ok();
        }
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<u64>> {
        let mut end = None;
        let mut n: u32 = 0;
        loop {
            if let Some(s) = self.rx.receive().map_err(|e| anyhow!("receive: {e:?}"))? {
                std::hint::black_box(s.user_header().seq());
                return Ok(Some(read_stamp(s.payload())));
            }
            if self.mode.sleeps() {
                let end = *end.get_or_insert_with(|| Instant::now() + timeout);
                let left = end.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Ok(None);
                }
                self.listener
                    .timed_wait(|_| {}, left.min(Duration::from_millis(100)))
                    .map_err(|e| anyhow!("wait: {e:?}"))?;
            } else {
                // The floor: poll receive() alone, looking at the clock every 256 polls.
                n = n.wrapping_add(1);
                if n.is_multiple_of(256)
                    && Instant::now() >= *end.get_or_insert_with(|| Instant::now() + timeout)
                {
                    return Ok(None);
                }
                std::hint::spin_loop();
            }
        }
    }
}
