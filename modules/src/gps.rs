//! GPS/IMU: localization from the GPS-like sensor (Table 1: provides "Localization"; data out:
//! position). Backed here by the simulator's `sim/gps` (`PoseWithCovariance` in `map`, absent
//! during an outage), relayed on `pose_out`.
//!
//! Quality Q ([`gps_quality`]) falls with the reported position standard deviation σ: 1 at or
//! below `sigma_good_m`, -1 at or above `sigma_bad_m`, linear in between. In a degraded zone
//! the simulator reports a larger σ, so Q drops; in an outage no fix arrives and after
//! `fix_timeout_s` Q is -1 with aptitude 0. This is what lets a client switch to SLAM there.

use hng_runtime::channel::InputId;
use hng_runtime::contract::ServiceOffer;
use hng_runtime::msg::PoseWithCovariance;
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{field_error, positive, seconds};

/// Configuration of `hng module gps`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct GpsModuleConfig {
    /// Fixes from the device (default `sim/gps`).
    #[default("sim/gps".into())]
    pub fix_in: String,
    /// Position published (default `gps/pose`).
    #[default("gps/pose".into())]
    pub pose_out: String,
    /// No fix for this long: Q = -1, aptitude 0, s (default 1.0).
    #[default(1.0)]
    pub fix_timeout_s: f64,
    /// σ at or below which Q is 1, m (default 0.1).
    #[default(0.1)]
    pub sigma_good_m: f64,
    /// σ at or above which Q is -1, m (default 1.0).
    #[default(1.0)]
    pub sigma_bad_m: f64,
}

/// Position σ of a fix: the square root of the larger of its x and y variances (NaN if they
/// are not finite and non-negative).
pub fn position_sigma(fix: &PoseWithCovariance) -> f64 {
    let (vx, vy) = (fix.covariance[0], fix.covariance[4]);
    if vx.is_finite() && vy.is_finite() && vx >= 0.0 && vy >= 0.0 {
        vx.max(vy).sqrt()
    } else {
        f64::NAN
    }
}

/// Q of a fix with position σ `sigma`: 1 at `good`, -1 at `bad`, linear in between; -1 for NaN.
pub fn gps_quality(sigma: f64, good: f64, bad: f64) -> f32 {
    if sigma.is_nan() {
        return -1.0;
    }
    let t = ((sigma - good) / (bad - good)).clamp(0.0, 1.0);
    (1.0 - 2.0 * t) as f32
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct GpsState {
    fixes: u64,
    outages: u64,
    last_sigma_m: f64,
}

/// The GPS/IMU localization module.
#[derive(Debug)]
pub struct GpsModule {
    fix_in: Subscriber<PoseWithCovariance>,
    pose_out: Publisher<PoseWithCovariance>,
    good: f64,
    bad: f64,
    state: GpsState,
}

impl Module for GpsModule {
    type Config = GpsModuleConfig;

    fn configure(ctx: &mut Context, cfg: GpsModuleConfig) -> ModuleResult<Self> {
        let timeout = seconds("fix_timeout_s", cfg.fix_timeout_s)?;
        positive("sigma_good_m", cfg.sigma_good_m)?;
        if !(cfg.sigma_bad_m.is_finite() && cfg.sigma_bad_m > cfg.sigma_good_m) {
            return Err(field_error("sigma_bad_m", "must be finite and > sigma_good_m").into());
        }
        // Provides "Localization" on `pose_out`; its Q falls with σ (see `gps_quality`), so
        // a client switches to SLAM in a degraded zone and back after.
        let mut offer = ServiceOffer::new("Localization", "hng/PoseWithCovariance/v1");
        offer.channel = cfg.pose_out.clone();
        ctx.provide(offer);
        ctx.set_quality(false, -1.0);
        Ok(GpsModule {
            fix_in: ctx.subscribe(&cfg.fix_in, Some(timeout))?,
            pose_out: ctx.publisher(&cfg.pose_out)?,
            good: cfg.sigma_good_m,
            bad: cfg.sigma_bad_m,
            state: GpsState::default(),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        while let Some(fix) = self.fix_in.receive()? {
            let sigma = position_sigma(&fix);
            let q = gps_quality(sigma, self.good, self.bad);
            ctx.set_quality(!sigma.is_nan(), q);
            self.state.fixes += 1;
            self.state.last_sigma_m = sigma;
            if sigma.is_nan() {
                continue;
            }
            self.pose_out.publish(*fix)?; // restamped, frame kept
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::info!(module = ctx.name(), "no GPS fix");
        self.state.outages += 1;
        ctx.set_quality(false, -1.0);
        Ok(())
    }

    hng_runtime::checkpoint_field!(state);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gps_quality_falls_with_the_reported_covariance() {
        let (good, bad) = (0.1, 1.0);
        assert_eq!(gps_quality(0.05, good, bad), 1.0);
        let nominal = gps_quality(0.3, good, bad);
        let degraded = gps_quality(1.5, good, bad); // the simulator's degraded zone: σ × 5
        assert!(nominal > 0.4 && nominal < 0.6, "{nominal}");
        assert_eq!(degraded, -1.0);
        assert!(gps_quality(0.5, good, bad) < nominal);
        assert_eq!(gps_quality(f64::NAN, good, bad), -1.0);
        let fix = PoseWithCovariance {
            covariance: [0.09, 0.0, 0.0, 0.0, 0.04, 0.0, 0.0, 0.0, 0.001],
            ..Default::default()
        };
        assert!((position_sigma(&fix) - 0.3).abs() < 1e-12);
        let bad_fix = PoseWithCovariance {
            covariance: [-1.0; 9],
            ..Default::default()
        };
        assert!(position_sigma(&bad_fix).is_nan());
    }
}
