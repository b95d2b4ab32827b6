//! The receiver thread of `hng run`: it sleeps on `hng/report`, the command channel and the
//! termination signals (one [`Waiter`] with a signalfd), stamps each report when it arrives
//! and hands everything to the main thread, waking its poll.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::error::{Context as _, Result};
use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::ModuleReport;
use hng_runtime::system::{SUPERVISOR_COMMAND, SupervisorCommand};
use hng_runtime::wait::{WaitMode, Waiter, Wake};
use hng_runtime::{Node, NodeOptions};
use hng_watchdog::Waker;

/// What the receiver thread hands to the main thread.
pub(crate) enum Inbox {
    Report { report: ModuleReport, at: Instant },
    Command(SupervisorCommand),
    Signal(i32),
    Failed(String),
}

/// The receiver thread: reports, commands and termination signals.
pub(crate) struct Receiver {
    pub(crate) rx: mpsc::Receiver<Inbox>,
    pub(crate) stop: Arc<AtomicBool>,
    pub(crate) thread: Option<std::thread::JoinHandle<()>>,
}

impl Receiver {
    pub(crate) fn start(prefix: &str, waker: Waker) -> Result<Receiver> {
        let (tx, rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), String>>();
        let prefix = prefix.to_owned();
        let stop2 = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("hng-run-rx".into())
            .spawn(move || {
                if let Err(e) = receive_loop(&prefix, &tx, &waker, &stop2, &ready_tx) {
                    let _ = ready_tx.send(Err(format!("{e:#}")));
                    let _ = tx.send(Inbox::Failed(format!("{e:#}")));
                    let _ = waker.wake();
                }
            })
            .context("starting the receiver thread")?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Receiver {
                rx,
                stop,
                thread: Some(thread),
            }),
            Ok(Err(e)) => crate::error::bail!("receiver thread: {e}"),
            Err(_) => crate::error::bail!("the receiver thread ended before it was ready"),
        }
    }
}

fn receive_loop(
    prefix: &str,
    tx: &mpsc::Sender<Inbox>,
    waker: &Waker,
    stop: &AtomicBool,
    ready: &mpsc::Sender<Result<(), String>>,
) -> Result<()> {
    let node = Node::new(NodeOptions::new("hng-run-rx").prefix(prefix))?;
    let reports = node.subscriber::<ModuleReport>(REPORT_CHANNEL)?;
    let commands = node.subscriber::<SupervisorCommand>(SUPERVISOR_COMMAND)?;
    // Sleep at once: the supervisor is not latency-critical to the microsecond, and it must
    // not steal CPU from the modules.
    let mut waiter = Waiter::new(WaitMode::SLEEP)?;
    waiter.attach(&reports)?;
    waiter.attach(&commands)?;
    waiter.catch_termination_signals()?;
    let _ = ready.send(Ok(()));
    while !stop.load(Ordering::Acquire) {
        let wake = waiter.wait(Some(Duration::from_secs(1)))?;
        let mut any = false;
        if let Wake::Signal(sig) = wake {
            any = true;
            if tx.send(Inbox::Signal(sig)).is_err() {
                break;
            }
        }
        let at = Instant::now();
        while let Some(r) = reports.receive()? {
            any = true;
            if tx.send(Inbox::Report { report: *r, at }).is_err() {
                return Ok(());
            }
        }
        while let Some(c) = commands.receive()? {
            any = true;
            if tx.send(Inbox::Command(*c)).is_err() {
                return Ok(());
            }
        }
        if any {
            let _ = waker.wake();
        }
    }
    Ok(())
}

/// Blocks SIGINT, SIGTERM and SIGHUP in the calling thread, and so in every thread it starts
/// later. `main` calls it for `hng run` before anything else, while it is the only thread:
/// from then on these signals are only read from the receiver thread's signalfd and start the
/// orderly stop, whichever thread the kernel would have picked (a signal delivered to a thread
/// that did not block it would have killed the process by its default action).
pub fn block_termination_signals() {
    if let Err(e) = hng_runtime::wait::block_termination_signals() {
        eprintln!("hng: warning: {e}");
    }
}
