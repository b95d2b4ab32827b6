//! systemd integration for `hng run` as a `Type=notify` service
//! (see `docs/hng.service`).
//!
//! All functions do nothing unless `NOTIFY_SOCKET` is set, so they can be
//! called unconditionally. Typical use:
//!
//! ```no_run
//! use std::time::Instant;
//! use hng_watchdog::systemd::SdNotify;
//! let mut sd = SdNotify::from_env();
//! // ... modules started ...
//! sd.ready();
//! loop {
//!     // in the event loop, with the supervisor's poll timeout at most
//!     // sd.next_ping_in(Instant::now()):
//!     sd.ping_if_due(Instant::now());
//! #   break;
//! }
//! sd.stopping();
//! ```

use std::time::{Duration, Instant};

use sd_notify::NotifyState;

/// Notification state of this process towards systemd.
#[derive(Debug, Clone)]
pub struct SdNotify {
    enabled: bool,
    /// Half of `WATCHDOG_USEC`, if the unit has `WatchdogSec=`.
    ping_every: Option<Duration>,
    last_ping: Option<Instant>,
}

impl SdNotify {
    /// Read `NOTIFY_SOCKET`, `WATCHDOG_USEC` and `WATCHDOG_PID`.
    pub fn from_env() -> Self {
        let enabled = std::env::var_os("NOTIFY_SOCKET").is_some();
        let ping_every = if enabled {
            sd_notify::watchdog_enabled().map(|d| d / 2)
        } else {
            None
        };
        Self {
            enabled,
            ping_every,
            last_ping: None,
        }
    }

    /// Is systemd listening?
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// How often `WATCHDOG=1` must be sent (half of `WatchdogSec=`).
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.ping_every
    }

    fn send(&self, states: &[NotifyState<'_>]) {
        if !self.enabled {
            return;
        }
        if let Err(e) = sd_notify::notify(states) {
            tracing::warn!("sd_notify failed: {e}");
        }
    }

    /// `READY=1`: every module has been started.
    pub fn ready(&mut self) {
        self.send(&[NotifyState::Ready]);
    }

    /// `STATUS=...`: free text shown by `systemctl status`.
    pub fn status(&self, text: &str) {
        self.send(&[NotifyState::Status(text)]);
    }

    /// `STOPPING=1`: orderly shutdown has begun.
    pub fn stopping(&self) {
        self.send(&[NotifyState::Stopping]);
    }

    /// Send `WATCHDOG=1` if half the watchdog interval has passed since the
    /// last ping. Returns true if a ping was sent.
    pub fn ping_if_due(&mut self, now: Instant) -> bool {
        let Some(every) = self.ping_every else {
            return false;
        };
        if self
            .last_ping
            .is_some_and(|t| now.saturating_duration_since(t) < every)
        {
            return false;
        }
        self.last_ping = Some(now);
        self.send(&[NotifyState::Watchdog]);
        true
    }

    /// Time until the next ping is due (`None`: no watchdog). Use it to bound
    /// the supervisor's poll timeout.
    pub fn next_ping_in(&self, now: Instant) -> Option<Duration> {
        let every = self.ping_every?;
        Some(match self.last_ping {
            Some(t) => (t + every).saturating_duration_since(now),
            None => Duration::ZERO,
        })
    }
}
