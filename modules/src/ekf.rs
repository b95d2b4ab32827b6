//! An extended Kalman filter on the planar pose (x, y, θ) and the odometry's distance scale
//! `k`: wheel odometry is the motion model, absolute pose fixes (GPS/IMU: x, y and heading,
//! each with its covariance) are the measurements, gated by their Mahalanobis distance. Pure
//! logic, used by the [`crate::localization`] module.
//!
//! Prediction with the odometry increment `u = (dx, dy, dθ)` (robot frame, from one odometry
//! pose to the next): `(x, y, θ)' = (x, y, θ) ⊕ (k·dx, k·dy, dθ)`, `k' = k`,
//! `P' = F P Fᵀ + G Q Gᵀ`, with `F` the Jacobian in the state and `Q` a diagonal noise in the
//! robot frame that grows with the distance and the rotation of the increment and with time
//! (and a slow random walk of `k` per metre).
//!
//! Why `k`: wheel odometry has a systematic distance error (the simulator's 1 %, a worn or
//! mis-measured wheel on a robot). Folded into the noise, it is a bias the filter cannot see:
//! the estimate runs ahead of the truth by about `v · 1 % · τ` (τ, the filter's time constant,
//! is about 12 s here), 4-7 cm along the track at 0.5 m/s, so a robot stopping by its estimate
//! stopped short of its goals by that much. The fixes make `k` observable (the distance driven
//! against the distance measured): it settles within tens of seconds, and the along-track bias
//! falls to about 1 cm (`ekf::tests::the_odometry_scale_is_learnt_and_the_along_track_bias_goes`).
//!
//! Update with a fix `z` of covariance `R` (`H = [I₃ 0]`): the innovation `y = z − Hx`
//! (heading wrapped), `S = H P Hᵀ + R`; the fix is rejected when `yᵀ S⁻¹ y` exceeds the gate
//! (χ² with 3 degrees of freedom), otherwise `K = P Hᵀ S⁻¹`, `x += K y`,
//! `P = (I − K H) P (I − K H)ᵀ + K R Kᵀ` (Joseph form, symmetric and positive). After
//! `max_rejections` fixes rejected in a row the filter is taken to be lost and re-initialised
//! at the fix (a filter that has diverged would otherwise reject every fix for ever); it keeps
//! the scale it learnt (a property of the wheels, not of where the robot is).

use hng_runtime::msg::Pose2D;
use nalgebra::{Matrix3, Matrix3x4, Matrix4, Matrix4x3, Vector3, Vector4};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{compose, relative, wrap_angle};

/// Noise and gate of the filter.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct EkfParams {
    /// Standard deviation of the travelled distance per metre, along and across the
    /// heading (default 0.05: covers the simulator's 2 % random and 1 % scale errors).
    #[default(0.05)]
    pub linear_per_m: f64,
    /// Standard deviation of the rotation per radian turned (default 0.05).
    #[default(0.05)]
    pub angular_per_rad: f64,
    /// Standard deviation of the heading per metre driven, rad/m (default 0.01: drift).
    #[default(0.01)]
    pub angular_per_m: f64,
    /// Position random walk, m/√s, applied with time even at rest (default 0.01).
    #[default(0.01)]
    pub position_per_sqrt_s: f64,
    /// Heading random walk, rad/√s (default 0.002).
    #[default(0.002)]
    pub heading_per_sqrt_s: f64,
    /// Mahalanobis gate: fixes with `yᵀ S⁻¹ y` above it are rejected (default 16.27, the
    /// 99.9 % quantile of χ² with 3 degrees of freedom).
    #[default(16.27)]
    pub gate: f64,
    /// Fixes rejected in a row after which the filter re-initialises at the fix (default 10).
    #[default(10)]
    pub max_rejections: u32,
    /// Standard deviation of the odometry's distance scale before any fix has shown it
    /// (default 0.05: ±5 %; 0 keeps the scale at 1, as before the scale was estimated).
    #[default(0.05)]
    pub scale_sigma: f64,
    /// Random walk of the distance scale, per √m driven (default 0.0005: tyres wear slowly).
    #[default(0.0005)]
    pub scale_per_sqrt_m: f64,
}

