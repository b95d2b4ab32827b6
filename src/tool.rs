//! What the command-line tools share to join a running system.

use anyhow::{Context as _, Result};
use hng_runtime::msg::Message;
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, Subscriber};

/// This process's node in the system under `prefix`, named `hng-TOOL-PID`.
pub(crate) fn node(prefix: &str, tool: &str) -> Result<Node> {
    Node::new(NodeOptions::new(&format!("hng-{tool}-{}", std::process::id())).prefix(prefix))
        .with_context(|| format!("cannot join the system under prefix {prefix:?}"))
}

/// A reader of `channel`: the tool's node (keep it alive), its subscriber, and a waiter
/// attached to it.
pub(crate) fn reader<T: Message>(
    prefix: &str,
    tool: &str,
    channel: &str,
) -> Result<(Node, Subscriber<T>, Waiter)> {
    let node = node(prefix, tool)?;
    let sub = node
        .subscriber::<T>(channel)
        .with_context(|| format!("cannot subscribe to {channel}"))?;
    let mut waiter = Waiter::new(WaitMode::SLEEP)?;
    waiter.attach(&sub)?;
    Ok((node, sub, waiter))
}
