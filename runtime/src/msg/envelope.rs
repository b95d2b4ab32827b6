//! The speed-limit envelope a safety module (Security) publishes for a driver (the Robot):
//! the largest safe speed for every curvature of motion, computed from one scan, so the driver
//! limits whatever command it elected without a round trip through the safety module.

use iceoryx2::prelude::ZeroCopySend;
use serde::Serialize;
use serde::ser::{SerializeStruct, Serializer};

use super::{Header, Twist};
use crate::qos::ChannelKind;

/// Number of curvature bins of a [`SpeedEnvelope`] (odd: the middle one is straight motion).
pub const ENVELOPE_BINS: usize = 49;
/// Largest curvature the bins resolve, 1/m (a radius of 5 cm); sharper arcs use the end bin.
pub const ENVELOPE_MAX_CURVATURE: f64 = 20.0;

/// Position of curvature `k` (1/m) on the bins' axis, in bins from the first: the bins are
/// uniform in `atan(k)`, fine near straight motion and coarse for sharp turns.
fn bin_position(k: f64) -> f64 {
    let psi_max = ENVELOPE_MAX_CURVATURE.atan();
    let psi = k
        .clamp(-ENVELOPE_MAX_CURVATURE, ENVELOPE_MAX_CURVATURE)
        .atan();
    (psi + psi_max) / (2.0 * psi_max) * (ENVELOPE_BINS - 1) as f64
}

/// The curvature, 1/m (`angular_z / linear_x`, positive to the left), of bin `i`.
pub fn envelope_bin_curvature(i: usize) -> f64 {
    let psi_max = ENVELOPE_MAX_CURVATURE.atan();
    let i = i.min(ENVELOPE_BINS - 1) as f64;
    let psi = -psi_max + 2.0 * psi_max * i / (ENVELOPE_BINS - 1) as f64;
    // Keep the middle bin exactly straight.
    if psi.abs() < 1e-12 { 0.0 } else { psi.tan() }
}

/// The largest safe speeds for one scan (REP-103: m/s, rad/s; curvature `w/v` in 1/m,
/// positive to the left), published by the safety module at every scan and when its verdict
/// changes, on a state channel (a driver that joins late gets the latest).
///
/// A command `(v, w)` with `v != 0` follows the arc of curvature `k = w/v`; it is safe at
/// speeds up to [`SpeedEnvelope::max_speed`]: the lower of the two bins around `k` (the bins
/// are close enough that the arc between two bins stays within the swept discs the safety
/// module checked, less than its safety distance away). [`SpeedEnvelope::limit`] applies it.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("hng/SpeedEnvelope/v1")]
pub struct SpeedEnvelope {
    /// Header; the publisher stamps it when it publishes.
    pub header: Header,
    /// The stamp of the scan the envelope was computed from, ns of the common clock: the
    /// envelope is as old as that scan.
    pub scan_stamp_ns: u64,
    /// 1: every motion is forbidden (the safety module has no fresh scan).
    pub stop: u8,
    /// Largest turn rate allowed when turning in place (`v = 0`), rad/s (infinite: not
    /// limited; a disc robot turning in place sweeps nothing new).
    pub turn_in_place: f64,
    /// Largest safe forward speed at the curvature of each bin, m/s (>= 0).
    pub forward: [f64; ENVELOPE_BINS],
    /// Largest safe backward speed (a magnitude) at the curvature of each bin, m/s (>= 0).
    pub backward: [f64; ENVELOPE_BINS],
}
crate::impl_message!(SpeedEnvelope, ChannelKind::State);

impl Default for SpeedEnvelope {
    /// The stop envelope: nothing allowed.
    fn default() -> Self {
        SpeedEnvelope {
            header: Header::default(),
            scan_stamp_ns: 0,
            stop: 1,
            turn_in_place: 0.0,
            forward: [0.0; ENVELOPE_BINS],
            backward: [0.0; ENVELOPE_BINS],
        }
    }
}

impl SpeedEnvelope {
    /// The stop envelope (no fresh scan), for the scan of stamp `scan_stamp_ns`.
    pub fn stopped(scan_stamp_ns: u64) -> Self {
        SpeedEnvelope {
            scan_stamp_ns,
            ..Default::default()
        }
    }

    /// The largest safe speed, m/s (a magnitude), moving forward (`forward`) or backward on
    /// the arc of curvature `k` (1/m): the lower of the two bins around it.
    pub fn max_speed(&self, forward: bool, k: f64) -> f64 {
        if self.stop != 0 || k.is_nan() {
            return 0.0;
        }
        let bins = if forward {
            &self.forward
        } else {
            &self.backward
        };
        let p = bin_position(k);
        let lo = (p.floor() as usize).min(ENVELOPE_BINS - 1);
        let hi = (p.ceil() as usize).min(ENVELOPE_BINS - 1);
        bins[lo].min(bins[hi]).max(0.0)
    }

