//! Quality of service of every channel, defined in this one place.
//!
//! iceoryx2 fixes a service's QoS when the first process creates it; later openers must ask
//! for compatible values or the open fails. hng therefore derives the QoS from the kind of
//! channel, and the kind from the message type ([`crate::msg::Message::KIND`]), so every
//! process asks for the same values.
//!
//! | kind | history (late joiners get) | buffer | safe overflow | publishers | subscribers |
//! |---|---|---|---|---|---|
//! | `Sensor` | 0 | 8 | yes | 4 | 16 |
//! | `Command` | 0 | 4 | yes | 16 | 8 |
//! | `State` | 1 (the latest) | 4 | yes | 4 | 64 |
//! | `StateBulk` | 1 (the latest) | 2 | yes | 2 | 8 |
//! | `Bulk` | 0 | 2 | yes | 2 | 8 |
//! | `Control` | 0 | 64 | yes | 128 | 128 |
//! | `Contract` | 0 | 16 | yes | 128 | 32 |
//! | `Report` | 0 | 64 | yes | 128 | 8 |
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
}

impl ChannelKind {
    /// The QoS of this kind of channel.
    pub const fn qos(self) -> Qos {
        let (history, buffer, max_publishers, max_subscribers) = match self {
            ChannelKind::Sensor => (0, 8, 4, 16),
            ChannelKind::Command => (0, 4, 16, 8),
            ChannelKind::State => (1, 4, 4, 64),
            ChannelKind::StateBulk => (1, 2, 2, 8),
            ChannelKind::Bulk => (0, 2, 2, 8),
            ChannelKind::Control => (0, 64, 128, 128),
            ChannelKind::Contract => (0, 16, 128, 32),
            ChannelKind::Report => (0, 64, 128, 8),
        };
        Qos {
            history,
            buffer,
            borrowed: 2,
            max_publishers,
            max_subscribers,
        }
    }
}