/// The distance scale stays within these bounds (a larger error is a broken odometry, not a
/// scale to learn).
const SCALE_RANGE: (f64, f64) = (0.8, 1.25);

/// What a fix did to the filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixOutcome {
    /// The filter started at this fix.
    Initialised,
    /// The fix was fused; its squared Mahalanobis distance.
    Fused(f64),
    /// The fix was gated out; its squared Mahalanobis distance.
    Rejected(f64),
    /// Too many fixes were rejected in a row: the filter restarted at this one.
    Reset(f64),
    /// The fix's pose or covariance is not usable (not finite, not positive definite).
    Invalid,
}

/// The filter's state, as a checkpoint keeps it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct EkfState {
    /// Mean pose, map frame; `None` before the first fix.
    pub pose: Option<Pose2D>,
    /// Row-major covariance of (x, y, θ).
    pub covariance: [f64; 9],
    /// The odometry pose the mean goes with (the last one predicted from).
    pub odom: Option<Pose2D>,
    /// Fixes rejected in a row.
    pub rejected_in_a_row: u32,
    /// The odometry's distance scale and its variance (`None`: not yet learnt; the
    /// checkpoint loses its correlation with the pose).
    #[serde(default)]
    pub odom_scale: Option<[f64; 2]>,
}

/// The EKF.
#[derive(Debug, Clone)]
pub struct Ekf {
    params: EkfParams,
    /// (x, y, θ, k).
    x: Option<Vector4<f64>>,
    p: Matrix4<f64>,
    /// The scale and its variance while there is no pose (before the first fix).
    scale: (f64, f64),
    odom: Option<Pose2D>,
    rejected_in_a_row: u32,
}

fn to_matrix(c: &[f64; 9]) -> Matrix3<f64> {
    Matrix3::from_row_slice(c)
}

fn to_array(m: &Matrix4<f64>) -> [f64; 9] {
    let mut a = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            a[3 * r + c] = m[(r, c)];
        }
    }
    a
}

/// The full covariance from the pose's and the scale's variance (uncorrelated).
fn with_scale(pose: &Matrix3<f64>, scale_var: f64) -> Matrix4<f64> {
    let mut p = Matrix4::zeros();
    p.fixed_view_mut::<3, 3>(0, 0).copy_from(pose);
    p[(3, 3)] = scale_var;
    p
}

impl Ekf {
    /// A filter with no estimate yet: it starts at the first fix.
    pub fn new(params: EkfParams) -> Ekf {
        let var = if params.scale_sigma.is_finite() {
            params.scale_sigma * params.scale_sigma
        } else {
            0.0
        };
        Ekf {
            params,
            x: None,
            p: Matrix4::zeros(),
            scale: (1.0, var),
            odom: None,
            rejected_in_a_row: 0,
        }
    }

    /// A filter resuming from `state` (a checkpoint).
    pub fn resume(params: EkfParams, state: &EkfState) -> Ekf {
        let mut ekf = Ekf::new(params);
        if let Some([k, var]) = state.odom_scale
            && k.is_finite()
            && var.is_finite()
            && var >= 0.0
        {
            ekf.scale = (k.clamp(SCALE_RANGE.0, SCALE_RANGE.1), var);
        }
        let p = to_matrix(&state.covariance);
        if p.iter().all(|v| v.is_finite()) {
            ekf.x = state
                .pose
                .map(|p| Vector4::new(p.x, p.y, p.theta, ekf.scale.0));
            ekf.p = with_scale(&p, ekf.scale.1);
        }
        ekf.odom = state.odom;
        ekf.rejected_in_a_row = state.rejected_in_a_row;
        ekf
    }

