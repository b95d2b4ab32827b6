//! The sending side: the orders thread publishes the operator's orders, teleop commands and
//! designations the moment they arrive (it sleeps on its queue, never on a period); the
//! control thread sends module commands to the supervisor and waits for its
//! acknowledgement, exactly as `hng kill`/`hng restart` do, without holding up an order.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender};
use std::time::{Duration, Instant};

use hng_runtime::msg::{DESIGNATION_CHANNEL, Designation, ORDER_CHANNEL, Order, OrderKind, Twist};
use hng_runtime::system::status::StatusDoc;
use hng_runtime::system::{
    CommandOp, JsonInfo, SUPERVISOR_COMMAND, SUPERVISOR_STATUS, SupervisorCommand,
};
use hng_runtime::wait::{WaitMode, Waiter};

use crate::orders::ModuleOp;

/// The teleop channel (the Interface's `teleop_in`).
pub const TELEOP_CHANNEL: &str = "hng/teleop";

/// How long a module command waits for the supervisor's acknowledgement.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);

/// Something to publish.
#[derive(Debug)]
pub enum Outgoing {
    /// An order.
    Order(Box<Order>),
    /// A teleop command.
    Teleop(Twist),
    /// A designation.
    Designate(Designation),
}

/// A module command and where to answer.
#[derive(Debug)]
pub struct ModuleCommand {
    /// What.
    pub op: ModuleOp,
    /// Which module.
    pub module: String,
    /// Signal number for `kill`.
    pub signal: i32,
    /// The answer: what was done, or why not.
    pub reply: tokio::sync::oneshot::Sender<Result<String, String>>,
}

/// The orders thread: runs until `stop` is set or every sender is gone.
pub fn orders(
    prefix: &str,
    rx: &Receiver<Outgoing>,
    stop: &AtomicBool,
) -> Result<(), crate::Error> {
    let node = crate::bus::node(prefix, "hng-gui-orders")?;
    let order = node.publisher::<Order>(ORDER_CHANNEL)?;
    let teleop = node.publisher::<Twist>(TELEOP_CHANNEL)?;
    let designation = node.publisher::<Designation>(DESIGNATION_CHANNEL)?;
    while !stop.load(Ordering::Acquire) {
        match rx.recv_timeout(Duration::from_millis(250)) {
            Ok(Outgoing::Order(o)) => {
                order.update_connections();
                if let Err(e) = order.publish(*o) {
                    tracing::warn!("operator page: publishing an order: {e}");
                }
                let kind = OrderKind::from_u32(o.kind).map_or("?", OrderKind::name);
                tracing::info!(seq = o.seq, kind, "operator page: order sent");
            }
            Ok(Outgoing::Teleop(t)) => {
                if let Err(e) = teleop.publish(t) {
                    tracing::warn!("operator page: publishing teleop: {e}");
                }
            }
            Ok(Outgoing::Designate(d)) => {
                if let Err(e) = designation.publish(d) {
                    tracing::warn!("operator page: publishing a designation: {e}");
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        // Late subscribers of the designation (a state channel) get the latest one.
        node.update_connections();
    }
    Ok(())
}

/// The control thread: module commands to the supervisor, one at a time.
pub fn control(
    prefix: &str,
    rx: &Receiver<ModuleCommand>,
    stop: &AtomicBool,
) -> Result<(), crate::Error> {
    let node = crate::bus::node(prefix, "hng-gui-control")?;
    let commands = node.publisher::<SupervisorCommand>(SUPERVISOR_COMMAND)?;
    let status = node.slice_subscriber::<JsonInfo>(SUPERVISOR_STATUS)?;
    let mut waiter = Waiter::new(WaitMode::SLEEP)?;
    waiter.attach(&status)?;
    // The supervisor's status, typed (the schema `hng ps` and the resource manager read).
    let mut last: Option<StatusDoc> = None;
    let mut read = |waiter: &mut Waiter, until: Instant, pred: &dyn Fn(&StatusDoc) -> bool| loop {
        while let Ok(Some(s)) = status.receive() {
            match serde_json::from_slice::<StatusDoc>(s.data()) {
                Ok(d) => last = Some(d),
                Err(e) => tracing::debug!("a supervisor status that does not parse: {e}"),
            }
        }
        if let Some(v) = &last
            && pred(v)
        {
            return Some(v.clone());
        }
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return None;
        }
        if waiter.wait(Some(left)).is_err() {
            return None;
        }
    };
    while !stop.load(Ordering::Acquire) {
        let cmd = match rx.recv_timeout(Duration::from_millis(250)) {
            Ok(c) => c,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        let answer = (|| -> Result<String, String> {
            let before = read(&mut waiter, deadline, &|_| true).ok_or_else(|| {
                "no status from the supervisor (is the system running?)".to_owned()
            })?;
            if before.module(&cmd.module).is_none() {
                return Err(format!(
                    "no module {:?}; the modules: {}",
                    cmd.module,
                    before.names()
                ));
            }
            let op = match cmd.op {
                ModuleOp::Kill => CommandOp::Kill,
                ModuleOp::Restart => CommandOp::Restart,
                ModuleOp::Start => CommandOp::Start,
                ModuleOp::Stop => CommandOp::Stop,
            };
            let mut c = SupervisorCommand::new(op, &cmd.module);
            c.signal = cmd.signal;
            let seen = before.commands;
            commands.update_connections();
            commands
                .publish(c)
                .map_err(|e| format!("sending the command: {e}"))?;
            let doc = read(&mut waiter, deadline, &|d| d.commands > seen)
                .ok_or_else(|| "the supervisor did not acknowledge the command".to_owned())?;
            match doc.last_command.as_ref().and_then(|r| r.error.as_deref()) {
                Some(e) => Err(format!("the supervisor refused: {e}")),
                None => Ok(format!("{:?} {} done", cmd.op, cmd.module).to_lowercase()),
            }
        })();
        let _ = cmd.reply.send(answer);
    }
    Ok(())
}

/// Both senders of a running server.
#[derive(Debug, Clone)]
pub struct Senders {
    /// To the orders thread.
    pub out: Sender<Outgoing>,
    /// To the control thread.
    pub control: Sender<ModuleCommand>,
}
