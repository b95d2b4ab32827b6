//! A lidar scan as the modules read it: its geometry ([`ScanView`]), whether it can be
//! interpreted at all, and its quality. The Laser driver and Security rate a scan by the one
//! formula here ([`scan_quality`]).

use hng_runtime::msg::{LaserScan, MAX_BEAMS};

/// A scan as the geometry needs it.
#[derive(Debug, Clone, Copy)]
pub struct ScanView<'a> {
    /// Angle of beam 0, rad.
    pub angle_min: f64,
    /// Angle between beams, rad.
    pub angle_increment: f64,
    /// Smallest valid range (`-inf` readings are placed there), m.
    pub range_min: f64,
    /// Ranges, m (`+inf`: nothing hit, `-inf`: too close, NaN: invalid).
    pub ranges: &'a [f32],
}

impl<'a> ScanView<'a> {
    /// A view of a scan message.
    pub fn of(scan: &'a LaserScan) -> ScanView<'a> {
        ScanView {
            angle_min: f64::from(scan.angle_min),
            angle_increment: f64::from(scan.angle_increment),
            range_min: f64::from(scan.range_min),
            ranges: scan.ranges(),
        }
    }

    /// Obstacle points in the robot frame.
    pub fn points(&self, laser_x: f64) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.ranges.iter().enumerate().filter_map(move |(i, &r)| {
            let r = if r == f32::NEG_INFINITY {
                self.range_min.max(0.0)
            } else if r.is_finite() {
                f64::from(r)
            } else {
                return None;
            };
            let a = self.angle_min + self.angle_increment * i as f64;
            Some((laser_x + r * a.cos(), r * a.sin()))
        })
    }

    /// Fraction of NaN beams (0 for an empty scan).
    pub fn invalid_fraction(&self) -> f64 {
        if self.ranges.is_empty() {
            return 1.0;
        }
        self.ranges.iter().filter(|r| r.is_nan()).count() as f64 / self.ranges.len() as f64
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
