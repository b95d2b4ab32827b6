//! The hand-over between the bus thread (which reads the channels) and the WebSocket clients:
//! one slot per topic holding only the latest frame ("latest wins"), a version per slot, and
//! a tick that wakes the clients. Nothing is ever queued: a client that is slow to read skips
//! the frames it missed, and counts them.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use axum::body::Bytes;
use axum::extract::ws::{Message, Utf8Bytes};
use tokio::sync::watch;

/// One encoded frame, encoded once for every client (a clone is a reference count).
#[derive(Debug)]
pub struct Frame {
    /// The message as sent: text `{"t": TOPIC, "v": ...}`, or, for bulk bytes (images,
    /// grids), binary: a 4-byte little-endian length, that many bytes of the JSON
    /// `{"t": TOPIC, "v": ...}` describing them, then the raw bytes (no base64).
    pub payload: Payload,
    /// The topic is the scan (the latency benchmark's frames).
    pub is_scan: bool,
    /// The source message's stamp (ns of its publisher's clock; 0 if none): what the
    /// latency benchmark measures against.
    pub stamp_ns: u64,
}

/// A frame's bytes on the WebSocket.
#[derive(Debug, Clone)]
pub enum Payload {
    /// A text message (JSON).
    Text(Utf8Bytes),
    /// A binary message (length-prefixed JSON header, then raw bytes).
    Binary(Bytes),
}

impl Payload {
    /// The WebSocket message.
    pub fn message(&self) -> Message {
        match self {
            Payload::Text(t) => Message::Text(t.clone()),
            Payload::Binary(b) => Message::Binary(b.clone()),
        }
    }

    /// The text, for a text frame.
    pub fn text(&self) -> Option<&str> {
        match self {
            Payload::Text(t) => Some(t.as_str()),
            Payload::Binary(_) => None,
        }
    }
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
                payload: Payload::Text(text.into()),
                is_scan: topic == "scan",
                stamp_ns,
            },
        );
    }

    /// Encodes `value` (the description) and `bytes` as the binary frame of `topic`.
    pub fn put_binary(&self, topic: &str, value: &serde_json::Value, bytes: &[u8], stamp_ns: u64) {
        let Some(i) = Hub::index(topic) else {
            return;
        };
        let head = serde_json::json!({ "t": topic, "v": value }).to_string();
        let Ok(len) = u32::try_from(head.len()) else {
            return;
        };
        let mut buf = Vec::with_capacity(4 + head.len() + bytes.len());
        buf.extend_from_slice(&len.to_le_bytes());
        buf.extend_from_slice(head.as_bytes());
        buf.extend_from_slice(bytes);
        self.put(
            i,
            Frame {
                payload: Payload::Binary(buf.into()),
                is_scan: topic == "scan",
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

    pub(crate) fn sent(&self, frame: &Frame) {
        self.sent.fetch_add(1, Ordering::Relaxed);
        if frame.is_scan && frame.stamp_ns > 0 {
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
        let text = frames[0].payload.text().expect("text");
        assert!(text.contains("\"v\":4"), "{text}");
        assert_eq!(skipped, 0);
        for k in 5..8 {
            hub.put_json("scan", &serde_json::json!(k), 0);
        }
        let (frames, skipped) = hub.newer(&mut seen);
        assert!(
            frames[0]
                .payload
                .text()
                .is_some_and(|t| t.contains("\"v\":7"))
        );
        assert_eq!(skipped, 2);
        assert_eq!(seen[scan], 8);
        assert!(hub.newer(&mut seen).0.is_empty());
    }

    #[test]
    fn a_binary_frame_is_its_header_length_the_json_header_and_the_raw_bytes() {
        let hub = Hub::default();
        let mut seen = hub.fresh();
        hub.put_binary("image", &serde_json::json!({ "width": 2 }), &[0, 255, 7], 5);
        let (frames, _) = hub.newer(&mut seen);
        let Payload::Binary(b) = &frames[0].payload else {
            panic!("not binary: {:?}", frames[0].payload);
        };
        let len = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
        let head: serde_json::Value = serde_json::from_slice(&b[4..4 + len]).expect("JSON");
        assert_eq!(
            head,
            serde_json::json!({ "t": "image", "v": { "width": 2 } })
        );
        assert_eq!(&b[4 + len..], &[0, 255, 7]);
        assert_eq!(frames[0].stamp_ns, 5);
        assert!(!frames[0].is_scan);
    }
}