    /// What a checkpoint keeps.
    pub fn state(&self) -> EkfState {
        let (k, var) = self.odom_scale();
        EkfState {
            pose: self.pose(),
            covariance: to_array(&self.p),
            odom: self.odom,
            rejected_in_a_row: self.rejected_in_a_row,
            odom_scale: Some([k, var]),
        }
    }

    /// The odometry's distance scale (true distance per odometry metre) and its variance.
    pub fn odom_scale(&self) -> (f64, f64) {
        match self.x {
            Some(x) => (x[3], self.p[(3, 3)]),
            None => self.scale,
        }
    }

    /// Starts the filter at fix `z` (covariance `r`), keeping the scale learnt so far.
    fn start_at(&mut self, z: &Vector3<f64>, r: &Matrix3<f64>) {
        let (k, var) = self.odom_scale();
        self.x = Some(Vector4::new(z[0], z[1], z[2], k));
        self.p = with_scale(r, var);
        self.rejected_in_a_row = 0;
    }

    /// Restarts the filter at `pose` with covariance `cov` (row-major x, y, θ), keeping the
    /// odometry scale learnt so far: an estimate known to be better than the filter's (the
    /// operator's, see [`crate::initial_pose`]).
    pub fn restart_at(&mut self, pose: Pose2D, cov: &[f64; 9]) {
        self.start_at(&Vector3::new(pose.x, pose.y, pose.theta), &to_matrix(cov));
    }

    /// The mean pose (`None` before the first fix).
    pub fn pose(&self) -> Option<Pose2D> {
        self.x.map(|x| Pose2D::new(x[0], x[1], x[2]))
    }

    /// Row-major covariance of (x, y, θ).
    pub fn covariance(&self) -> [f64; 9] {
        to_array(&self.p)
    }

    /// Position standard deviation: the square root of the larger eigenvalue of the
    /// position block (the semi-major axis of the 1σ ellipse); infinite before the first fix.
    pub fn position_sigma(&self) -> f64 {
        if self.x.is_none() {
            return f64::INFINITY;
        }
        let (a, b, c) = (self.p[(0, 0)], self.p[(1, 1)], self.p[(0, 1)]);
        let mean = 0.5 * (a + b);
        let d = (0.25 * (a - b) * (a - b) + c * c).sqrt();
        (mean + d).max(0.0).sqrt()
    }

    /// Odometry reading `odom` (odom frame), `dt` seconds after the previous one: predicts
    /// with the motion since the previous reading.
    pub fn predict(&mut self, odom: Pose2D, dt: f64) {
        let Some(prev) = self.odom.replace(odom) else {
            return;
        };
        let Some(x) = self.x.as_mut() else {
            return;
        };
        let u = relative(&prev, &odom);
        if !(u.x.is_finite() && u.y.is_finite() && u.theta.is_finite()) {
            return;
        }
        let dt = if dt.is_finite() { dt.max(0.0) } else { 0.0 };
        let (s, c) = x[2].sin_cos();
        let k = x[3];
        let next = compose(
            &Pose2D::new(x[0], x[1], x[2]),
            &Pose2D::new(k * u.x, k * u.y, u.theta),
        );
        *x = Vector4::new(next.x, next.y, next.theta, k);
        // Jacobian of the motion in (x, y, θ, k).
        let (ex, ey) = (c * u.x - s * u.y, s * u.x + c * u.y);
        #[rustfmt::skip]
        let f = Matrix4::new(
            1.0, 0.0, -k * ey, ex,
            0.0, 1.0, k * ex, ey,
            0.0, 0.0, 1.0, 0.0,
            0.0, 0.0, 0.0, 1.0,
        );
        // Noise in the robot frame, rotated into the map frame.
        let pr = &self.params;
        let d = u.x.hypot(u.y);
        let lin = (pr.linear_per_m * d).powi(2) + pr.position_per_sqrt_s.powi(2) * dt;
        let ang = (pr.angular_per_rad * u.theta.abs() + pr.angular_per_m * d).powi(2)
            + pr.heading_per_sqrt_s.powi(2) * dt;
        let walk = if pr.scale_sigma > 0.0 {
            pr.scale_per_sqrt_m.powi(2) * d
        } else {
            0.0
        };
        let g = Matrix4::new(
            c, -s, 0.0, 0.0, s, c, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        );
        let q = Matrix4::from_diagonal(&Vector4::new(lin, lin, ang, walk));
        self.p = f * self.p * f.transpose() + g * q * g.transpose();
        self.p = 0.5 * (self.p + self.p.transpose());
    }

