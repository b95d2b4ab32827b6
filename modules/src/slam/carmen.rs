//! CARMEN log files (<http://carmen.sourceforge.net/logger_playback.html>):
//! `ODOM`, `FLASER` and `ROBOTLASER1` lines are read; every other line is
//! skipped and counted by message type ([`CarmenLog::skipped`]).
//!
//! # Laser geometry, from the data
//!
//! A `ROBOTLASER1` line carries its geometry: start angle, field of view,
//! angular resolution and maximum range; those are used as they are.
//!
//! An old-style `FLASER` line carries only its beam count `n`. The field of
//! view is taken as 180° (a front SICK LMS; override with
//! [`LogOptions::fov`], `hng eval slam --fov DEG`), centred on the robot's
//! heading, and the convention depends on the parity of `n`:
//!
//! | beams `n` | convention | beam `i` at | example |
//! |---|---|---|---|
//! | even | `n` steps of `fov/n`, the last end excluded | `−fov/2 + i·fov/n` | 180 beams: 1° from −90° to +89°; 360: 0.5° from −90° to +89.5° |
//! | odd | `n − 1` steps of `fov/(n−1)`, both ends included | `−fov/2 + i·fov/(n−1)` | 181 beams: 1° from −90° to +90°; 361: 0.5° from −90° to +90° |
//!
//! These are the SICK LMS settings (180/181 readings at 1°, 360/361 at 0.5°).
//! On the Intel log (180 beams) the even rule matched consecutive scans better
//! than the alternatives (−89.5° start, or 180°/179° steps). `FLASER` lines
//! give no maximum range: readings at or above [`LogOptions::range_max`]
//! (50 m) are "no return" (SICK lasers log 81.83 m or 81.91 m for no echo).
//!
//! # Bad input
//!
//! A line of a known type that is cut short, or has a field that is not a
//! number, is an error naming the file, the line and the field. A `NaN`,
//! infinite or negative *range* is kept as an invalid reading (it yields no
//! point) and counted in [`CarmenLog::invalid_ranges`]: lasers report such
//! values, and one bad beam is no reason to drop a scan.

use smart_default::SmartDefault;
use std::collections::BTreeMap;
use std::f64::consts::PI;
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
        /// Message type (`ODOM`, `FLASER`, `ROBOTLASER1`).
        kind: &'static str,
        /// Field name.
        field: String,
        /// What is wrong.
        msg: String,
    },
}

/// Beam geometry of a laser scan.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct LaserConfig {
    /// Angle of beam 0 in the sensor frame (rad). Default −π/2.
    #[default(-std::f64::consts::FRAC_PI_2)]
    pub angle_min: f64,
    /// Angle between beams (rad). Default 1°.
    #[default(1f64.to_radians())]
    pub angle_increment: f64,
    /// Readings below this are invalid (m). Default 0.05.
    #[default(0.05)]
    pub range_min: f64,
    /// Readings at or above this are "no return" (m). Default 50.
    #[default(50.0)]
    pub range_max: f64,
}

impl LaserConfig {
    /// The geometry of an `n`-beam `FLASER` scan over `fov` radians centred on
    /// the heading (see the [module docs](self)): `fov/n` steps for even `n`,
    /// `fov/(n − 1)` steps with both ends included for odd `n`.
    pub fn flaser(n: usize, fov: f64, range_max: f64) -> Self {
        let steps = if n % 2 == 1 { n.saturating_sub(1) } else { n }.max(1);
        Self {
            angle_min: -fov / 2.0,
            angle_increment: fov / steps as f64,
            range_min: 0.05,
            range_max,
        }
    }

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

/// How to read a log.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct LogOptions {
    /// Field of view of `FLASER` scans (rad); `None`: 180° (see the module docs).
    pub fov: Option<f64>,
    /// `FLASER` readings at or above this are "no return" (m). Default 50.
    #[default(50.0)]
    pub range_max: f64,
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

/// A laser scan: an old-style `FLASER n r1..rn x y theta odom_x odom_y
/// odom_theta timestamp hostname logger_timestamp` line, or a `ROBOTLASER1`
/// line.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserRecord {
    /// 1-based line.
    pub line: usize,
    /// Range readings (m); invalid readings (NaN, negative) are NaN.
    pub ranges: Vec<f32>,
    /// Beam geometry of this scan.
    pub laser: LaserConfig,
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
    /// `FLASER` or `ROBOTLASER1`.
    Laser(LaserRecord),
}

/// A parsed log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CarmenLog {
    /// `ODOM` and laser records in file order.
    pub records: Vec<Record>,
    /// Lines skipped, by message type (`PARAM`, `NEFF`, `#` for comments, ...).
    pub skipped: BTreeMap<String, usize>,
    /// Range readings that were NaN, infinite or negative (kept as invalid).
    pub invalid_ranges: usize,
}

