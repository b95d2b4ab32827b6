//! Quality of service of every channel, defined in this one place.
//!
//! iceoryx2 fixes a service's QoS when the first process creates it; later openers must ask
//! for compatible values or the open fails. hng therefore derives the QoS from the kind of
//! channel, and the kind from the message type ([`crate::msg::Message::KIND`]), so every
//! process asks for the same values.
//!
//! | kind | history (late joiners get) | buffer | recorder's buffer | safe overflow | publishers | subscribers |
//! |---|---|---|---|---|---|---|
//! | `Sensor` | 0 | 8 | 64 | yes | 4 | 24 |
//! | `Command` | 0 | 4 | 64 | yes | 16 | 16 |
//! | `State` | 1 (the latest) | 4 | 64 | yes | 4 | 64 |
//! | `StateBulk` | 1 (the latest) | 2 | 4 | yes | 4 | 16 |
//! | `Bulk` | 0 | 2 | 4 | yes | 2 | 16 |
//! | `Control` | 0 | 64 | 64 | yes | 128 | 128 |
//! | `Contract` | 0 | 16 | 16 | yes | 128 | 32 |
//! | `Report` | 0 | 64 | 64 | yes | 128 | 32 |
//!
//! A module's subscriber holds `buffer` samples (only fresh data matters to it). A recorder's
//! subscriber ([`crate::Node::tap_subscriber`]: `hng record`, the live view) holds the
//! recorder's buffer, so a recorder that polls its channels every few milliseconds, and is
//! sometimes not scheduled for longer, loses nothing of a channel published at up to
//! `record_buffer` samples per such gap (64 samples: 64 ms of a 1 kHz stream). The channel's
//! subscriber buffer bound is the larger of the two. A few channels have a larger built-in
//! recorder's buffer ([`BUILT_IN_RECORD_BUFFERS`]: the true pose, which the mission monitor
//! must not lose at `--speed max`). Large messages (maps, images) keep a
//! small recorder's buffer: every publisher preallocates `subscribers x (bound + 2)` samples.
//!
//! The subscriber limits leave room, beside the modules, for the tools that watch a running
//! system at once: a recorder (`hng record`), a live view (`hng foxglove`), an operator page
//! and several `hng topic echo`. A channel holds at most `publishers + subscribers` processes.
//!
//! ## Changing the limits
//! `HNG_CHANNEL_LIMITS` overrides them per kind, e.g.
//! `HNG_CHANNEL_LIMITS="sensor.subscribers=48,report.subscribers=64,bulk.publishers=4"`.
//! The first process to open a channel fixes its limits (iceoryx2 keeps the creator's QoS),
//! so every process of a system must see the same value: set it where `hng run` starts
//! (its modules inherit the environment). A port beyond a limit fails with
//! [`crate::Error::ChannelFull`], which names the channel, the limit and this variable.
//! Each publisher preallocates `subscribers x (buffer + 2)` samples, so a higher limit costs
//! shared memory on channels of large messages.
//!
//! The recorder's buffer is set the same way, per kind or per channel, for channels whose
//! rate needs more (a channel's own setting wins over its kind's):
//! `HNG_CHANNEL_LIMITS="sensor.record_buffer=256,camera/image.record_buffer=16"`.
//!

//! Every kind uses safe overflow: a full buffer drops the subscriber's oldest sample, so a
//! slow or killed subscriber can never block a publisher. Drops are detected from sequence
//! gaps and counted ([`crate::channel::ChannelStats`]).

use serde::Serialize;

/// The kind of a channel; it fixes the QoS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ChannelKind {
    /// A sensor stream (lidar, odometry, camera): only fresh data matters.
    Sensor,
    /// Commands to actuators; several clients may publish, the driver arbitrates.
    Command,
    /// State (pose, goal, mission, clock): late joiners get the latest sample.
    State,
    /// Large state (maps): late joiners get the latest sample.
    StateBulk,
    /// Large streams (images, raw bytes).
    Bulk,
    /// Supervisor commands and events.
    Control,
    /// Contract-protocol messages (module inboxes, service query channels): one publisher per
    /// peer, few subscribers, so each publisher preallocates little shared memory.
    Contract,
    /// Module reports (heartbeats).
    Report,
}

