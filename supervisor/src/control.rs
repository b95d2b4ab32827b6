//! Control requests to a running system's supervisor (`hng kill/restart/start/stop`, the
//! operator page's module buttons): one [`SupervisorCommand`] on its command channel, answered
//! by the next status document.

use std::time::Duration;

use crate::error::{Context as _, Result, bail};
use hng_runtime::system::{CommandOp, SUPERVISOR_COMMAND, SupervisorCommand};

use crate::status::{StatusDoc, status_reader};

/// How long a tool waits for the supervisor's status (it is published at least twice a second).
pub const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);

/// Sends one command and waits for the supervisor's acknowledgement; returns the document
/// that acknowledges it. `tool` names the caller's node.
pub fn command(prefix: &str, cmd: SupervisorCommand, tool: &str) -> Result<StatusDoc> {
    let mut reader = status_reader(prefix, tool)?;
    let before = reader.current(ANSWER_TIMEOUT)?;
    let module = cmd.module();
    if cmd.op() != Some(CommandOp::Shutdown) && before.module(module).is_none() {
        bail!(
            "no module {module:?} in system {:?} (prefix {prefix:?}); its modules: {}",
            before.system,
            before.names()
        );
    }
    let publisher = reader
        .node()
        .publisher::<SupervisorCommand>(SUPERVISOR_COMMAND)
        .context("opening the supervisor's command channel")?;
    publisher.update_connections();
    publisher
        .publish(cmd)
        .context("sending the command to the supervisor")?;
    let seen = before.commands;
    let doc = reader
        .next_where(ANSWER_TIMEOUT, |d| d.commands > seen)
        .context("the supervisor did not acknowledge the command")?;
    if let Some(r) = &doc.last_command
        && let Some(e) = &r.error
    {
        bail!("the supervisor refused {} {}: {e}", r.op, r.module);
    }
    Ok(doc)
}
