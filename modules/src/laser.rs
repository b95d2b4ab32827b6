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
use hng_runtime::msg::LaserScan;
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::seconds;
use crate::scan::{is_malformed, scan_quality};

/// Configuration of `hng module laser`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct LaserModuleConfig {
    /// The device's scans (default `sim/scan`).
    #[default("sim/scan".into())]
    pub scan_in: String,
    /// Relayed scans (default `laser/scan`).
    #[default("laser/scan".into())]
    pub scan_out: String,
    /// No scan for this long means the device is gone, s (default 0.5).
    #[default(0.5)]
    pub scan_timeout_s: f64,
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

    hng_runtime::checkpoint_field!(state);
}