    /// A pose fix `z` with row-major covariance `r` (map frame).
    pub fn update(&mut self, z: Pose2D, r: &[f64; 9]) -> FixOutcome {
        let r = to_matrix(r);
        let finite = z.x.is_finite() && z.y.is_finite() && z.theta.is_finite();
        if !finite || r.iter().any(|v| !v.is_finite()) || r.cholesky().is_none() {
            return FixOutcome::Invalid;
        }
        let zv = Vector3::new(z.x, z.y, wrap_angle(z.theta));
        let Some(x) = self.x else {
            self.start_at(&zv, &r);
            return FixOutcome::Initialised;
        };
        let mut y = zv - x.fixed_rows::<3>(0);
        y[2] = wrap_angle(y[2]);
        let s = self.p.fixed_view::<3, 3>(0, 0) + r;
        let Some(s_inv) = s.try_inverse() else {
            return FixOutcome::Invalid;
        };
        let d2 = (y.transpose() * s_inv * y)[(0, 0)];
        // A NaN distance (degenerate S) counts as an outlier.
        if d2.is_nan() || d2 > self.params.gate {
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row >= self.params.max_rejections {
                self.start_at(&zv, &r);
                return FixOutcome::Reset(d2);
            }
            return FixOutcome::Rejected(d2);
        }
        self.rejected_in_a_row = 0;
        let h = Matrix3x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0);
        let k: Matrix4x3<f64> = self.p * h.transpose() * s_inv;
        let mut nx = x + k * y;
        nx[2] = wrap_angle(nx[2]);
        if self.params.scale_sigma > 0.0 {
            nx[3] = nx[3].clamp(SCALE_RANGE.0, SCALE_RANGE.1);
        } else {
            nx[3] = 1.0;
        }
        self.x = Some(nx);
        let ik = Matrix4::identity() - k * h;
        self.p = ik * self.p * ik.transpose() + k * r * k.transpose();
        self.p = 0.5 * (self.p + self.p.transpose());
        FixOutcome::Fused(d2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Standard normal samples (xorshift64* and Box-Muller): deterministic, no dependency.
    struct Gauss(u64);

    impl Gauss {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
            ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }

        fn sample(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }

    const SIGMA: f64 = 0.3;

    fn gps_cov(sigma: f64) -> [f64; 9] {
        let v = sigma * sigma;
        [v, 0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0, 0.03 * 0.03]
    }

    /// A robot driving a square-ish loop at 0.5 m/s with odometry at 50 Hz (1 % scale error,
    /// 2 % noise, heading drift as the simulator's defaults) and fixes at 5 Hz (σ 0.3 m).
    /// Returns the RMS and max position error over the last `tail` seconds, and the filter.
    fn drive(seconds: f64, fixes: bool, seed: u64) -> (f64, f64, Ekf) {
        let (rms, max, _, ekf) = drive_with(EkfParams::default(), seconds, fixes, seed);
        (rms, max, ekf)
    }

    /// [`drive`] with `params`; also the mean error along the heading (+: ahead of the truth).
    fn drive_with(params: EkfParams, seconds: f64, fixes: bool, seed: u64) -> (f64, f64, f64, Ekf) {
        let mut noise =
            Gauss(0x9E37_79B9_7F4A_7C15 ^ (seed + 1).wrapping_mul(0xBF58_476D_1CE4_E5B9));
        let mut ekf = Ekf::new(params);
        let mut truth = Pose2D::new(2.0, 2.0, 0.3);
        let mut odom = Pose2D::default();
        let dt = 0.02;
        ekf.predict(odom, dt);
        ekf.update(truth, &gps_cov(SIGMA));
        let (mut sum2, mut max, mut n, mut along) = (0.0, 0.0_f64, 0, 0.0);
        let steps = (seconds / dt) as usize;
        for k in 0..steps {
            let turn = if (k / 250) % 2 == 0 { 0.0 } else { 0.4 };
            let (d, dth) = (0.5 * dt, turn * dt);
            truth = compose(&truth, &Pose2D::new(d, 0.0, dth));
            let dm = d * 1.01 + 0.02 * d * noise.sample();
            let dthm = dth * 1.02 + 0.005 * d + 0.02 * dth.abs() * noise.sample();
            odom = compose(&odom, &Pose2D::new(dm, 0.0, dthm));
            ekf.predict(odom, dt);
            if fixes && k % 10 == 0 {
                let z = Pose2D::new(
                    truth.x + SIGMA * noise.sample(),
                    truth.y + SIGMA * noise.sample(),
                    truth.theta + 0.03 * noise.sample(),
                );
                ekf.update(z, &gps_cov(SIGMA));
            }
            if k > steps / 2 {
                let p = ekf.pose().expect("initialised");
                let e = (p.x - truth.x).hypot(p.y - truth.y);
                sum2 += e * e;
                max = max.max(e);
                along += (p.x - truth.x) * truth.theta.cos() + (p.y - truth.y) * truth.theta.sin();
                n += 1;
            }
        }
        ((sum2 / n as f64).sqrt(), max, along / n as f64, ekf)
    }

    #[test]
    fn the_odometry_scale_is_learnt_and_the_along_track_bias_goes() {
        // The odometry reads 1 % long: the true scale is 1 / 1.01 = 0.990.
        let fixed = EkfParams {
            scale_sigma: 0.0,
            ..EkfParams::default()
        };
        let (mut before, mut after) = (0.0, 0.0);
        for seed in 0..4 {
            let (_, _, b, _) = drive_with(fixed, 120.0, true, seed);
            let (rms, _, a, ekf) = drive_with(EkfParams::default(), 120.0, true, seed);
            let (k, var) = ekf.odom_scale();
            assert!((k - 1.0 / 1.01).abs() < 0.004, "seed {seed}: scale {k}");
            assert!(var.sqrt() < 0.01, "seed {seed}: scale σ {}", var.sqrt());
            assert!(rms < 0.1, "seed {seed}: rms {rms}");
            (before, after) = (before + b / 4.0, after + a / 4.0);
        }
        // Without the scale the estimate runs ahead of the truth by centimetres.
        assert!(before > 0.02, "bias with a fixed scale: {before}");
        eprintln!(
            "mean error along the heading: {before:.4} m with a fixed scale, {after:.4} m learnt"
        );
        assert!(
            after.abs() < 0.6 * before,
            "bias {after} (fixed scale: {before})"
        );
        // A checkpoint keeps the scale.
        let (_, _, _, ekf) = drive_with(EkfParams::default(), 60.0, true, 9);
        let resumed = Ekf::resume(EkfParams::default(), &ekf.state());
        assert_eq!(resumed.odom_scale(), ekf.odom_scale());
    }

    #[test]
    fn fusion_converges_well_below_the_gps_noise() {
        for seed in 0..4 {
            let (rms, max, ekf) = drive(120.0, true, seed);
            // Raw fixes have an RMS position error of 0.3·√2 = 0.42 m.
            assert!(rms < 0.12, "seed {seed}: rms {rms}");
            assert!(max < 0.3, "seed {seed}: max {max}");
            let sigma = ekf.position_sigma();
            assert!(sigma > 0.02 && sigma < 0.15, "seed {seed}: σ {sigma}");
        }
    }

    #[test]
    fn an_outlier_fix_is_rejected_and_does_not_move_the_estimate() {
        let mut ekf = Ekf::new(EkfParams::default());
        let start = Pose2D::new(1.0, 1.0, 0.0);
        ekf.predict(Pose2D::default(), 0.0);
        assert_eq!(ekf.update(start, &gps_cov(SIGMA)), FixOutcome::Initialised);
        for _ in 0..20 {
            assert!(matches!(
                ekf.update(start, &gps_cov(SIGMA)),
                FixOutcome::Fused(_)
            ));
        }
        let before = ekf.pose().expect("pose");
        let jump = Pose2D { x: 4.0, ..start };
        let out = ekf.update(jump, &gps_cov(SIGMA));
        assert!(
            matches!(out, FixOutcome::Rejected(d) if d > 16.27),
            "{out:?}"
        );
        assert_eq!(ekf.pose(), Some(before));
        // A fix that is merely noisy (1σ off) is fused.
        let near = Pose2D { x: 1.3, ..start };
        assert!(matches!(
            ekf.update(near, &gps_cov(SIGMA)),
            FixOutcome::Fused(_)
        ));
        // Invalid fixes are refused without touching the filter.
        let nan = Pose2D {
            x: f64::NAN,
            ..start
        };
        assert_eq!(ekf.update(nan, &gps_cov(SIGMA)), FixOutcome::Invalid);
        assert_eq!(ekf.update(start, &[-1.0; 9]), FixOutcome::Invalid);
        // A filter that is truly elsewhere (every fix far off) resets after the limit.
        let mut last = FixOutcome::Invalid;
        for _ in 0..EkfParams::default().max_rejections {
            last = ekf.update(jump, &gps_cov(SIGMA));
        }
        assert!(matches!(last, FixOutcome::Reset(_)), "{last:?}");
        assert_eq!(ekf.pose().map(|p| p.x), Some(4.0));
    }

    #[test]
    fn covariance_grows_without_fixes_in_motion_and_with_time() {
        let (_, _, with) = drive(60.0, true, 7);
        let fused = with.position_sigma();
        // The same drive, fixes only for the first second, then odometry alone.
        let mut ekf = Ekf::new(EkfParams::default());
        ekf.predict(Pose2D::default(), 0.0);
        ekf.update(Pose2D::default(), &gps_cov(SIGMA));
        let mut odom = Pose2D::default();
        // det(F) = 1, so the prediction never shrinks the uncertainty volume det P of the
        // whole state (the pose's part alone may dip slightly through its correlation with
        // the scale, σ as the ellipse turns with the heading).
        let det = |e: &Ekf| e.p.determinant();
        let mut last = det(&ekf);
        for k in 0..3000 {
            odom = compose(&odom, &Pose2D::new(0.01, 0.0, 0.002));
            ekf.predict(odom, 0.02);
            let d = det(&ekf);
            assert!(d >= last, "step {k}: {d} < {last}");
            last = d;
        }
        let sigma = ekf.position_sigma();
        assert!(
            sigma > SIGMA && sigma > 3.0 * fused,
            "{sigma} vs fused {fused}"
        );
        // At rest the covariance still grows with time.
        let at_rest = ekf.position_sigma();
        for _ in 0..500 {
            ekf.predict(odom, 0.02);
        }
        assert!(ekf.position_sigma() > at_rest);
        // A checkpointed filter resumes where it was.
        let resumed = Ekf::resume(EkfParams::default(), &ekf.state());
        assert_eq!(resumed.pose(), ekf.pose());
        assert_eq!(resumed.covariance(), ekf.covariance());
    }
}
