//! CARMEN log files (<http://carmen.sourceforge.net/logger_playback.html>):
//! `ODOM` and `FLASER` lines; all other lines (`PARAM`, `SYNC`, `NEFF`,
//! comments, ...) are skipped.
//!
//! Laser geometry: an old-style `FLASER` line carries no angles. CARMEN's
//! convention for a 180-reading front laser is a 180° field of view starting at
//! −90° (the robot's right) with 1° between beams, i.e. beam `i` at
//! `−90° + i·1°` (the last beam is at +89°). On the Intel log this convention
//! matched consecutive scans better than the alternatives (−89.5° start, or
//! 180/179° steps); see [`LaserConfig`].

use std::path::{Path, PathBuf};

use nalgebra::{Isometry2, Vector2};

/// A parse or I/O error naming the file, line (1-based) and field.
#[derive(Debug, thiserror::Error)]
pub enum CarmenError {
    /// The file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A line does not follow the format.
    #[error("{}:{line}: {kind} field `{field}`: {msg}", path.display())]
    Parse {
        /// File.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// Message type (`ODOM`, `FLASER`).
        kind: &'static str,
        /// Field name.
        field: String,
        /// What is wrong.
        msg: String,
    },
}

/// Beam geometry of a laser scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserConfig {
    /// Angle of beam 0 in the sensor frame (rad). Default −π/2.
    pub angle_min: f64,
    /// Angle between beams (rad). Default 1°.
    pub angle_increment: f64,
    /// Readings below this are invalid (m). Default 0.05.
    pub range_min: f64,
    /// Readings at or above this are "no return" (m). The Intel log uses
    /// 81.83 for no return; default 50.
    pub range_max: f64,
}

impl Default for LaserConfig {
    fn default() -> Self {
        Self {
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: 1f64.to_radians(),
            range_min: 0.05,
            range_max: 50.0,
        }
    }
}

impl LaserConfig {
    /// End points of the valid readings in the sensor frame.
    pub fn points(&self, ranges: &[f32]) -> Vec<Vector2<f64>> {
        ranges
            .iter()
            .enumerate()
            .filter(|(_, r)| {
                let r = f64::from(**r);
                r.is_finite() && r >= self.range_min && r < self.range_max
            })
            .map(|(i, &r)| {
                let a = self.angle_min + i as f64 * self.angle_increment;
                Vector2::new(f64::from(r) * a.cos(), f64::from(r) * a.sin())
            })
            .collect()
    }
}

/// An `ODOM x y theta tv rv accel timestamp hostname logger_timestamp` line.
#[derive(Debug, Clone, PartialEq)]
pub struct OdomRecord {
    /// 1-based line.
    pub line: usize,
    /// Odometry pose (x, y, theta).
    pub pose: [f64; 3],
    /// Translational velocity (m/s).
    pub tv: f64,
    /// Rotational velocity (rad/s).
    pub rv: f64,
    /// Timestamp (s).
    pub timestamp: f64,
}

/// A `FLASER n r1..rn x y theta odom_x odom_y odom_theta timestamp hostname logger_timestamp` line.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserRecord {
    /// 1-based line.
    pub line: usize,
    /// Range readings (m).
    pub ranges: Vec<f32>,
    /// Laser pose (x, y, theta); in a corrected log, the corrected pose.
    pub laser_pose: [f64; 3],
    /// Robot odometry pose at the scan (x, y, theta).
    pub odom_pose: [f64; 3],
    /// Timestamp (s).
    pub timestamp: f64,
}

/// One record of a log, in file order.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// `ODOM`.
    Odom(OdomRecord),
    /// `FLASER`.
    Laser(LaserRecord),
}

/// A parsed log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CarmenLog {
    /// `ODOM` and `FLASER` records in file order.
    pub records: Vec<Record>,
}

impl CarmenLog {
    /// The laser scans in file order.
    pub fn scans(&self) -> impl Iterator<Item = &LaserRecord> {
        self.records.iter().filter_map(|r| match r {
            Record::Laser(l) => Some(l),
            Record::Odom(_) => None,
        })
    }

