//! Laser: the lidar driver (Table 1: provides "LIDAR data"). Backed here by the simulator's
//! `sim/scan`; on a real robot this is where the device is read.
//!
//! Every scan is relayed on `scan_out` (loaned in shared memory, copied once). Scans that are
//! malformed (more beams than the message holds, a non-positive or non-finite angle step) are
//! not relayed.
//!
//! Quality Q: `1 − 2·(fraction of NaN beams)` of the last scan, -1 (aptitude 0) when scans stop
//! arriving (`scan_timeout_s`) or the last one was malformed.

use hng_runtime::channel::InputId;
use hng_runtime::msg::{LaserScan, MAX_BEAMS};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{decode_state, encode_state, seconds};
use crate::security::ScanView;

/// Configuration of `hng module laser`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LaserModuleConfig {
    /// The device's scans (default `sim/scan`).
    pub scan_in: String,
    /// Relayed scans (default `laser/scan`).
    pub scan_out: String,
    /// No scan for this long means the device is gone, s (default 0.5).
    pub scan_timeout_s: f64,
}

impl Default for LaserModuleConfig {
    fn default() -> Self {
        LaserModuleConfig {
            scan_in: "sim/scan".into(),
            scan_out: "laser/scan".into(),
            scan_timeout_s: 0.5,
        }
    }
}

/// True if a scan cannot be interpreted: no beams, more beams than the message holds, or a
/// non-finite or non-positive angle step.
pub fn is_malformed(scan: &LaserScan) -> bool {
    let inc = scan.angle_increment;
    scan.count == 0 || scan.count as usize > MAX_BEAMS || !inc.is_finite() || inc <= 0.0
}

/// Whether a scan is usable, and its quality Q in [-1, 1].
pub fn scan_quality(scan: &LaserScan) -> (bool, f32) {
    if is_malformed(scan) {
        return (false, -1.0);
    }
    let bad = ScanView::of(scan).invalid_fraction();
    (bad < 0.5, (1.0 - 2.0 * bad) as f32)
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct LaserState {
    relayed: u64,
    malformed: u64,
}

/// The Laser driver module.
#[derive(Debug)]
pub struct LaserModule {
    scan_in: Subscriber<LaserScan>,
    scan_out: Publisher<LaserScan>,
    state: LaserState,
}

impl Module for LaserModule {
    type Config = LaserModuleConfig;

    fn configure(ctx: &mut Context, cfg: LaserModuleConfig) -> ModuleResult<Self> {
        let timeout = seconds("scan_timeout_s", cfg.scan_timeout_s)?;
        // Provides "LIDAR data" on `scan_out`.
        let mut offer = hng_runtime::contract::ServiceOffer::new("LIDAR data", "hng/LaserScan/v1");
        offer.channel = cfg.scan_out.clone();
        ctx.provide(offer);
        ctx.set_quality(false, -1.0);
        Ok(LaserModule {
            scan_in: ctx.subscribe(&cfg.scan_in, Some(timeout))?,
            scan_out: ctx.publisher(&cfg.scan_out)?,
            state: LaserState::default(),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        while let Some(s) = self.scan_in.receive()? {
            let (ok, q) = scan_quality(&s);
            ctx.set_quality(ok, q);
            if is_malformed(&s) {
                self.state.malformed += 1;
                continue;
            }
            // Publishing stamps the header afresh (sequence, time, source); the frame stays.
            let mut out = self.scan_out.loan()?;
            *out = *s;
            out.publish()?;
            self.state.relayed += 1;
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no scan from the lidar");
        ctx.set_quality(false, -1.0);
        Ok(())
    }

    fn checkpoint(&self) -> Option<Vec<u8>> {
        encode_state(&self.state)
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        self.state = decode_state(state)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scan_quality_reflects_validity() {
        let mut s = LaserScan {
            count: 4,
            angle_increment: 0.01,
            ..Default::default()
        };
        s.ranges[..4].copy_from_slice(&[1.0, 2.0, f32::INFINITY, f32::NEG_INFINITY]);
        assert_eq!(scan_quality(&s), (true, 1.0));
        s.ranges[0] = f32::NAN;
        assert_eq!(scan_quality(&s), (true, 0.5));
        s.angle_increment = f32::NAN;
        assert_eq!(scan_quality(&s), (false, -1.0));
        s.angle_increment = 0.01;
        s.count = 0;
        assert!(!scan_quality(&s).0);
    }
}
