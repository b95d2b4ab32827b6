//! The run's progress lines on stdout. Nobody reading them any more (`hng run | head -1`, a
//! closed terminal, a parent that died) must neither stop the robot nor leave its files
//! behind: `println!` would panic on the broken pipe, mid-run or mid-stop. A line that cannot
//! be written is dropped; the first such failure is said once in the log.

use std::io::Write as _;
use std::sync::atomic::{AtomicBool, Ordering};

static CLOSED: AtomicBool = AtomicBool::new(false);

/// Writes one line to stdout; after a failed write, drops every later line.
pub fn line(args: std::fmt::Arguments<'_>) {
    if CLOSED.load(Ordering::Relaxed) {
        return;
    }
    let mut out = std::io::stdout().lock();
    let written = out
        .write_fmt(args)
        .and_then(|()| out.write_all(b"\n"))
        .and_then(|()| out.flush());
    if let Err(e) = written
        && !CLOSED.swap(true, Ordering::Relaxed)
    {
        tracing::warn!("stdout is closed ({e}): progress lines are dropped from now on");
    }
}

/// `println!` that never panics: [`line`].
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::stdout::line(format_args!($($arg)*))
    };
}
