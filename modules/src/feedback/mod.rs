//! Client feedback (the E term of eq. 3, paper 4.2): a client rates the provider it uses by
//! what it can check itself.
//!
//! [`OdometryConsistency`]: the Servo-controller rates its "Localization" provider. Over each
//! window of `window_s`, the motion the provider's poses show is compared with the motion the
//! odometry measured (both as increments in their own frames, so a drift-free offset between
//! the two frames does not matter). An error within the provider's own claimed uncertainty
//! (3 σ of its covariance, plus an odometry allowance of `odom_rel` of the distance moved and
//! `floor_m`) is consistent; beyond it, the evaluation falls linearly to −1 at twice the
//! allowance. Only inconsistency is reported (E ≤ 0): eq. 3 adds every judgement's E (each sent
//! once) with a decay τ, so a positive E sent every window would pile up and entrench whichever provider
//! is in use, whatever the others offer.
//!
//! [`ScanMapAgreement`] (`scan_map.rs`): Planning rates its "Mapping" provider by agreement
//! of the map with the scans.

mod scan_map;

pub use scan_map::{MapFeedbackParams, MapRating, ScanMapAgreement};

use hng_runtime::msg::{Odometry, Pose2D, PoseWithCovariance};
use hng_runtime::{Context, ModuleResult, Subscriber};
use smart_default::SmartDefault;

use crate::common::{relative, wrap_angle};
use crate::initial_pose::EstimateNotice;

/// Consistency of a pose source with odometry.
#[derive(Debug, Clone, SmartDefault)]
pub struct OdometryConsistency {
    /// Length of one comparison, s.
    #[default(1.0)]
    pub window_s: f64,
    /// Odometry allowance per metre moved.
    #[default(0.1)]
    pub odom_rel: f64,
    /// Smallest allowance, m.
    #[default(0.05)]
    pub floor_m: f64,
    base: Option<(Pose2D, Pose2D, f64)>,
    odom: Option<Pose2D>,
    /// No comparison before this time, s (see [`OdometryConsistency::hold`]).
    #[default(f64::NEG_INFINITY)]
    held_until: f64,
    /// The last evaluation and the error behind it, m.
    pub last: Option<(f64, f64)>,
}

impl OdometryConsistency {
    /// Forgets the comparison in progress (a new provider).
    pub fn reset(&mut self) {
        self.base = None;
        self.last = None;
    }

    /// No judgement until `t + window_s`: the provider is told to jump (an operator's pose
    /// estimate), and the first comparison starts from a pose after the jump.
    pub fn hold(&mut self, t: f64) {
        self.base = None;
        self.held_until = t + self.window_s;
    }

    /// Whether the provider's poses are in doubt at `t` s: within a hold, or the last window
    /// found them inconsistent (until a window finds them consistent again).
    pub fn in_doubt(&self, t: f64) -> bool {
        t < self.held_until || self.last.is_some_and(|(e, _)| e < 0.0)
    }

    /// The latest odometry pose.
    pub fn on_odom(&mut self, odom: Pose2D) {
        self.odom = Some(odom);
    }

    /// A pose of the provider at `t` s with its position standard deviation `sigma_m` (from
    /// its covariance); returns an evaluation in [-1, 0] when a window closes.
    pub fn on_pose(&mut self, pose: Pose2D, sigma_m: f64, t: f64) -> Option<f64> {
        let odom = self.odom?;
        if t < self.held_until {
            self.base = None;
            return None;
        }
        let Some((p0, o0, t0)) = self.base else {
            self.base = Some((pose, odom, t));
            return None;
        };
        if t < t0 {
            self.base = Some((pose, odom, t));
            return None;
        }
        if t - t0 < self.window_s {
            return None;
        }
        self.base = Some((pose, odom, t));
        let dp = relative(&p0, &pose);
        let dq = relative(&o0, &odom);
        let moved = dq.x.hypot(dq.y);
        let err = (dp.x - dq.x).hypot(dp.y - dq.y) + 0.5 * wrap_angle(dp.theta - dq.theta).abs();
        let sigma = if sigma_m.is_finite() {
            sigma_m.max(0.0)
        } else {
            0.0
        };
        let allowance = 3.0 * sigma + self.floor_m + self.odom_rel * moved;
        let e = if err.is_finite() {
            (1.0 - err / allowance).clamp(-1.0, 0.0)
        } else {
            -1.0
        };
        self.last = Some((e, err));
        Some(e)
    }
}

/// A client's check of its "Localization" provider: the [`OdometryConsistency`] of the poses
/// it receives, with the latest odometry and held over the operator's estimates. Both are
/// polled inputs, read when a pose comes: they wake nobody.
#[derive(Debug)]
pub struct PoseCheck {
    odom: Option<Subscriber<Odometry>>,
    estimates: Option<EstimateNotice>,
    /// The rating.
    pub rater: OdometryConsistency,
}

impl PoseCheck {
    /// Odometry from channel `odom`, estimates from channel `initial_pose` (an empty name:
    /// none; without odometry nothing is judged).
    pub fn new(ctx: &mut Context, odom: &str, initial_pose: &str) -> ModuleResult<PoseCheck> {
        Ok(PoseCheck {
            odom: if odom.is_empty() {
                None
            } else {
                Some(ctx.subscribe_polled(odom)?)
            },
            estimates: EstimateNotice::new(ctx, initial_pose)?,
            rater: OdometryConsistency::default(),
        })
    }