    /// Odometry motion since the previous scan, one entry per scan (identity
    /// for the first), composed from the increments between consecutive `ODOM`
    /// lines.
    ///
    /// Increments across a `FLASER` line are left out: in corrected logs such
    /// as Intel's, the `ODOM` stream is re-anchored to the corrected pose at
    /// each scan, so that jump would leak the ground truth into the prior. The
    /// `odom_*` fields of `FLASER` are not used either, for the same reason
    /// (in the Intel log they equal the corrected pose).
    pub fn odometry_deltas(&self) -> Vec<Isometry2<f64>> {
        let mut out = Vec::new();
        let mut acc = Isometry2::identity();
        let mut prev: Option<Isometry2<f64>> = None;
        let mut crossed = false;
        for r in &self.records {
            match r {
                Record::Odom(o) => {
                    let p = pose_from(o.pose);
                    if let (Some(q), false) = (prev, crossed) {
                        acc *= q.inverse() * p;
                    }
                    prev = Some(p);
                    crossed = false;
                }
                Record::Laser(_) => {
                    out.push(if out.is_empty() {
                        Isometry2::identity()
                    } else {
                        acc
                    });
                    acc = Isometry2::identity();
                    crossed = true;
                }
            }
        }
        out
    }
}

/// `Isometry2` from `[x, y, theta]`.
pub fn pose_from(p: [f64; 3]) -> Isometry2<f64> {
    Isometry2::new(Vector2::new(p[0], p[1]), p[2])
}

/// `[x, y, theta]` of an `Isometry2`, theta in (−π, π].
pub fn pose_to(p: &Isometry2<f64>) -> [f64; 3] {
    [p.translation.x, p.translation.y, p.rotation.angle()]
}

/// Reads and parses a log file.
pub fn read_log(path: &Path) -> Result<CarmenLog, CarmenError> {
    let text = std::fs::read_to_string(path).map_err(|source| CarmenError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_log(&text, path)
}

struct Fields<'a> {
    it: std::str::SplitWhitespace<'a>,
    path: &'a Path,
    line: usize,
    kind: &'static str,
}

impl<'a> Fields<'a> {
    fn err(&self, field: impl Into<String>, msg: impl Into<String>) -> CarmenError {
        CarmenError::Parse {
            path: self.path.to_path_buf(),
            line: self.line,
            kind: self.kind,
            field: field.into(),
            msg: msg.into(),
        }
    }
    fn raw(&mut self, field: &str) -> Result<&'a str, CarmenError> {
        self.it
            .next()
            .ok_or_else(|| self.err(field, "missing (line too short)"))
    }
    fn f64(&mut self, field: &str) -> Result<f64, CarmenError> {
        let s = self.raw(field)?;
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(self.err(field, format!("{s:?} is not a finite number"))),
        }
    }
    fn pose(&mut self, prefix: &str) -> Result<[f64; 3], CarmenError> {
        Ok([
            self.f64(&format!("{prefix}x"))?,
            self.f64(&format!("{prefix}y"))?,
            self.f64(&format!("{prefix}theta"))?,
        ])
    }
}

