//! The hand-over between the bus thread (which reads the channels) and the WebSocket clients:
//! one slot per topic holding only the latest frame ("latest wins"), a version per slot, and
//! a tick that wakes the clients. Nothing is ever queued: a client that is slow to read skips
//! the frames it missed, and counts them.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use tokio::sync::watch;

/// One encoded frame: the WebSocket text message `{"t": TOPIC, "v": ...}`.
#[derive(Debug)]
pub struct Frame {
    /// The message as sent.
    pub text: Arc<str>,
    /// The source message's stamp (ns of its publisher's clock; 0 if none): what the
    /// latency benchmark measures against.
    pub stamp_ns: u64,
}

/// A topic's slot.
#[derive(Debug)]
struct Slot {
    name: &'static str,
    version: AtomicU64,
    frame: Mutex<Option<Arc<Frame>>>,
}

/// The topics the page receives, in the order they are sent after a tick.
pub const TOPICS: &[&str] = &[
    "clock",
    "order_status",
    "pose",
    "truth",
    "odom",
    "scan",
    "waypoint",
    "path",
    "goal",
    "beacons",
    "tracks",
    "behaviours",
    "designation",
    "mission",
    "events",
    "status",
    "contracts",
    "map",
    "slam_map",
    "image",
];

/// Figures of the live stream (the page's "stream" line and `GET /api/stats`).
#[derive(Debug, Default, serde::Serialize)]
pub struct StreamStats {
    /// Clients connected now.
    pub clients: usize,
    /// Frames sent, all clients.
    pub frames_sent: u64,
    /// Frames replaced by a newer one before a client could send them, all clients.
    pub frames_skipped: u64,
    /// Clients dropped for not reading within the send timeout.
    pub clients_dropped: u64,
}

/// Shared between the bus thread and the server.
#[derive(Debug)]
pub struct Hub {
    slots: Vec<Slot>,
    tick: watch::Sender<u64>,
    clients: AtomicUsize,
    sent: AtomicU64,
    skipped: AtomicU64,
    dropped: AtomicU64,
    /// Scan-to-send latencies, ns (only while a benchmark asks for them).
    latencies: Mutex<Option<Vec<u64>>>,
    /// The Interface's latest answer (`seq`, the `OrderStatus` as JSON), clients or not.
    answers: watch::Sender<Option<(u32, serde_json::Value)>>,
}

impl Default for Hub {
    fn default() -> Self {
        Hub {
            slots: TOPICS
                .iter()
                .map(|n| Slot {
                    name: n,
                    version: AtomicU64::new(0),
                    frame: Mutex::new(None),
                })
                .collect(),
            tick: watch::Sender::new(0),
            clients: AtomicUsize::new(0),
            sent: AtomicU64::new(0),
            skipped: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            latencies: Mutex::new(None),
            answers: watch::Sender::new(None),
        }
    }
}

impl Hub {
    /// Index of `topic` in [`TOPICS`].
    pub fn index(topic: &str) -> Option<usize> {
        TOPICS.iter().position(|t| *t == topic)
    }

    /// Replaces the frame of topic `i` (from [`Hub::index`]); wakes the clients.
    pub fn put(&self, i: usize, frame: Frame) {
        let Some(slot) = self.slots.get(i) else {
            return;
        };
        *slot.frame.lock().unwrap_or_else(PoisonError::into_inner) = Some(Arc::new(frame));
        slot.version.fetch_add(1, Ordering::AcqRel);
        self.tick.send_modify(|t| *t += 1);
    }

    /// Encodes `value` as the frame of `topic`.
    pub fn put_json(&self, topic: &str, value: &serde_json::Value, stamp_ns: u64) {
        let Some(i) = Hub::index(topic) else {
            return;
        };
        let text = serde_json::json!({ "t": topic, "v": value }).to_string();
        self.put(
            i,
            Frame {
                text: text.into(),
                stamp_ns,
            },
        );
    }

    /// Records the Interface's answer to order `seq`.
    pub fn answer(&self, seq: u32, status: serde_json::Value) {
        self.answers.send_replace(Some((seq, status)));
    }