impl CarmenLog {
    /// The laser scans in file order.
    pub fn scans(&self) -> impl Iterator<Item = &LaserRecord> {
        self.records.iter().filter_map(|r| match r {
            Record::Laser(l) => Some(l),
            Record::Odom(_) => None,
        })
    }

    /// Lines skipped in all.
    pub fn skipped_lines(&self) -> usize {
        self.skipped.values().sum()
    }

    /// Odometry motion since the previous scan, one entry per scan (identity
    /// for the first), composed from the increments between consecutive `ODOM`
    /// lines.
    ///
    /// In corrected logs (all five shipped ones) the `ODOM` stream is
    /// re-anchored to the corrected pose at each scan: the first `ODOM` after
    /// a laser line equals that line's pose. That jump would leak the ground
    /// truth into the prior, so an increment across a laser line is left out
    /// when the `ODOM` after it equals the scan's pose; in a raw log (no such
    /// equality) it is kept. The `odom_*` fields of `FLASER` are not used
    /// either, for the same reason (in corrected logs they equal the
    /// corrected pose).
    pub fn odometry_deltas(&self) -> Vec<Isometry2<f64>> {
        let mut out = Vec::new();
        let mut acc = Isometry2::identity();
        let mut prev: Option<Isometry2<f64>> = None;
        let mut crossed: Option<[f64; 3]> = None;
        for r in &self.records {
            match r {
                Record::Odom(o) => {
                    let p = pose_from(o.pose);
                    let reanchored = crossed
                        .is_some_and(|s| s.iter().zip(&o.pose).all(|(a, b)| (a - b).abs() < 1e-6));
                    if let (Some(q), false) = (prev, reanchored) {
                        acc *= q.inverse() * p;
                    }
                    prev = Some(p);
                    crossed = None;
                }
                Record::Laser(l) => {
                    out.push(if out.is_empty() {
                        Isometry2::identity()
                    } else {
                        acc
                    });
                    acc = Isometry2::identity();
                    crossed = Some(l.laser_pose);
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

/// Reads and parses a log file with default [`LogOptions`].
pub fn read_log(path: &Path) -> Result<CarmenLog, CarmenError> {
    read_log_with(path, &LogOptions::default())
}

/// Reads and parses a log file.
pub fn read_log_with(path: &Path, opts: &LogOptions) -> Result<CarmenLog, CarmenError> {
    let bytes = std::fs::read(path).map_err(|source| CarmenError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    // Hostnames and comments may hold any bytes; numbers are ASCII.
    parse_log_with(&String::from_utf8_lossy(&bytes), path, opts)
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
    fn count(&mut self, field: &str) -> Result<usize, CarmenError> {
        let s = self.raw(field)?;
        s.parse()
            .ok()
            .filter(|&n| n <= 10_000)
            .ok_or_else(|| self.err(field, format!("{s:?} is not a count in 0..=10000")))
    }
    /// A range reading: NaN, infinite or negative readings become NaN and are
    /// counted; text that is not a number is an error.
    fn range(&mut self, k: usize, invalid: &mut usize) -> Result<f32, CarmenError> {
        let s = self.raw(&format!("range[{k}]"))?;
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() && v >= 0.0 => Ok(v as f32),
            Ok(_) => {
                *invalid += 1;
                Ok(f32::NAN)
            }
            Err(_) => Err(self.err(format!("range[{k}]"), format!("{s:?} is not a number"))),
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

/// Parses log text with default [`LogOptions`]; `path` is only used in errors.
pub fn parse_log(text: &str, path: &Path) -> Result<CarmenLog, CarmenError> {
    parse_log_with(text, path, &LogOptions::default())
}

/// Parses log text; `path` is only used in errors.
pub fn parse_log_with(
    text: &str,
    path: &Path,
    opts: &LogOptions,
) -> Result<CarmenLog, CarmenError> {
    let mut log = CarmenLog::default();
    let fov = opts.fov.unwrap_or(PI);
    for (i, l) in text.lines().enumerate() {
        let line = i + 1;
        let mut it = l.split_whitespace();
        let kind = match it.next() {
            Some("ODOM") => "ODOM",
            Some("FLASER") => "FLASER",
            Some("ROBOTLASER1") => "ROBOTLASER1",
            Some(other) => {
                let key = if other.starts_with('#') { "#" } else { other };
                *log.skipped.entry(key.to_owned()).or_default() += 1;
                continue;
            }
            None => continue,
        };
        let mut f = Fields {
            it,
            path,
            line,
            kind,
        };
        let invalid = &mut log.invalid_ranges;
        let record = match kind {
            "ODOM" => {
                let pose = f.pose("")?;
                let tv = f.f64("tv")?;
                let rv = f.f64("rv")?;
                let _accel = f.f64("accel")?;
                let timestamp = f.f64("timestamp")?;
                Record::Odom(OdomRecord {
                    line,
                    pose,
                    tv,
                    rv,
                    timestamp,
                })
            }
            "FLASER" => {
                let n = f.count("num_readings")?;
                let ranges = (0..n)
                    .map(|k| f.range(k, &mut *invalid))
                    .collect::<Result<Vec<_>, _>>()?;
                let laser_pose = f.pose("")?;
                let odom_pose = f.pose("odom_")?;
                let timestamp = f.f64("timestamp")?;
                Record::Laser(LaserRecord {
                    line,
                    laser: LaserConfig::flaser(n, fov, opts.range_max),
                    ranges,
                    laser_pose,
                    odom_pose,
                    timestamp,
                })
            }
            _ => {
                // ROBOTLASER1 laser_type start_angle field_of_view angular_resolution
                // maximum_range accuracy remission_mode num_readings [ranges]
                // num_remissions [remissions] laser_x laser_y laser_theta robot_x
                // robot_y robot_theta tv rv forward_safety_dist side_safety_dist
                // turn_axis timestamp hostname logger_timestamp
                let _type = f.raw("laser_type")?;
                let start = f.f64("start_angle")?;
                let _fov = f.f64("field_of_view")?;
                let res = f.f64("angular_resolution")?;
                let max = f.f64("maximum_range")?;
                if res <= 0.0 || max <= 0.0 {
                    return Err(f.err(
                        "angular_resolution",
                        format!("resolution {res} and maximum range {max} must be positive"),
                    ));
                }
                let _accuracy = f.f64("accuracy")?;
                let _mode = f.raw("remission_mode")?;
                let n = f.count("num_readings")?;
                let ranges = (0..n)
                    .map(|k| f.range(k, &mut *invalid))
                    .collect::<Result<Vec<_>, _>>()?;
                let nr = f.count("num_remissions")?;
                for k in 0..nr {
                    f.f64(&format!("remission[{k}]"))?;
                }
                let laser_pose = f.pose("laser_")?;
                let odom_pose = f.pose("robot_")?;
                for field in ["tv", "rv", "forward_safety_dist", "side_safety_dist"] {
                    f.f64(field)?;
                }
                let _turn_axis = f.f64("turn_axis")?;
                let timestamp = f.f64("timestamp")?;
                Record::Laser(LaserRecord {
                    line,
                    laser: LaserConfig {
                        angle_min: start,
                        angle_increment: res,
                        range_min: 0.05f64.min(max / 2.0),
                        range_max: max,
                    },
                    ranges,
                    laser_pose,
                    odom_pose,
                    timestamp,
                })
            }
        };
        log.records.push(record);
    }
    Ok(log)
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
        let pts = s[0].laser.points(&s[0].ranges);
        assert_eq!(pts.len(), 2, "81.83 is no return");
        assert!((pts[0] - Vector2::new(0.0, -1.0)).norm() < 1e-12);
        assert_eq!(log.skipped.get("#"), Some(&1));
        assert_eq!(log.skipped.get("PARAM"), Some(&1));
        assert_eq!(log.skipped.get("NEFF"), Some(&1));
        assert_eq!(log.skipped_lines(), 3);
    }

    fn flaser_line(n: usize) -> String {
        let mut s = format!("FLASER {n}");
        for _ in 0..n {
            s.push_str(" 2.0");
        }
        s.push_str(" 0 0 0 0 0 0 1 h 1\n");
        s
    }

    /// The convention per beam count: first and last beam angle.
    #[test]
    fn flaser_geometry_follows_the_beam_count() {
        for (n, step, last) in [
            (180, 1.0, 89.0),
            (181, 1.0, 90.0),
            (360, 0.5, 89.5),
            (361, 0.5, 90.0),
        ] {
            let log = parse_log(&flaser_line(n), Path::new("x.log")).expect("log");
            let s = log.scans().next().expect("scan");
            let g = s.laser;
            assert!((g.angle_min.to_degrees() + 90.0).abs() < 1e-9, "{n}: {g:?}");
            assert!((g.angle_increment.to_degrees() - step).abs() < 1e-9, "{n}");
            let l = (g.angle_min + (n - 1) as f64 * g.angle_increment).to_degrees();
            assert!((l - last).abs() < 1e-9, "{n}: last beam at {l}");
        }
        // --fov 270 on a 1081-beam (odd) scan: 0.25 degrees, both ends.
        let opts = LogOptions {
            fov: Some(270f64.to_radians()),
            ..LogOptions::default()
        };
        let log = parse_log_with(&flaser_line(1081), Path::new("x.log"), &opts).expect("log");
        let g = log.scans().next().expect("scan").laser;
        assert!((g.angle_min.to_degrees() + 135.0).abs() < 1e-9);
        assert!((g.angle_increment.to_degrees() - 0.25).abs() < 1e-9);
    }

    #[test]
    fn parses_robotlaser1_with_its_own_geometry() {
        // 3 readings from -1.0 rad in 0.5 rad steps, max range 30; 2 remissions.
        let text = "ROBOTLASER1 0 -1.0 1.0 0.5 30.0 0.01 0 3 1.5 30.0 2.5 2 7 8 \
                    1 2 0.3 1.1 2.1 0.4 0 0 0.5 0.2 0 12.5 host 12.5\n";
        let log = parse_log(text, Path::new("r.log")).expect("log");
        let s = log.scans().next().expect("scan");
        assert_eq!(s.ranges, vec![1.5, 30.0, 2.5]);
        assert_eq!(s.laser.angle_min, -1.0);
        assert_eq!(s.laser.angle_increment, 0.5);
        assert_eq!(s.laser.range_max, 30.0);
        assert_eq!(s.laser_pose, [1.0, 2.0, 0.3]);
        assert_eq!(s.odom_pose, [1.1, 2.1, 0.4]);
        assert_eq!(s.timestamp, 12.5);
        let pts = s.laser.points(&s.ranges);
        assert_eq!(pts.len(), 2, "30.0 is the maximum: no return");
        assert!((pts[1] - Vector2::new(2.5 * 0.0f64.cos(), 0.0)).norm() < 1e-6);
        let e = parse_log(
            "ROBOTLASER1 0 -1.0 1.0 0.5 30.0 0.01 0 3 1.5 30.0\n",
            Path::new("r.log"),
        )
        .expect_err("short");
        assert_eq!(
            e.to_string(),
            "r.log:1: ROBOTLASER1 field `range[2]`: missing (line too short)"
        );
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
            "x.log:2: FLASER field `range[1]`: \"abc\" is not a number"
        );
        let e = parse_log("FLASER 2 1.0 1.0 0 0 0 0 0\n", Path::new("x.log")).expect_err("short");
        assert!(e.to_string().contains("field `odom_theta`"), "{e}");
        let e = parse_log("FLASER -1\n", Path::new("x.log")).expect_err("count");
        assert!(e.to_string().contains("field `num_readings`"), "{e}");
        let e = parse_log("ODOM nan 0 0 0 0 0 1 h 1\n", Path::new("x.log")).expect_err("nan");
        assert!(e.to_string().contains("x.log:1: ODOM field `x`"), "{e}");
    }

    #[test]
    fn nan_and_negative_ranges_are_invalid_readings_counted() {
        let text = "FLASER 4 1.0 nan -2.0 inf 0 0 0 0 0 0 1 h 1\nFOO bar\nFOO\n";
        let log = parse_log(text, Path::new("x.log")).expect("log");
        assert_eq!(log.invalid_ranges, 3);
        assert_eq!(log.skipped.get("FOO"), Some(&2));
        let s = log.scans().next().expect("scan");
        assert_eq!(s.ranges[0], 1.0);
        assert!(s.ranges[1..].iter().all(|r| r.is_nan()));
        assert_eq!(s.laser.points(&s.ranges).len(), 1);
    }

    #[test]
    fn odometry_deltas_skip_reanchoring_jumps_only() {
        // Corrected log: the ODOM after the scan equals the scan's pose (5 5 0).
        let text = "ODOM 0 0 0 0 0 0 0 h 0\nFLASER 0 5 5 0 0 0 0 0 h 0\n\
                    ODOM 5 5 0 0 0 0 1 h 1\nODOM 6 5 0 0 0 0 2 h 2\nFLASER 0 0 0 0 0 0 0 0 h 0\n";
        let log = parse_log(text, Path::new("x.log")).expect("log");
        let d = log.odometry_deltas();
        assert_eq!(d.len(), 2);
        assert!((d[1].translation.vector - Vector2::new(1.0, 0.0)).norm() < 1e-12);
        // Raw log: no re-anchoring, the increment across the scan is kept.
        let text = "ODOM 0 0 0 0 0 0 0 h 0\nFLASER 0 9 9 0 0 0 0 0 h 0\n\
                    ODOM 0.5 0 0 0 0 0 1 h 1\nODOM 1 0 0 0 0 0 2 h 2\nFLASER 0 0 0 0 0 0 0 0 h 0\n";
        let d = parse_log(text, Path::new("x.log"))
            .expect("log")
            .odometry_deltas();
        assert!((d[1].translation.vector - Vector2::new(1.0, 0.0)).norm() < 1e-12);
    }
}
