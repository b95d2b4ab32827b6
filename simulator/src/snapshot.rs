//! What a checkpoint keeps of a running simulation, and its byte encoding.
//!
//! Restored: simulated time, the robot's true pose, the odometry pose, the counters, the next
//! due time of every sensor and the position of every noise stream, so a resumed simulation
//! continues the same sensor schedule and noise sequence. Not restored: the robot's velocity
//! (it resumes at rest and waits for a new command), and rapier's internal solver and contact
//! state (rebuilt from the world), so a resumed run is close to, not bit-identical with, an
//! uninterrupted one.

use crate::error::{Result, SimError};
use crate::sensors::SimStats;
use crate::world::Pose2D;

/// Format version written first in [`SimSnapshot::to_bytes`].
const VERSION: u32 = 1;
/// Encoded size in bytes.
const LEN: usize = 4 + 8 + 3 * 8 + 4 * 4 + 3 * 8 + 4 * 8 + 8 + 5 * 8 + 5 * 16;

/// The restorable state of a [`crate::Simulator`].
#[derive(Debug, Clone, PartialEq)]
pub struct SimSnapshot {
    /// Simulated time, ns.
    pub now_ns: u64,
    /// True pose in the map frame.
    pub pose: Pose2D,
    /// The physics body's exact pose: x, y, cos and sin of the heading (single precision, as
    /// rapier keeps it; `pose.theta` alone does not give the same rotation back).
    pub body: [f32; 4],
    /// Odometry pose in the odom frame.
    pub odom: Pose2D,
    /// Counters.
    pub stats: SimStats,
    /// Next due time of lidar, odometry, GPS, camera and ground truth, ns.
    pub next_due_ns: [u64; 5],
    /// Word positions of the lidar, odometry, GPS, camera and spare noise streams.
    pub rng_word_pos: [u128; 5],
}

impl SimSnapshot {
    /// Encodes the snapshot (little-endian, versioned, fixed size).
    #[must_use]
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(LEN);
        b.extend(VERSION.to_le_bytes());
        b.extend(self.now_ns.to_le_bytes());
        for p in [self.pose, self.odom] {
            for v in [p.x, p.y, p.theta] {
                b.extend(v.to_le_bytes());
            }
        }
        for v in self.body {
            b.extend(v.to_le_bytes());
        }
        let s = &self.stats;
        for v in [
            s.steps,
            s.collisions,
            s.rejected_commands,
            s.command_timeouts,
        ] {
            b.extend(v.to_le_bytes());
        }
        b.extend(s.min_clearance.to_le_bytes());
        for v in self.next_due_ns {
            b.extend(v.to_le_bytes());
        }
        for v in self.rng_word_pos {
            b.extend(v.to_le_bytes());
        }
        b
    }

    /// Decodes bytes written by [`SimSnapshot::to_bytes`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let bad = |m: String| SimError::invalid("checkpoint", m);
        if bytes.len() != LEN {
            return Err(bad(format!("{} bytes, expected {LEN}", bytes.len())));
        }
        let mut r = Reader { bytes, pos: 0 };
        let version = u32::from_le_bytes(r.take()?);
        if version != VERSION {
            return Err(bad(format!("version {version}, expected {VERSION}")));
        }
        let now_ns = r.u64()?;
        let mut pose = || -> Result<Pose2D> { Ok(Pose2D::new(r.f64()?, r.f64()?, r.f64()?)) };
        let (pose, odom) = (pose()?, pose()?);
        let mut body = [0.0f32; 4];
        for v in &mut body {
            *v = f32::from_le_bytes(r.take()?);
        }
        let stats = SimStats {
            steps: r.u64()?,
            collisions: r.u64()?,
            rejected_commands: r.u64()?,
            command_timeouts: r.u64()?,
            min_clearance: r.f64()?,
        };
        let mut next_due_ns = [0; 5];
        for v in &mut next_due_ns {
            *v = r.u64()?;
        }
        let mut rng_word_pos = [0; 5];
        for v in &mut rng_word_pos {
            *v = u128::from_le_bytes(r.take()?);
        }
        let snap = Self {
            now_ns,
            pose,
            body,
            odom,
            stats,
            next_due_ns,
            rng_word_pos,
        };
        let finite = [pose.x, pose.y, pose.theta, odom.x, odom.y, odom.theta]
            .iter()
            .all(|v| v.is_finite())
            && body.iter().all(|v| v.is_finite());
        if !finite {
            return Err(bad("pose is not finite".to_owned()));
        }
        Ok(snap)
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N]> {
        let chunk = self
            .bytes
            .get(self.pos..self.pos + N)
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or_else(|| SimError::invalid("checkpoint", "truncated"))?;
        self.pos += N;
        Ok(chunk)
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take()?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snapshot_round_trips_and_rejects_garbage() -> Result<()> {
        let s = SimSnapshot {
            now_ns: 12_340_000_000,
            pose: Pose2D::new(1.5, -2.0, 0.3),
            body: [1.5, -2.0, 0.3f32.cos(), 0.3f32.sin()],
            odom: Pose2D::new(0.1, 0.2, -3.0),
            stats: SimStats {
                steps: 1234,
                collisions: 2,
                rejected_commands: 1,
                command_timeouts: 3,
                min_clearance: 0.01,
            },
            next_due_ns: [1, 2, 3, 4, 5],
            rng_word_pos: [u128::MAX, 0, 7, 8, 9],
        };
        let bytes = s.to_bytes();
        assert_eq!(bytes.len(), LEN);
        assert_eq!(SimSnapshot::from_bytes(&bytes)?, s);
        assert!(SimSnapshot::from_bytes(&bytes[1..]).is_err());
        let mut other = bytes.clone();
        other[0] = 9;
        assert!(SimSnapshot::from_bytes(&other).is_err());
        Ok(())
    }

    #[test]
    fn a_restored_simulator_continues_the_same_streams() -> Result<()> {
        let mut a = crate::Simulator::new(crate::World::default_world())?;
        a.set_cmd_vel(0.5, 0.2)?;
        a.run_until(1_500_000_000);
        // Let the robot come to rest (command timeout), as a restored one starts at rest.
        a.run_until(3_000_000_000);
        let bytes = a.snapshot().to_bytes();
        let mut b = crate::Simulator::new(crate::World::default_world())?;
        b.restore(&SimSnapshot::from_bytes(&bytes)?)?;
        assert_eq!(b.now_ns(), a.now_ns());
        assert_eq!(b.stats(), a.stats());
        let (ga, gb) = (a.ground_truth(), b.ground_truth());
        assert_eq!((ga.x, ga.y, ga.theta), (gb.x, gb.y, gb.theta));
        assert_eq!(a.run_until(4_000_000_000), b.run_until(4_000_000_000));
        Ok(())
    }
}