    /// Watches the Interface's answers.
    pub fn answers(&self) -> watch::Receiver<Option<(u32, serde_json::Value)>> {
        self.answers.subscribe()
    }

    /// The tick receivers wait on.
    pub fn subscribe(&self) -> watch::Receiver<u64> {
        self.tick.subscribe()
    }

    /// Clients connected now (the bus thread encodes nothing while there are none).
    pub fn clients(&self) -> usize {
        self.clients.load(Ordering::Acquire)
    }

    pub(crate) fn client_joined(&self) {
        self.clients.fetch_add(1, Ordering::AcqRel);
        // Wake the bus thread's next round to encode what it holds for the newcomer.
        self.tick.send_modify(|t| *t += 1);
    }

    pub(crate) fn client_left(&self) {
        self.clients.fetch_sub(1, Ordering::AcqRel);
    }

    pub(crate) fn client_dropped(&self) {
        self.dropped.fetch_add(1, Ordering::Relaxed);
    }

    /// The frames newer than `seen` (one per topic, the latest), updating `seen`; the
    /// count of frames skipped is added to the statistics and returned.
    pub fn newer(&self, seen: &mut [u64]) -> (Vec<Arc<Frame>>, u64) {
        let mut out = Vec::new();
        let mut skipped = 0;
        for (i, slot) in self.slots.iter().enumerate() {
            let v = slot.version.load(Ordering::Acquire);
            if v > seen[i] {
                if let Some(f) = slot
                    .frame
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .clone()
                {
                    out.push(f);
                }
                if seen[i] > 0 {
                    skipped += v - seen[i] - 1;
                }
                seen[i] = v;
            }
        }
        self.skipped.fetch_add(skipped, Ordering::Relaxed);
        (out, skipped)
    }

    /// A version vector for a new client (nothing seen).
    pub fn fresh(&self) -> Vec<u64> {
        vec![0; self.slots.len()]
    }

    pub(crate) fn sent(&self, frame: &Frame, topic_is_scan: bool) {
        self.sent.fetch_add(1, Ordering::Relaxed);
        if topic_is_scan && frame.stamp_ns > 0 {
            let now = hng_runtime::clock::monotonic_ns();
            if let Some(l) = self
                .latencies
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .as_mut()
            {
                l.push(now.saturating_sub(frame.stamp_ns));
            }
        }
    }

    /// Starts (or restarts) recording scan-to-send latencies.
    pub fn measure_latency(&self) {
        *self
            .latencies
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = Some(Vec::new());
    }

    /// The latencies recorded so far (and stops recording).
    pub fn take_latencies(&self) -> Vec<u64> {
        self.latencies
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
            .unwrap_or_default()
    }

    /// The stream's figures.
    pub fn stats(&self) -> StreamStats {
        StreamStats {
            clients: self.clients(),
            frames_sent: self.sent.load(Ordering::Relaxed),
            frames_skipped: self.skipped.load(Ordering::Relaxed),
            clients_dropped: self.dropped.load(Ordering::Relaxed),
        }
    }

    /// The name of slot `i`.
    pub fn name(&self, i: usize) -> &'static str {
        self.slots.get(i).map_or("", |s| s.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slow_reader_gets_the_latest_frame_and_counts_the_rest() {
        let hub = Hub::default();
        let mut seen = hub.fresh();
        let scan = Hub::index("scan").unwrap();
        for k in 0..5 {
            hub.put_json("scan", &serde_json::json!(k), 0);
        }
        let (frames, skipped) = hub.newer(&mut seen);
        // The first frame a client sees is not a skip; a new client starts from the latest.
        assert_eq!(frames.len(), 1);
        assert!(frames[0].text.contains("\"v\":4"), "{}", frames[0].text);
        assert_eq!(skipped, 0);
        for k in 5..8 {
            hub.put_json("scan", &serde_json::json!(k), 0);
        }
        let (frames, skipped) = hub.newer(&mut seen);
        assert!(frames[0].text.contains("\"v\":7"));
        assert_eq!(skipped, 2);
        assert_eq!(seen[scan], 8);
        assert!(hub.newer(&mut seen).0.is_empty());
    }
}