    /// Reads the latest odometry and whether an estimate came (a hold from `t` s); call before
    /// passing on the poses received with them.
    pub fn poll(&mut self, t: f64) -> ModuleResult {
        if let Some(odom) = &self.odom
            && let Some(o) = odom.latest()?
        {
            self.rater.on_odom(o.pose);
        }
        if let Some(e) = &mut self.estimates
            && e.new_estimate()?
        {
            self.rater.hold(t);
        }
        Ok(())
    }

    /// A pose of the provider at `t` s: an evaluation in [-1, 0] when a window closes.
    pub fn on_pose(&mut self, p: &PoseWithCovariance, t: f64) -> Option<f64> {
        self.rater.on_pose(p.pose, position_sigma(&p.covariance), t)
    }
}

/// The position standard deviation of a row-major 3x3 (x, y, θ) covariance, m.
pub fn position_sigma(cov: &[f64; 9]) -> f64 {
    (0.5 * (cov[0] + cov[4])).max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(scale: f64, sigma: f64) -> Vec<f64> {
        let mut c = OdometryConsistency::default();
        let mut out = Vec::new();
        for k in 0..50 {
            let t = k as f64 * 0.1;
            // Odometry: straight at 0.4 m/s in a frame rotated and shifted from the map.
            let d = 0.4 * t;
            c.on_odom(Pose2D::new(10.0 - d, 5.0, std::f64::consts::PI));
            let pose = Pose2D::new(1.0 + scale * d, 2.0, 0.0);
            if let Some(e) = c.on_pose(pose, sigma, t) {
                out.push(e);
            }
        }
        out
    }

    #[test]
    fn a_consistent_source_is_not_blamed_and_a_lying_one_is() {
        let good = run(1.0, 0.02);
        assert!(
            !good.is_empty() && good.iter().all(|&e| e == 0.0),
            "{good:?}"
        );
        // Reports 30 % of the motion while claiming 2 cm: -1.
        let liar = run(0.3, 0.02);
        assert!(
            !liar.is_empty() && liar.iter().all(|&e| e < -0.5),
            "{liar:?}"
        );
        // The same error within a claimed 0.3 m: consistent.
        let honest_noisy = run(0.3, 0.3);
        assert!(honest_noisy.iter().all(|&e| e == 0.0), "{honest_noisy:?}");
        assert!(
            (position_sigma(&[0.09, 0.0, 0.0, 0.0, 0.09, 0.0, 0.0, 0.0, 0.0]) - 0.3).abs() < 1e-12
        );
    }

    #[test]
    fn poses_are_in_doubt_from_an_inconsistent_window_to_a_consistent_one_and_over_a_hold() {
        let mut c = OdometryConsistency::default();
        let mut doubt = Vec::new();
        for k in 0..60 {
            let t = k as f64 * 0.1;
            // Odometry at 0.4 m/s; the source lies (30 % of the motion) from 1 s to 3 s.
            c.on_odom(Pose2D::new(0.4 * t, 0.0, 0.0));
            let lie = 0.7 * 0.4 * (t.clamp(1.0, 3.0) - 1.0);
            c.on_pose(Pose2D::new(0.4 * t - lie, 0.0, 0.0), 0.02, t);
            if k == 45 {
                c.hold(t);
            }
            doubt.push(c.in_doubt(t));
        }
        let at = |t: f64| doubt[(t * 10.0).round() as usize];
        assert!(!at(0.5) && !at(1.5), "nothing judged against it yet");
        assert!(at(2.0) && at(2.9), "the window 1-2 s was inconsistent");
        assert!(at(3.5), "so was 2-3 s");
        assert!(
            !at(4.2),
            "3-4 s was consistent (the offset stays, the motion agrees)"
        );
        assert!(at(4.5) && at(5.4), "held over the estimate");
        assert!(!at(5.5), "the hold is over");
    }

    /// A source that jumps 15 m at 2.05 s (the operator's estimate after the robot was
    /// carried) while the odometry shows it standing: blamed, unless told of the estimate.
    fn jump(told: bool) -> Vec<f64> {
        let mut c = OdometryConsistency::default();
        c.on_odom(Pose2D::new(0.0, 0.0, 0.0));
        let mut out = Vec::new();
        for k in 0..60 {
            let t = k as f64 * 0.1;
            if told && k == 20 {
                c.hold(t);
            }
            let x = if k > 20 { 16.0 } else { 1.0 };
            out.extend(c.on_pose(Pose2D::new(x, 2.0, 0.0), 0.05, t));
        }
        out
    }

    #[test]
    fn a_jump_to_the_operators_estimate_is_not_blamed_and_an_untold_one_is() {
        let untold = jump(false);
        assert!(untold.iter().any(|&e| e <= -1.0), "{untold:?}");
        let told = jump(true);
        assert!(
            told.len() >= 2 && told.iter().all(|&e| e == 0.0),
            "judged again after the hold, and consistent: {told:?}"
        );
    }
}
