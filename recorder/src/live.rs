//! The live view: a Foxglove WebSocket server (the Foxglove SDK's, subprotocol
//! `foxglove.sdk.v1`) fed with the recorder's channels, schemas and encodings.
//!
//! The SDK runs the server on its own tokio runtime, in the recorder's thread's process
//! (`hng foxglove`, or the supervisor for `hng run --foxglove`), never in a module. Logging a
//! message to it only queues it: each client has a bounded queue that drops its oldest
//! message when full ([`BACKLOG`]), so a slow client sees the latest data, late, and never
//! slows the recorder, let alone a module.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::Error;
use crate::codec::SchemaDesc;

/// Default address of the live view.
pub const DEFAULT_ADDR: &str = "ws://127.0.0.1:8765";

/// Messages queued per client before the oldest are dropped.
pub const BACKLOG: usize = 256;

/// A running live view.
pub struct Live {
    ctx: Arc<foxglove::Context>,
    server: foxglove::WebSocketServerHandle,
}

/// `ws://HOST:PORT`, `HOST:PORT` or `PORT` as host and port.
pub fn parse_addr(addr: &str) -> Result<(String, u16), Error> {
    let a = addr
        .strip_prefix("ws://")
        .unwrap_or(addr)
        .trim_end_matches('/');
    let (host, port) = match a.rsplit_once(':') {
        Some((h, p)) => (h.to_string(), p),
        None => ("127.0.0.1".to_string(), a),
    };
    let port: u16 = port.parse().map_err(|_| {
        Error::Other(format!(
            "live view address {addr:?}: expected ws://HOST:PORT (e.g. {DEFAULT_ADDR})"
        ))
    })?;
    Ok((host.trim_matches(['[', ']']).to_string(), port))
}

impl Live {
    /// Starts the server on `addr` (port 0: any free port).
    pub fn start(addr: &str) -> Result<Live, Error> {
        let (host, port) = parse_addr(addr)?;
        let ctx = foxglove::Context::new();
        let server = ctx
            .websocket_server()
            .name("hng")
            .bind(host.clone(), port)
            .message_backlog_size(BACKLOG)
            .start_blocking()
            .map_err(|e| Error::Other(format!("live view on {host}:{port}: {e}")))?;
        tracing::info!(
            "live view (Foxglove WebSocket) on ws://{host}:{}",
            server.port()
        );
        println!("live view: ws://{host}:{}", server.port());
        Ok(Live { ctx, server })
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.server.port()
    }

    /// Advertises a channel.
    pub(crate) fn channel(
        &self,
        name: &str,
        type_name: &str,
        schema: &SchemaDesc,
    ) -> Result<Arc<foxglove::RawChannel>, Error> {
        let mut meta = BTreeMap::new();
        meta.insert("hng.type".to_string(), type_name.to_string());
        self.ctx
            .channel_builder(name)
            .message_encoding(schema.message_encoding)
            .schema(foxglove::Schema::new(
                schema.name.clone(),
                schema.encoding,
                schema.data.clone(),
            ))
            .metadata(meta)
            .build_raw()
            .map_err(|e| Error::Other(format!("live view channel {name}: {e}")))
    }

    /// Stops the server (clients are disconnected).
    pub fn stop(self) {
        self.server.stop().detach_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(
            parse_addr(DEFAULT_ADDR).unwrap(),
            ("127.0.0.1".into(), 8765)
        );
        assert_eq!(
            parse_addr("localhost:9000").unwrap(),
            ("localhost".into(), 9000)
        );
        assert_eq!(parse_addr("0").unwrap(), ("127.0.0.1".into(), 0));
        assert!(parse_addr("ws://host:x").is_err());
    }
}