/// The QoS of a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Qos {
    /// Samples kept for subscribers that join later.
    pub history: usize,
    /// Samples a subscriber can hold unread.
    pub buffer: usize,
    /// Samples a subscriber may hold at once.
    pub borrowed: usize,
    /// Publishers at most.
    pub max_publishers: usize,
    /// Subscribers at most.
    pub max_subscribers: usize,
    /// Samples a recorder's subscriber can hold unread (the channel's subscriber buffer bound
    /// is the larger of this and `buffer`).
    pub record_buffer: usize,
}

impl Qos {
    /// The channel's bound on a subscriber's buffer.
    pub fn max_buffer(&self) -> usize {
        self.buffer.max(self.record_buffer)
    }
}

impl ChannelKind {
    /// Every kind, in the order of the table above.
    pub const ALL: [ChannelKind; 8] = [
        ChannelKind::Sensor,
        ChannelKind::Command,
        ChannelKind::State,
        ChannelKind::StateBulk,
        ChannelKind::Bulk,
        ChannelKind::Control,
        ChannelKind::Contract,
        ChannelKind::Report,
    ];

    /// The kind's name as `HNG_CHANNEL_LIMITS` spells it.
    pub const fn name(self) -> &'static str {
        match self {
            ChannelKind::Sensor => "sensor",
            ChannelKind::Command => "command",
            ChannelKind::State => "state",
            ChannelKind::StateBulk => "state_bulk",
            ChannelKind::Bulk => "bulk",
            ChannelKind::Control => "control",
            ChannelKind::Contract => "contract",
            ChannelKind::Report => "report",
        }
    }

    /// The built-in QoS of this kind of channel (without `HNG_CHANNEL_LIMITS`).
    pub const fn default_qos(self) -> Qos {
        let (history, buffer, record_buffer, max_publishers, max_subscribers) = match self {
            ChannelKind::Sensor => (0, 8, 64, 4, 24),
            ChannelKind::Command => (0, 4, 64, 16, 16),
            ChannelKind::State => (1, 4, 64, 4, 64),
            ChannelKind::StateBulk => (1, 2, 4, 4, 16),
            ChannelKind::Bulk => (0, 2, 4, 2, 16),
            ChannelKind::Control => (0, 64, 64, 128, 128),
            ChannelKind::Contract => (0, 16, 16, 128, 32),
            ChannelKind::Report => (0, 64, 64, 128, 32),
        };
        Qos {
            history,
            buffer,
            borrowed: 2,
            max_publishers,
            max_subscribers,
            record_buffer,
        }
    }

    /// The QoS of this kind of channel: the built-in values with the limits of
    /// `HNG_CHANNEL_LIMITS` (an invalid variable is reported by [`crate::Node::new`] and
    /// leaves the built-in values).
    pub fn qos(self) -> Qos {
        match ChannelLimits::from_env() {
            Ok(l) => l.qos(self),
            Err(_) => self.default_qos(),
        }
    }

    /// The QoS of `channel`, a channel of this kind: [`ChannelKind::qos`] with the channel's
    /// own recorder's buffer from `HNG_CHANNEL_LIMITS`, if it has one.
    pub fn qos_of(self, channel: &str) -> Qos {
        match ChannelLimits::from_env() {
            Ok(l) => l.qos_of(self, channel),
            Err(_) => ChannelLimits::default().qos_of(self, channel),
        }
    }
}

/// The environment variable that overrides the publisher and subscriber limits.
pub const LIMITS_ENV: &str = "HNG_CHANNEL_LIMITS";

/// Largest limit accepted (iceoryx2 preallocates per port).
pub const MAX_LIMIT: usize = 1024;

/// Largest recorder's buffer accepted, samples.
pub const MAX_RECORD_BUFFER: usize = 16384;

static PROCESS_LIMITS: std::sync::OnceLock<Result<ChannelLimits, String>> =
    std::sync::OnceLock::new();

