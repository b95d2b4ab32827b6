//! Stopping `hng eval nav` cleanly: SIGTERM, SIGINT and SIGHUP set a flag (the handler does
//! nothing else, async-signal-safe); the problem loop sees it, stops the current problem's
//! `hng run` in order (SIGTERM: its modules in reverse order, its prefix files removed) and
//! ends with 128 + the signal. Each `hng run` is started with a parent-death signal (SIGTERM),
//! so an eval killed outright (SIGKILL) still has its current run stop in order.

use std::io;
use std::os::unix::process::CommandExt as _;
use std::process::Command;
use std::sync::atomic::{AtomicI32, Ordering};

use nix::libc;
use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};

/// The termination signal received (0: none).
static REQUESTED: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    REQUESTED.store(sig, Ordering::SeqCst);
}

/// Installs the handlers of SIGTERM, SIGINT and SIGHUP.
pub fn install() -> nix::Result<()> {
    let action = SigAction::new(
        SigHandler::Handler(on_signal),
        SaFlags::SA_RESTART,
        SigSet::empty(),
    );
    for sig in [Signal::SIGTERM, Signal::SIGINT, Signal::SIGHUP] {
        // SAFETY: the handler only stores into an atomic, which is async-signal-safe.
        unsafe { sigaction(sig, &action) }?;
    }
    Ok(())
}

/// The termination signal received, if any.
pub fn requested() -> Option<i32> {
    match REQUESTED.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// Makes `cmd`'s process receive SIGTERM when this process dies (`PR_SET_PDEATHSIG`); if this
/// process is already gone when the child sets it, the spawn fails instead of leaving an
/// orphan.
pub fn terminate_with_parent(cmd: &mut Command) {
    // SAFETY: getpid before the fork; the closure runs between fork and exec and only makes
    // async-signal-safe syscalls (prctl, getppid) with integer arguments, allocating nothing.
    let parent = unsafe { libc::getpid() };
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(
                libc::PR_SET_PDEATHSIG,
                libc::SIGTERM as libc::c_ulong,
                0,
                0,
                0,
            ) != 0
            {
                return Err(io::Error::last_os_error());
            }
            if libc::getppid() != parent {
                return Err(io::Error::from_raw_os_error(libc::ESRCH));
            }
            Ok(())
        });
    }
}