/// Parses log text; `path` is only used in errors.
pub fn parse_log(text: &str, path: &Path) -> Result<CarmenLog, CarmenError> {
    let mut records = Vec::new();
    for (i, l) in text.lines().enumerate() {
        let line = i + 1;
        let mut it = l.split_whitespace();
        let kind = match it.next() {
            Some("ODOM") => "ODOM",
            Some("FLASER") => "FLASER",
            _ => continue,
        };
        let mut f = Fields {
            it,
            path,
            line,
            kind,
        };
        if kind == "ODOM" {
            let pose = f.pose("")?;
            let tv = f.f64("tv")?;
            let rv = f.f64("rv")?;
            let _accel = f.f64("accel")?;
            let timestamp = f.f64("timestamp")?;
            records.push(Record::Odom(OdomRecord {
                line,
                pose,
                tv,
                rv,
                timestamp,
            }));
        } else {
            let ns = f.raw("num_readings")?;
            let n: usize = ns.parse().ok().filter(|&n| n <= 10_000).ok_or_else(|| {
                f.err(
                    "num_readings",
                    format!("{ns:?} is not a count in 0..=10000"),
                )
            })?;
            let mut ranges = Vec::with_capacity(n);
            for k in 0..n {
                let field = format!("range[{k}]");
                let r = f.f64(&field)?;
                if r < 0.0 {
                    return Err(f.err(field, format!("negative range {r}")));
                }
                ranges.push(r as f32);
            }
            let laser_pose = f.pose("")?;
            let odom_pose = f.pose("odom_")?;
            let timestamp = f.f64("timestamp")?;
            records.push(Record::Laser(LaserRecord {
                line,
                ranges,
                laser_pose,
                odom_pose,
                timestamp,
            }));
        }
    }
    Ok(CarmenLog { records })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_odom_and_flaser() {
        let text = "# comment\nPARAM a 1 nohost 0\nODOM 1 2 0.5 0.1 0.2 0 3.5 host 3.5\n\
                    FLASER 3 1.0 2.0 81.83 0.5 0.6 0.7 1 2 0.5 4.0 host 4.0\nNEFF 3\n";
        let log = parse_log(text, Path::new("x.log")).expect("log");
        assert_eq!(log.records.len(), 2);
        let Record::Odom(o) = &log.records[0] else {
            panic!("expected ODOM")
        };
        assert_eq!(o.pose, [1.0, 2.0, 0.5]);
        assert_eq!(o.line, 3);
        let s: Vec<_> = log.scans().collect();
        assert_eq!(s[0].ranges, vec![1.0, 2.0, 81.83]);
        assert_eq!(s[0].laser_pose, [0.5, 0.6, 0.7]);
        assert_eq!(s[0].odom_pose, [1.0, 2.0, 0.5]);
        let pts = LaserConfig::default().points(&s[0].ranges);
        assert_eq!(pts.len(), 2, "81.83 is no return");
        assert!((pts[0] - Vector2::new(0.0, -1.0)).norm() < 1e-12);
    }

    #[test]
    fn errors_name_line_and_field() {
        let e = parse_log("ODOM 1 2\n", Path::new("x.log")).expect_err("short");
        assert_eq!(
            e.to_string(),
            "x.log:1: ODOM field `theta`: missing (line too short)"
        );
        let e = parse_log("\nFLASER 2 1.0 abc 0 0 0 0 0 0 1 h 1\n", Path::new("x.log"))
            .expect_err("bad range");
        assert_eq!(
            e.to_string(),
            "x.log:2: FLASER field `range[1]`: \"abc\" is not a finite number"
        );
        let e = parse_log("FLASER 2 1.0 1.0 0 0 0 0 0\n", Path::new("x.log")).expect_err("short");
        assert!(e.to_string().contains("field `odom_theta`"), "{e}");
        let e = parse_log("FLASER -1\n", Path::new("x.log")).expect_err("count");
        assert!(e.to_string().contains("field `num_readings`"), "{e}");
    }

    #[test]
    fn odometry_deltas_skip_jumps_across_scans() {
        let text = "ODOM 0 0 0 0 0 0 0 h 0\nFLASER 0 0 0 0 0 0 0 0 h 0\n\
                    ODOM 5 5 0 0 0 0 1 h 1\nODOM 6 5 0 0 0 0 2 h 2\nFLASER 0 0 0 0 0 0 0 0 h 0\n";
        let log = parse_log(text, Path::new("x.log")).expect("log");
        let d = log.odometry_deltas();
        assert_eq!(d.len(), 2);
        assert!((d[1].translation.vector - Vector2::new(1.0, 0.0)).norm() < 1e-12);
    }
}
