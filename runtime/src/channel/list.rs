//! The channels that exist under a prefix, as `hng topic list` and the recorder see them.

use iceoryx2::prelude::*;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern;
use serde::Serialize;

use super::{Service, iceoryx_config};
use crate::Error;

/// One publish-subscribe channel of the bus.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ChannelListing {
    /// The channel's name.
    pub name: String,
    /// Its iceoryx2 type name (a slice channel's header type).
    #[serde(rename = "type")]
    pub type_name: String,
    /// Processes (nodes) attached to it, when known.
    pub nodes: Option<usize>,
    /// Samples a new subscriber receives from the past.
    pub history: usize,
    /// The largest buffer a subscriber may ask for.
    pub buffer: usize,
}

/// The publish-subscribe channels under `prefix`, sorted by name.
///
/// # Errors
/// An invalid prefix, or iceoryx2 failing to list its services.
pub fn list_channels(prefix: &str) -> Result<Vec<ChannelListing>, Error> {
    let config = iceoryx_config(prefix)?;
    let mut out = Vec::new();
    <Service as iceoryx2::service::Service>::list(&config, |d| {
        if let MessagingPattern::PublishSubscribe(ps) = d.static_details.messaging_pattern() {
            let t = ps.message_type_details();
            let header = t.user_header.type_name().to_string();
            out.push(ChannelListing {
                name: d.static_details.name().to_string(),
                type_name: if header == "()" {
                    t.payload.type_name().to_string()
                } else {
                    header
                },
                nodes: d.dynamic_details.as_ref().map(|dy| dy.nodes.len()),
                history: ps.history_size(),
                buffer: ps.subscriber_max_buffer_size(),
            });
        }
        CallbackProgression::Continue
    })
    .map_err(|e| Error::channel(&format!("{prefix}*"), "listing the channels", e))?;
    out.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(out)
}