    /// `cmd` limited to the envelope, and whether it was changed: a speed above the limit of
    /// its curvature is reduced keeping the curvature (the robot stays on the arc that was
    /// checked); reduced to 0 it keeps its turn rate, within the turn-in-place allowance. A
    /// non-finite command becomes a stop.
    pub fn limit(&self, cmd: &Twist) -> (Twist, bool) {
        let (v, w) = (cmd.linear_x, cmd.angular_z);
        if !(v.is_finite() && w.is_finite()) {
            return (Twist::default(), true);
        }
        if self.stop != 0 {
            let stopped = Twist::default();
            return (stopped, v != 0.0 || w != 0.0 || cmd.linear_y != 0.0);
        }
        let turn = |w: f64| w.clamp(-self.turn_in_place, self.turn_in_place);
        let (v2, w2) = if v == 0.0 {
            (0.0, turn(w))
        } else {
            let vmax = self.max_speed(v > 0.0, w / v);
            if v.abs() <= vmax {
                (v, w)
            } else if vmax > 0.0 {
                let v2 = v.signum() * vmax;
                (v2, w * v2 / v)
            } else {
                (0.0, turn(w))
            }
        };
        let out = Twist {
            header: cmd.header,
            linear_x: v2,
            linear_y: 0.0,
            angular_z: w2,
        };
        let changed = v2 != v || w2 != w || cmd.linear_y != 0.0;
        (out, changed)
    }
}

impl Serialize for SpeedEnvelope {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("SpeedEnvelope", 6)?;
        st.serialize_field("header", &self.header)?;
        st.serialize_field("scan_stamp_ns", &self.scan_stamp_ns)?;
        st.serialize_field("stop", &self.stop)?;
        st.serialize_field("turn_in_place", &self.turn_in_place)?;
        st.serialize_field("forward", &self.forward[..])?;
        st.serialize_field("backward", &self.backward[..])?;
        st.end()
    }
}

/// Curvature axis check: the bins cover straight motion exactly and both turn directions.
#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn env(f: impl Fn(f64) -> f64) -> SpeedEnvelope {
        let mut e = SpeedEnvelope {
            stop: 0,
            turn_in_place: f64::INFINITY,
            ..Default::default()
        };
        for i in 0..ENVELOPE_BINS {
            e.forward[i] = f(envelope_bin_curvature(i));
            e.backward[i] = 1.0;
        }
        e
    }

    fn cmd(v: f64, w: f64) -> Twist {
        Twist {
            linear_x: v,
            angular_z: w,
            ..Default::default()
        }
    }

    #[test]
    fn bins_run_from_right_to_left_turns_with_straight_in_the_middle() {
        assert_eq!(envelope_bin_curvature(ENVELOPE_BINS / 2), 0.0);
        assert!((envelope_bin_curvature(0) + ENVELOPE_MAX_CURVATURE).abs() < 1e-9);
        assert!((envelope_bin_curvature(ENVELOPE_BINS - 1) - ENVELOPE_MAX_CURVATURE).abs() < 1e-9);
        for i in 1..ENVELOPE_BINS {
            assert!(envelope_bin_curvature(i) > envelope_bin_curvature(i - 1));
            assert!((bin_position(envelope_bin_curvature(i)) - i as f64).abs() < 1e-9);
        }
        assert!(std::f64::consts::FRAC_PI_2 > ENVELOPE_MAX_CURVATURE.atan());
    }

    #[test]
    fn between_two_bins_the_lower_one_counts() {
        // Limits rise with the curvature: between bins the lower (right) neighbour holds.
        let e = env(|k| 1.0 + k);
        let (k0, k1) = (envelope_bin_curvature(24), envelope_bin_curvature(25));
        let k = 0.5 * (k0 + k1);
        assert_eq!(e.max_speed(true, k), 1.0 + k0);
        let e = env(|k| 1.0 - k);
        assert_eq!(e.max_speed(true, k), 1.0 - k1);
    }

    #[test]
    fn limiting_keeps_the_curvature_and_turning_in_place() {
        let e = env(|_| 0.4);
        let (c, changed) = e.limit(&cmd(0.8, 0.4));
        assert!(changed);
        assert!((c.linear_x - 0.4).abs() < 1e-12 && (c.angular_z - 0.2).abs() < 1e-12);
        assert_eq!(e.limit(&cmd(0.3, 0.1)), (cmd(0.3, 0.1), false));
        assert_eq!(
            e.limit(&cmd(-0.9, 0.0)),
            (cmd(-0.9, 0.0), false),
            "backward free"
        );
        let e = env(|_| 0.0);
        assert_eq!(
            e.limit(&cmd(0.5, 0.7)),
            (cmd(0.0, 0.7), true),
            "turn in place"
        );
        assert_eq!(e.limit(&cmd(0.0, 1.5)), (cmd(0.0, 1.5), false));
        let stop = SpeedEnvelope::stopped(7);
        assert_eq!(stop.limit(&cmd(0.0, 1.5)), (Twist::default(), true));
        assert_eq!(stop.limit(&cmd(f64::NAN, 0.0)).0, Twist::default());
        assert_eq!(stop.max_speed(false, 0.0), 0.0);
    }
}
