//! `hng eval replay A.mcap B.mcap --channel slam/pose`: compares the poses of two recordings
//! of one channel (a run, and a module replayed alone against it).
//!
//! Each pose of B is paired with the pose of A whose time stamp is nearest (stamps are
//! simulated time when the run was simulated); the figures are position and heading
//! differences over the pairs, and how many pairs are bit-identical.

use std::path::Path;

use hng_runtime::msg::{Odometry, Pose2D, PoseWithCovariance};
use serde::Serialize;

use crate::Error;
use crate::codec::FixedCodec;
use crate::read::{load, scan};
use crate::registry::type_name;

/// The poses of one channel: (stamp ns, pose).
pub fn poses(path: &Path, channel: &str) -> Result<Vec<(u64, Pose2D)>, Error> {
    let buf = load(path)?;
    let pwc = type_name::<PoseWithCovariance>();
    let odo = type_name::<Odometry>();
    let mut out = Vec::new();
    let mut seen = false;
    let contents = scan(path, &buf, &mut |ch, _, data| {
        if ch.topic != channel {
            return Ok(());
        }
        seen = true;
        let t = ch.hng_type.as_deref().unwrap_or("");
        let codec = |detail| Error::Codec {
            channel: channel.to_string(),
            detail,
        };
        let (stamp, pose) = if t == pwc {
            let m = <PoseWithCovariance as FixedCodec>::decode(data).map_err(codec)?;
            (m.header.stamp_ns, m.pose)
        } else if t == odo {
            let m = <Odometry as FixedCodec>::decode(data).map_err(codec)?;
            (m.header.stamp_ns, m.pose)
        } else {
            return Err(Error::Other(format!(
                "{}: channel {channel:?} carries {t:?}, not poses ({pwc} or {odo})",
                path.display()
            )));
        };
        out.push((stamp, pose));
        Ok(())
    })?;
    if let Some(d) = contents.damage {
        tracing::warn!("{d}; comparing the poses before it");
    }
    if !seen && !contents.channels.values().any(|c| c.topic == channel) {
        return Err(Error::Other(format!(
            "{}: no channel {channel:?} in the recording",
            path.display()
        )));
    }
    out.sort_by_key(|(t, _)| *t);
    Ok(out)
}

/// How two recordings' poses compare.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// The channel.
    pub channel: String,
    /// Poses in A.
    pub a_messages: usize,
    /// Poses in B.
    pub b_messages: usize,
    /// Pairs (every pose of B, when A has any).
    pub pairs: usize,
    /// Pairs with the same stamp and bit-identical poses.
    pub identical: usize,
    /// Largest time between paired stamps, s.
    pub max_stamp_gap_s: f64,
    /// Position difference: mean, 95th percentile and largest, m.
    pub mean_position_error_m: f64,
    /// 95th percentile, m.
    pub p95_position_error_m: f64,
    /// Largest, m.
    pub max_position_error_m: f64,
    /// Largest heading difference, rad.
    pub max_heading_error_rad: f64,
    /// Position difference of the last pose of B, m.
    pub final_position_error_m: f64,
}

fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d.min(std::f64::consts::TAU - d)
}

/// Compares channel `channel` of `a` and `b`.
pub fn compare(a: &Path, b: &Path, channel: &str) -> Result<Comparison, Error> {
    let pa = poses(a, channel)?;
    let pb = poses(b, channel)?;
    let mut errs = Vec::with_capacity(pb.len());
    let (mut identical, mut gap, mut head) = (0usize, 0f64, 0f64);
    for (t, p) in &pb {
        let i = pa.partition_point(|(ta, _)| ta < t);
        let cands = [i.checked_sub(1), Some(i)];
        let Some((ta, q)) = cands
            .iter()
            .flatten()
            .filter_map(|j| pa.get(*j))
            .min_by_key(|(ta, _)| ta.abs_diff(*t))
        else {
            break;
        };
        gap = gap.max(ta.abs_diff(*t) as f64 * 1e-9);
        let e = (p.x - q.x).hypot(p.y - q.y);
        head = head.max(angle_diff(p.theta, q.theta));
        if ta == t
            && p.x.to_bits() == q.x.to_bits()
            && p.y.to_bits() == q.y.to_bits()
            && p.theta.to_bits() == q.theta.to_bits()
        {
            identical += 1;
        }
        errs.push(e);
    }
    let final_err = errs.last().copied().unwrap_or(f64::NAN);
    let mut sorted = errs.clone();
    sorted.sort_by(f64::total_cmp);
    let pct = |q: f64| {
        if sorted.is_empty() {
            f64::NAN
        } else {
            sorted[((sorted.len() - 1) as f64 * q).round() as usize]
        }
    };
    Ok(Comparison {
        channel: channel.to_string(),
        a_messages: pa.len(),
        b_messages: pb.len(),
        pairs: errs.len(),
        identical,
        max_stamp_gap_s: gap,
        mean_position_error_m: if errs.is_empty() {
            f64::NAN
        } else {
            errs.iter().sum::<f64>() / errs.len() as f64
        },
        p95_position_error_m: pct(0.95),
        max_position_error_m: pct(1.0),
        max_heading_error_rad: head,
        final_position_error_m: final_err,
    })
}

impl std::fmt::Display for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} pose(s) in A, {} in B, {} paired by time stamp ({} bit-identical), largest stamp gap {:.3} s",
            self.channel,
            self.a_messages,
            self.b_messages,
            self.pairs,
            self.identical,
            self.max_stamp_gap_s
        )?;
        writeln!(
            f,
            "position difference: mean {:.4} m, p95 {:.4} m, max {:.4} m, final {:.4} m; heading max {:.4} rad",
            self.mean_position_error_m,
            self.p95_position_error_m,
            self.max_position_error_m,
            self.final_position_error_m,
            self.max_heading_error_rad
        )
    }
}
