//! Localization: wheel odometry fused with GPS/IMU fixes by an extended Kalman filter
//! ([`crate::ekf`]). Provides "Localization" (`PoseWithCovariance` in `map` on `pose_out`);
//! needs "Odometry" (rank 1, from the Robot), followed on its provider's channel like SLAM's
//! (the configured `odom` channel while it has no provider). The fixes are read from `fix_in`
//! (default `gps/pose`, the GPS/IMU module's output: when that module dies, no fix arrives).
//!
//! The pose is published at the odometry rate (every odometry batch) and after every fix,
//! once the filter has started at its first fix.
//!
//! Quality Q: from the filter's own position σ (the 1σ ellipse's semi-major axis) with the
//! GPS module's formula ([`crate::gps::gps_quality`]: 1 at or below `sigma_good_m`, -1 at or
//! above `sigma_bad_m`, linear between), so a fused estimate (σ about 0.05-0.1 m) is worth more
//! than a raw fix (σ 0.3 m, Q about 0.56) and wins the contract. The inputs dying loses it:
//! without odometry for `odom_timeout_s`, aptitude 0 and Q -1 (clients reconfigure to the
//! GPS or SLAM); without fixes the covariance grows with distance and time, so Q falls, and
//! after `fix_timeout_s` without a fused fix aptitude is 0 as well (dead reckoning is not
//! trusted for longer).
//!
//! The operator's pose estimate ([`crate::initial_pose`], `initial_pose_in`): the filter
//! restarts there, keeping the odometry scale it learnt (as a far fix would only after
//! `max_rejections` fixes gated out).
//!
//! Checkpoint: the filter's mean, covariance and the odometry reading it goes with, so a
//! restarted module goes on from where it was plus the odometry since, and the estimate
//! applied last, so a restart does not apply it again.

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::ProviderInput;
use hng_runtime::msg::{FrameId, Header, Odometry, PoseWithCovariance};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{field_error, non_negative, positive, seconds};
use crate::ekf::{Ekf, EkfParams, EkfState, FixOutcome};
use crate::gps::gps_quality;
use crate::initial_pose::{EstimateId, INITIAL_POSE_CHANNEL, InitialPoseInput};

/// Configuration of `hng module localization`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct LocalizationConfig {
    /// Odometry while no provider is contracted (default `robot/odom`).
    #[default("robot/odom".into())]
    pub odom: String,
    /// Pose fixes (default `gps/pose`).
    #[default("gps/pose".into())]
    pub fix_in: String,
    /// Fused pose published (default `localization/pose`).
    #[default("localization/pose".into())]
    pub pose_out: String,
    /// No odometry for this long: aptitude 0, s (default 0.5).
    #[default(0.5)]
    pub odom_timeout_s: f64,
    /// No fused fix for this long: aptitude 0, s (default 20).
    #[default(20.0)]
    pub fix_timeout_s: f64,
    /// σ at or below which Q is 1, m (default 0.1).
    #[default(0.1)]
    pub sigma_good_m: f64,
    /// σ at or above which Q is -1, m (default 1.0).
    #[default(1.0)]
    pub sigma_bad_m: f64,
    /// Noise and gate of the filter.
    #[default(EkfParams::default())]
    pub filter: EkfParams,
    /// The operator's pose estimates: the filter restarts at each (default
    /// `operator/initial_pose`; empty: none taken). See [`crate::initial_pose`].
    #[default(INITIAL_POSE_CHANNEL.into())]
    pub initial_pose_in: String,
}

/// Rank of the "Odometry" need.
pub const ODOMETRY_NEED: u16 = 1;

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct LocState {
    filter: EkfState,
    fused: u64,
    rejected: u64,
    /// The operator's estimate applied last (not applied again after a restart).
    estimate: Option<EstimateId>,
}

/// The localization module.
#[derive(Debug)]
pub struct LocalizationModule {
    ekf: Ekf,
    params: EkfParams,
    odom: ProviderInput<Odometry>,
    fix_in: Subscriber<PoseWithCovariance>,
    initial_pose: Option<InitialPoseInput>,
    pose_out: Publisher<PoseWithCovariance>,
    good: f64,
    bad: f64,
    fix_timeout_ns: u64,
    odom_ok: bool,
    /// Stamp of the last odometry message, ns.
    last_odom_ns: Option<u64>,
    /// Stamp (odometry time) of the last fused fix, ns.
    last_fix_ns: Option<u64>,
    state: LocState,
}

impl LocalizationModule {
    fn now_ns(&self) -> Option<u64> {
        self.last_odom_ns
    }

    /// Sets aptitude and Q from the filter's σ and the inputs' health.
    fn rate(&self, ctx: &mut Context) {
        let fix_fresh = match (self.now_ns(), self.last_fix_ns) {
            (Some(now), Some(fix)) => now.saturating_sub(fix) <= self.fix_timeout_ns,
            (None, Some(_)) => true,
            _ => false,
        };
        let apt = self.odom_ok && fix_fresh && self.ekf.pose().is_some();
        let q = if apt {
            gps_quality(self.ekf.position_sigma(), self.good, self.bad)
        } else {
            -1.0
        };
        ctx.set_quality(apt, q);
    }

