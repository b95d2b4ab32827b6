//! Fatal signals end a module on their first delivery.
//!
//! Rust's standard library installs a SIGSEGV and a SIGBUS handler before `main` (to print
//! "thread has overflowed its stack" when a guard page is hit). For any other SIGSEGV it
//! puts the default action back and *returns*, counting on the faulting instruction to fault
//! again. A SIGSEGV sent by `kill` (fault injection: `hng kill slam --signal SEGV`) has no
//! faulting instruction: the first one was swallowed and only a second one killed the
//! process.
//!
//! [`install`] chains a handler in front of the standard library's: a SIGSEGV or SIGBUS sent
//! by a process (`si_code <= 0`: `kill`, `tgkill`, `sigqueue`, `pidfd_send_signal`) writes one
//! line to stderr, restores the default action and re-raises the signal, so the process dies
//! of it at once (core dump as configured); a real fault goes on to the standard library's
//! handler (stack-overflow message, then the default action). Other fatal signals (SIGABRT,
//! SIGILL, SIGFPE, ...) have no handler in hng and keep their default action.
//! [`run_module`](crate::run_module) calls it; so does the `hng` executable.

use std::sync::OnceLock;

use nix::libc;

/// The actions that were in place before [`install`], index 0 for SIGSEGV, 1 for SIGBUS.
static PREVIOUS: OnceLock<[libc::sigaction; 2]> = OnceLock::new();

const SIGNALS: [libc::c_int; 2] = [libc::SIGSEGV, libc::SIGBUS];

/// Installs the chaining handler for SIGSEGV and SIGBUS (once per process; later calls do
/// nothing). Returns an error if `sigaction` fails.
pub fn install() -> std::io::Result<()> {
    if PREVIOUS.get().is_some() {
        return Ok(());
    }
    // SAFETY: a zeroed sigaction is a valid "default action, empty mask" value.
    let mut previous: [libc::sigaction; 2] = unsafe { std::mem::zeroed() };
    for (i, &sig) in SIGNALS.iter().enumerate() {
        // SAFETY: reading the current action into a valid, writable struct.
        if unsafe { libc::sigaction(sig, std::ptr::null(), &mut previous[i]) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    if PREVIOUS.set(previous).is_err() {
        return Ok(());
    }
    for &sig in &SIGNALS {
        // SAFETY: zeroed is a valid sigaction; the handler below is async-signal-safe.
        let mut action: libc::sigaction = unsafe { std::mem::zeroed() };
        action.sa_sigaction = handler as *const () as libc::sighandler_t;
        // On the alternate stack the standard library set up (a stack overflow has no stack
        // left), with the signal's details.
        action.sa_flags = libc::SA_SIGINFO | libc::SA_ONSTACK;
        // SAFETY: sa_mask is a valid sigset_t inside `action`.
        unsafe { libc::sigemptyset(&mut action.sa_mask) };
        // SAFETY: installing a valid action for a catchable signal.
        if unsafe { libc::sigaction(sig, &action, std::ptr::null_mut()) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

/// Writes `bytes` to stderr (async-signal-safe).
fn write_stderr(bytes: &[u8]) {
    // SAFETY: write(2) from a valid buffer of the given length.
    let _ = unsafe { libc::write(libc::STDERR_FILENO, bytes.as_ptr().cast(), bytes.len()) };
}

/// Formats `n` in decimal into `buf` without allocating; returns the digits.
/// Async-signal-safe: for signal handlers and pre-exec hooks.
#[must_use]
pub fn decimal(mut n: u64, buf: &mut [u8; 20]) -> &[u8] {
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 || i == 0 {
            break;
        }
    }
    &buf[i..]
}

extern "C" fn handler(sig: libc::c_int, info: *mut libc::siginfo_t, ctx: *mut libc::c_void) {
    let index = usize::from(sig == libc::SIGBUS);
    // SAFETY: the kernel passes a valid siginfo_t to an SA_SIGINFO handler.
    let code = if info.is_null() {
        0
    } else {
        unsafe { (*info).si_code }
    };
    if code <= 0 {
        // Sent by a process, not a fault: nothing will fault again, so die of it now.
        let name: &[u8] = if sig == libc::SIGBUS {
            b"SIGBUS"
        } else {
            b"SIGSEGV"
        };
        let mut buf = [0u8; 20];
        // SAFETY: for si_code <= 0 the siginfo carries the sender's pid.
        let from = if info.is_null() {
            0
        } else {
            unsafe { (*info).si_pid() }
        };
        write_stderr(b"hng: fatal signal ");
        write_stderr(name);
        write_stderr(b" sent by pid ");
        write_stderr(decimal(u64::try_from(from).unwrap_or(0), &mut buf));
        write_stderr(b": terminating with its default action\n");
        die_of(sig);
        return;
    }
    // A real fault: the standard library's handler (stack overflow check), or the default.
    let previous = PREVIOUS.get().map(|p| p[index]);
    match previous {
        Some(p)
            if p.sa_sigaction != libc::SIG_DFL
                && p.sa_sigaction != libc::SIG_IGN
                && p.sa_flags & libc::SA_SIGINFO != 0 =>
        {
            // SAFETY: the previous handler was installed with SA_SIGINFO, so it has this
            // signature; we forward the kernel's arguments unchanged.
            let f: extern "C" fn(libc::c_int, *mut libc::siginfo_t, *mut libc::c_void) =
                unsafe { std::mem::transmute(p.sa_sigaction) };
            f(sig, info, ctx);
        }
        Some(p) if p.sa_sigaction != libc::SIG_DFL && p.sa_sigaction != libc::SIG_IGN => {
            // SAFETY: a plain handler installed without SA_SIGINFO.
            let f: extern "C" fn(libc::c_int) = unsafe { std::mem::transmute(p.sa_sigaction) };
            f(sig);
        }
        // Default action: returning re-executes the faulting instruction, which faults again
        // and kills the process.
        _ => reset_default(sig),
    }
}

/// Puts the default action back for `sig`.
fn reset_default(sig: libc::c_int) {
    // SAFETY: zeroed is "SIG_DFL, empty mask, no flags".
    let action: libc::sigaction = unsafe { std::mem::zeroed() };
    // SAFETY: valid action for a catchable signal; async-signal-safe.
    unsafe { libc::sigaction(sig, &action, std::ptr::null_mut()) };
}

/// Default action for `sig`, then raise it: it is blocked while this handler runs and is
/// delivered (and kills the process) the moment the handler returns.
fn die_of(sig: libc::c_int) {
    reset_default(sig);
    // SAFETY: raise(3) is async-signal-safe.
    unsafe { libc::raise(sig) };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimals_without_allocation() {
        let mut b = [0u8; 20];
        assert_eq!(decimal(0, &mut b), b"0");
        assert_eq!(decimal(4_194_304, &mut b), b"4194304");
        assert_eq!(decimal(u64::MAX, &mut b), b"18446744073709551615");
    }
}