/// Channels whose recorder's buffer is larger than their kind's unless `HNG_CHANNEL_LIMITS`
/// says otherwise: the true pose (`sim/ground_truth`), against which the mission monitor of
/// `hng run` and `hng eval nav` judges every goal. It comes at 100 Hz of simulated time, so
/// at `--speed max` (20 times real time and more) 64 samples last a few tens of milliseconds
/// of a loaded machine; 1024 last 10 s of simulated time.
pub const BUILT_IN_RECORD_BUFFERS: &[(&str, usize)] = &[("sim/ground_truth", 1024)];

/// Publisher and subscriber limits and recorder's buffers per channel kind, and recorder's
/// buffers per channel (see the module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelLimits {
    limits: [(usize, usize); 8],
    record: [usize; 8],
    channels: Vec<(String, usize)>,
}

impl Default for ChannelLimits {
    fn default() -> Self {
        let mut limits = [(0, 0); 8];
        let mut record = [0; 8];
        for (i, k) in ChannelKind::ALL.iter().enumerate() {
            let q = k.default_qos();
            limits[i] = (q.max_publishers, q.max_subscribers);
            record[i] = q.record_buffer;
        }
        ChannelLimits {
            limits,
            record,
            channels: BUILT_IN_RECORD_BUFFERS
                .iter()
                .map(|(c, n)| ((*c).to_owned(), *n))
                .collect(),
        }
    }
}

