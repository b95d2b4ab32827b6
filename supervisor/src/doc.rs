//! Reading JSON documents that a running system keeps on state channels (the supervisor's
//! status, the Manager's mission, ...): the latest document is there for a tool that joins
//! late, and the next one is waited for without polling.

use std::marker::PhantomData;
use std::time::{Duration, Instant};

use crate::error::{Context as _, Result, bail};
use hng_runtime::channel::{Service, iceoryx_config};
use hng_runtime::system::JsonInfo;
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, SliceSubscriber};
use serde::de::DeserializeOwned;

/// Fails with a clear message (`what` and `hint` say who should publish it) when nothing has
/// ever published on `channel` under `prefix`; checked without creating any file.
pub fn ensure_channel_exists(prefix: &str, channel: &str, what: &str, hint: &str) -> Result<()> {
    let config = iceoryx_config(prefix)?;
    let name = iceoryx2::prelude::ServiceName::new(channel)
        .map_err(|e| crate::error::HostError::msg(format!("service name {channel:?}: {e:?}")))?;
    let details = <Service as iceoryx2::service::Service>::details(
        &name,
        &config,
        iceoryx2::service::messaging_pattern::MessagingPattern::PublishSubscribe,
    )
    .map_err(|e| {
        crate::error::HostError::msg(format!("looking up {what} of prefix {prefix:?}: {e:?}"))
    })?;
    if details.is_none() {
        bail!("no {what} runs under prefix {prefix:?} (no channel {channel}); {hint}");
    }
    Ok(())
}

/// A subscriber to a channel of JSON documents of type `T`.
pub struct DocReader<T> {
    sub: SliceSubscriber<JsonInfo>,
    waiter: Waiter,
    node: Node,
    what: String,
    _doc: PhantomData<T>,
}

impl<T: DeserializeOwned> DocReader<T> {
    /// Opens `channel` under `prefix` as the tool `tool`; `what` names the document in errors.
    pub fn open(prefix: &str, channel: &str, tool: &str, what: &str) -> Result<DocReader<T>> {
        let node =
            Node::new(NodeOptions::new(&format!("{tool}-{}", std::process::id())).prefix(prefix))
                .context("creating a node")?;
        let sub = node
            .slice_subscriber::<JsonInfo>(channel)
            .with_context(|| format!("subscribing to {what} ({channel})"))?;
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&sub)?;
        Ok(DocReader {
            sub,
            waiter,
            node,
            what: what.to_owned(),
            _doc: PhantomData,
        })
    }

    /// The node (to open more ports).
    pub fn node(&self) -> &Node {
        &self.node
    }

    /// The next document that satisfies `pred`, waiting up to `timeout`.
    pub fn next_where(&mut self, timeout: Duration, mut pred: impl FnMut(&T) -> bool) -> Result<T> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(s) = self.sub.receive()? {
                let doc: T = serde_json::from_slice(s.data())
                    .with_context(|| format!("{} is not a valid document", self.what))?;
                if pred(&doc) {
                    return Ok(doc);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!(
                    "no answer from {} of prefix {:?} within {timeout:?} (is the system still running?)",
                    self.what,
                    self.node.prefix()
                );
            }
            self.waiter.wait(Some(left))?;
        }
    }

    /// The current document.
    pub fn current(&mut self, timeout: Duration) -> Result<T> {
        self.next_where(timeout, |_| true)
    }
}