    fn publish(&mut self) -> ModuleResult {
        if let Some(pose) = self.ekf.pose() {
            self.pose_out.publish(PoseWithCovariance {
                header: Header {
                    frame_id: FrameId::MAP,
                    ..Header::default()
                },
                pose,
                covariance: self.ekf.covariance(),
            })?;
        }
        Ok(())
    }
}

impl Module for LocalizationModule {
    type Config = LocalizationConfig;
    /// 2: the checkpoint names the operator's estimate applied last.
    const STATE_VERSION: u32 = 2;

    fn configure(ctx: &mut Context, cfg: LocalizationConfig) -> ModuleResult<Self> {
        let odom_timeout = seconds("odom_timeout_s", cfg.odom_timeout_s)?;
        let fix_timeout = seconds("fix_timeout_s", cfg.fix_timeout_s)?;
        positive("sigma_good_m", cfg.sigma_good_m)?;
        if !(cfg.sigma_bad_m.is_finite() && cfg.sigma_bad_m > cfg.sigma_good_m) {
            return Err(field_error("sigma_bad_m", "must be finite and > sigma_good_m").into());
        }
        let f = &cfg.filter;
        for (name, v) in [
            ("filter.linear_per_m", f.linear_per_m),
            ("filter.angular_per_rad", f.angular_per_rad),
            ("filter.angular_per_m", f.angular_per_m),
            ("filter.position_per_sqrt_s", f.position_per_sqrt_s),
            ("filter.heading_per_sqrt_s", f.heading_per_sqrt_s),
            ("filter.scale_sigma", f.scale_sigma),
            ("filter.scale_per_sqrt_m", f.scale_per_sqrt_m),
        ] {
            non_negative(name, v)?;
        }
        positive("filter.gate", f.gate)?;
        if f.max_rejections == 0 {
            return Err(field_error("filter.max_rejections", "must be at least 1").into());
        }
        let mut offer = ServiceOffer::new("Localization", "hng/PoseWithCovariance/v1");
        offer.channel = cfg.pose_out.clone();
        ctx.provide(offer);
        ctx.need(NeedSpec::required("Odometry", ODOMETRY_NEED));
        ctx.set_quality(false, -1.0);
        // A slow check of the fix timeout while fixes are missing (odometry drives `rate`).
        let _ = ctx.add_timer(Duration::from_millis(500));
        Ok(LocalizationModule {
            ekf: Ekf::new(cfg.filter),
            params: cfg.filter,
            odom: ProviderInput::new()
                .with_deadline(Some(odom_timeout))
                .with_fallback(ctx, &cfg.odom)?,
            fix_in: ctx.subscribe(&cfg.fix_in, None)?,
            initial_pose: InitialPoseInput::new(ctx, &cfg.initial_pose_in)?,
            pose_out: ctx.publisher(&cfg.pose_out)?,
            good: cfg.sigma_good_m,
            bad: cfg.sigma_bad_m,
            fix_timeout_ns: u64::try_from(fix_timeout.as_nanos()).unwrap_or(u64::MAX),
            odom_ok: false,
            last_odom_ns: None,
            last_fix_ns: None,
            state: LocState::default(),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if self.odom.is(input) {
            let mut got = false;
            while let Some(o) = self.odom.receive()? {
                let stamp = o.header.stamp_ns;
                let dt = self
                    .last_odom_ns
                    .map_or(0.0, |t| stamp.saturating_sub(t) as f64 * 1e-9);
                self.ekf.predict(o.pose, dt);
                self.last_odom_ns = Some(stamp);
                got = true;
            }
            if got {
                self.odom_ok = true;
                self.rate(ctx);
                self.publish()?;
            }
        } else if input == self.fix_in.id() {
            let mut got = false;
            while let Some(fix) = self.fix_in.receive()? {
                match self.ekf.update(fix.pose, &fix.covariance) {
                    FixOutcome::Initialised | FixOutcome::Fused(_) => {
                        self.state.fused += 1;
                        self.last_fix_ns = self.last_odom_ns.or(Some(0));
                        got = true;
                    }
                    FixOutcome::Reset(d2) => {
                        tracing::warn!(
                            module = ctx.name(),
                            d2,
                            "every recent fix gated out: filter restarted at the fix"
                        );
                        self.state.rejected += 1;
                        self.last_fix_ns = self.last_odom_ns.or(Some(0));
                        got = true;
                    }
                    FixOutcome::Rejected(d2) => {
                        self.state.rejected += 1;
                        tracing::debug!(module = ctx.name(), d2, "fix gated out");
                    }
                    FixOutcome::Invalid => {
                        tracing::debug!(module = ctx.name(), "unusable fix ignored");
                    }
                }
            }
            self.rate(ctx);
            if got {
                self.publish()?;
            }
        } else if let Some(ip) = &mut self.initial_pose
            && ip.is(input)
            && let Some(p) = ip.take(
                ctx.name(),
                "filter restarted at the operator's pose estimate",
            )?
        {
            // The operator knows better: the filter restarts there (keeping the odometry
            // scale it learnt), and the next fixes are fused from there.
            self.ekf.restart_at(p.pose, &p.covariance);
            self.last_fix_ns = self.last_odom_ns.or(Some(0));
            self.rate(ctx);
            self.publish()?;
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        self.rate(ctx);
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no odometry: cannot localize");
        self.odom_ok = false;
        ctx.set_quality(false, -1.0);
        Ok(())
    }

    hng_runtime::follow_needs!(ODOMETRY_NEED => odom);

    hng_runtime::checkpoint_with!(Self::save_state, Self::load_state);
}

impl LocalizationModule {
    fn save_state(&self) -> LocState {
        LocState {
            filter: self.ekf.state(),
            estimate: self
                .initial_pose
                .as_ref()
                .and_then(InitialPoseInput::applied),
            ..self.state
        }
    }

    fn load_state(&mut self, s: LocState) -> ModuleResult {
        self.ekf = Ekf::resume(self.params, &s.filter);
        if let Some(ip) = &mut self.initial_pose {
            ip.restore(s.estimate);
        }
        self.state = s;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::harness::Harness;
    use hng_runtime::msg::Pose2D;

    fn near(p: &PoseWithCovariance, x: f64, y: f64) -> bool {
        (p.pose.x - x).hypot(p.pose.y - y) < 0.05
    }

    fn estimate(x: f64, y: f64, theta: f64, frame_id: FrameId) -> PoseWithCovariance {
        PoseWithCovariance {
            header: Header {
                frame_id,
                ..Header::default()
            },
            pose: Pose2D::new(x, y, theta),
            covariance: [0.0; 9],
        }
    }

    /// The module's own loop (in-process harness): it starts at the first fix, restarts at
    /// the operator's pose estimate far from it (beyond the fixes' gate), and refuses an
    /// estimate that is not in the map frame.
    #[test]
    fn the_filter_restarts_at_the_operators_estimate_and_refuses_one_outside_the_map_frame() {
        let mut h = Harness::new("localization").unwrap();
        let odom = h.input::<Odometry>("robot/odom").unwrap();
        let fix = h.input::<PoseWithCovariance>("gps/pose").unwrap();
        let initial = h.input::<PoseWithCovariance>(INITIAL_POSE_CHANNEL).unwrap();
        let mut pose = h.output::<PoseWithCovariance>("localization/pose").unwrap();
        h.start::<LocalizationModule>("").unwrap();
        let mut stamp = 0;
        // Odometry of a robot standing still, again until the module answers as `pred` says.
        let mut wait = |h: &Harness,
                        pose: &mut hng_runtime::harness::Output<PoseWithCovariance>,
                        pred: &dyn Fn(&PoseWithCovariance) -> bool| {
            for _ in 0..100 {
                stamp += 20_000_000;
                odom.publish(Odometry {
                    header: Header {
                        stamp_ns: stamp,
                        frame_id: FrameId::ODOM,
                        ..Header::default()
                    },
                    ..Odometry::default()
                })
                .unwrap();
                if let Ok(p) = h.wait_for(pose, Duration::from_millis(50), pred) {
                    return p;
                }
            }
            panic!("no such pose: {:?}", pose.samples.last());
        };
        let mut first = estimate(1.0, 1.0, 0.0, FrameId::MAP);
        first.covariance = [0.09, 0.0, 0.0, 0.0, 0.09, 0.0, 0.0, 0.0, 0.01];
        fix.publish(first).unwrap();
        wait(&h, &mut pose, &|p| near(p, 1.0, 1.0));

        initial
            .publish(estimate(10.0, 5.0, 1.0, FrameId::MAP))
            .unwrap();
        let p = wait(&h, &mut pose, &|p| near(p, 10.0, 5.0));
        assert!((p.pose.theta - 1.0).abs() < 1e-6, "{p:?}");
        assert!(
            (p.covariance[0] - 0.01).abs() < 1e-3,
            "the default σ of 0.1 m: {p:?}"
        );

        // Not in the map frame: refused; the pose stays.
        initial
            .publish(estimate(0.0, 0.0, 0.0, FrameId::ODOM))
            .unwrap();
        let n = pose.samples.len();
        for _ in 0..5 {
            wait(&h, &mut pose, &|_| true);
        }
        assert!(
            pose.samples[n..].iter().all(|c| near(&c.msg, 10.0, 5.0)),
            "{:?}",
            pose.samples.last()
        );
        h.finish().unwrap();
    }
}