impl ChannelLimits {
    /// Parses `kind.publishers=N,kind.subscribers=N,kind.record_buffer=N,
    /// channel/name.record_buffer=N,...` (whitespace and empty items are ignored; a channel
    /// name has a `/`); the error names the item and what is wrong with it.
    pub fn parse(spec: &str) -> Result<ChannelLimits, String> {
        const FORM: &str = "expected KIND.publishers=N, KIND.subscribers=N, KIND.record_buffer=N or CHANNEL.record_buffer=N";
        let mut out = ChannelLimits::default();
        for item in spec
            .split([',', ';'])
            .map(str::trim)
            .filter(|s| !s.is_empty())
        {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| format!("{item:?}: {FORM}"))?;
            let (kind, what) = key
                .trim()
                .rsplit_once('.')
                .ok_or_else(|| format!("{item:?}: {FORM}"))?;
            let (kind, what) = (kind.trim(), what.trim());
            let max = if what == "record_buffer" {
                MAX_RECORD_BUFFER
            } else {
                MAX_LIMIT
            };
            let n: Option<usize> = value.trim().parse().ok().filter(|n| (1..=max).contains(n));
            let idx = ChannelKind::ALL.iter().position(|k| k.name() == kind);
            if idx.is_none() && kind.contains('/') {
                // A channel's own recorder's buffer.
                if what != "record_buffer" {
                    return Err(format!(
                        "{item:?}: a channel ({kind:?}) sets only its record_buffer; \
                         publishers and subscribers are set per kind"
                    ));
                }
                let n = n.ok_or_else(|| {
                    format!("{item:?}: the buffer must be a number from 1 to {max}")
                })?;
                out.channels.retain(|(c, _)| c != kind);
                out.channels.push((kind.to_string(), n));
                continue;
            }
            let idx = idx.ok_or_else(|| {
                let names: Vec<&str> = ChannelKind::ALL.iter().map(|k| k.name()).collect();
                format!(
                    "{item:?}: unknown channel kind {kind:?} (kinds: {}; a channel name has a /)",
                    names.join(", ")
                )
            })?;
            let n =
                n.ok_or_else(|| format!("{item:?}: the limit must be a number from 1 to {max}"))?;
            match what {
                "publishers" => out.limits[idx].0 = n,
                "subscribers" => out.limits[idx].1 = n,
                "record_buffer" => out.record[idx] = n,
                other => {
                    return Err(format!(
                        "{item:?}: unknown limit {other:?} (publishers, subscribers or record_buffer)"
                    ));
                }
            }
        }
        Ok(out)
    }

    /// The limits of this process: `HNG_CHANNEL_LIMITS`, read once (or those
    /// [`ChannelLimits::install`]ed before).
    pub fn from_env() -> Result<ChannelLimits, String> {
        PROCESS_LIMITS
            .get_or_init(|| match std::env::var(LIMITS_ENV) {
                Ok(spec) => ChannelLimits::parse(&spec).map_err(|e| format!("{LIMITS_ENV}: {e}")),
                Err(_) => Ok(ChannelLimits::default()),
            })
            .clone()
    }

    /// Makes `spec` (the syntax of `HNG_CHANNEL_LIMITS`, added to that variable's value) the
    /// limits of this process, for a process that creates its channels itself (a benchmark).
    /// Fails when a channel was opened already (the limits are fixed then) or the spec is bad.
    pub fn install(spec: &str) -> Result<(), String> {
        let env = std::env::var(LIMITS_ENV).unwrap_or_default();
        let l = ChannelLimits::parse(&format!("{env},{spec}"))?;
        PROCESS_LIMITS
            .set(Ok(l))
            .map_err(|_| "the channel limits of this process are fixed already".to_string())
    }

    /// The QoS of `kind` with these limits.
    pub fn qos(&self, kind: ChannelKind) -> Qos {
        let mut q = kind.default_qos();
        if let Some(i) = ChannelKind::ALL.iter().position(|k| *k == kind) {
            (q.max_publishers, q.max_subscribers) = self.limits[i];
            q.record_buffer = self.record[i];
        }
        q
    }

    /// The QoS of `channel`, of kind `kind`, with these limits.
    pub fn qos_of(&self, kind: ChannelKind, channel: &str) -> Qos {
        let mut q = self.qos(kind);
        if let Some((_, n)) = self.channels.iter().find(|(c, _)| c == channel) {
            q.record_buffer = *n;
        }
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_parse_and_override_only_what_they_name() {
        let l = ChannelLimits::parse(" sensor.subscribers=48, bulk.publishers=3 ,").unwrap();
        assert_eq!(l.qos(ChannelKind::Sensor).max_subscribers, 48);
        assert_eq!(l.qos(ChannelKind::Sensor).max_publishers, 4);
        assert_eq!(l.qos(ChannelKind::Bulk).max_publishers, 3);
        assert_eq!(
            l.qos(ChannelKind::Report),
            ChannelKind::Report.default_qos()
        );
        assert_eq!(ChannelLimits::parse("").unwrap(), ChannelLimits::default());
    }

    #[test]
    fn bad_limits_name_the_item() {
        for (spec, needle) in [
            ("sensors.subscribers=4", "unknown channel kind \"sensors\""),
            ("sensor.subs=4", "unknown limit \"subs\""),
            ("sensor.subscribers=0", "from 1 to 1024"),
            ("sensor.subscribers=x", "from 1 to 1024"),
            ("sensor=4", "expected KIND.publishers=N"),
            ("sensor.record_buffer=0", "from 1 to 16384"),
            ("laser/scan.subscribers=4", "sets only its record_buffer"),
            ("lidar.record_buffer=4", "a channel name has a /"),
        ] {
            let e = ChannelLimits::parse(spec).unwrap_err();
            assert!(e.contains(needle), "{spec}: {e}");
        }
    }

    #[test]
    fn recorder_buffers_per_kind_and_per_channel() {
        let l = ChannelLimits::parse("sensor.record_buffer=256, laser/scan.record_buffer=1024")
            .unwrap();
        assert_eq!(l.qos(ChannelKind::Sensor).record_buffer, 256);
        assert_eq!(
            l.qos_of(ChannelKind::Sensor, "robot/odom").record_buffer,
            256
        );
        assert_eq!(
            l.qos_of(ChannelKind::Sensor, "laser/scan").record_buffer,
            1024
        );
        assert_eq!(l.qos_of(ChannelKind::Sensor, "laser/scan").buffer, 8);
        assert_eq!(
            l.qos_of(ChannelKind::Sensor, "laser/scan").max_buffer(),
            1024
        );
        let d = ChannelLimits::default();
        for k in ChannelKind::ALL {
            let q = d.qos(k);
            assert!(q.record_buffer >= q.buffer, "{k:?}");
        }
    }

    #[test]
    fn defaults_fit_the_tools() {
        // Beside the modules: recorder, live view, operator page, four `hng topic echo`.
        for k in [ChannelKind::Sensor, ChannelKind::Report, ChannelKind::Bulk] {
            assert!(k.default_qos().max_subscribers >= 16, "{k:?}");
        }
    }
}
