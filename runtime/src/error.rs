//! Errors of the runtime.

use thiserror::Error;

/// An error of the data plane or the SDK.
#[derive(Debug, Error)]
pub enum Error {
    /// The channel name is not a valid service name.
    #[error("channel name {channel:?} is invalid: {reason}")]
    InvalidChannelName {
        /// The channel.
        channel: String,
        /// Why.
        reason: String,
    },
    /// The channel exists with another message type.
    #[error(
        "channel {channel:?} carries messages of type {found}, but this port asked for {expected}"
    )]
    TypeMismatch {
        /// The channel.
        channel: String,
        /// The type this port asked for.
        expected: String,
        /// The type the channel was created with.
        found: String,
    },
    /// An iceoryx2 operation on a channel failed.
    #[error("channel {channel:?}: {op} failed: {detail}")]
    Channel {
        /// The channel.
        channel: String,
        /// The operation.
        op: &'static str,
        /// iceoryx2's error.
        detail: String,
    },
    /// Creating the node failed.
    #[error("node {name:?}: {detail}")]
    Node {
        /// The node's name.
        name: String,
        /// What failed.
        detail: String,
    },
    /// A channel has as many ports (or processes) as its limit allows.
    #[error(
        "channel {channel:?} ({kind} channel) admits at most {limit} {what} and has them all; \
         raise the limit for the whole system with {env}=\"{kind}.{key}=N\" (see docs/data-plane.md)"
    )]
    ChannelFull {
        /// The channel.
        channel: String,
        /// The channel's kind (as `HNG_CHANNEL_LIMITS` spells it).
        kind: &'static str,
        /// `subscribers`, `publishers` or `processes (publishers + subscribers)`.
        what: &'static str,
        /// The limit key to raise (`subscribers` or `publishers`).
        key: &'static str,
        /// The channel's limit.
        limit: usize,
        /// The variable to set.
        env: &'static str,
    },
    /// A slice larger than the channel's largest allowed sample.
    #[error("channel {channel:?}: a payload of {len} elements exceeds the limit of {max}")]
    TooLarge {
        /// The channel.
        channel: String,
        /// Requested length.
        len: usize,
        /// Largest length.
        max: usize,
    },
    /// A termination signal arrived while waiting (see [`crate::wait::Waiter::wait_for`]).
    #[error("interrupted by signal {signal}")]
    Interrupted {
        /// The signal's number.
        signal: i32,
    },
    /// The module's configuration or environment is invalid.
    #[error("configuration: {0}")]
    Config(String),
    /// An operating-system call failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
}

impl Error {
    pub(crate) fn channel(channel: &str, op: &'static str, detail: impl std::fmt::Debug) -> Error {
        Error::Channel {
            channel: channel.to_string(),
            op,
            detail: format!("{detail:?}"),
        }
    }

    pub(crate) fn io(context: impl Into<String>, source: impl Into<std::io::Error>) -> Error {
        Error::Io {
            context: context.into(),
            source: source.into(),
        }
    }
}
