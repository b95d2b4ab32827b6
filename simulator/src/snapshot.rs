//! What a checkpoint keeps of a running simulation. It is a serde value: the SDK encodes and
//! decodes it (`hng_runtime::checkpoint_with!` in the simulator module), and a decoded one
//! is checked ([`SimSnapshot::validate`]) before it is applied.
//!
//! Restored: simulated time, the robot's true pose, the odometry pose, the counters, the next
//! due time of every sensor and the position of every noise stream, so a resumed simulation
//! continues the same sensor schedule and noise sequence. Not restored: the robot's velocity
//! (it resumes at rest and waits for a new command), and rapier's internal solver and contact
//! state (rebuilt from the world), so a resumed run is close to, not bit-identical with, an
//! uninterrupted one.

use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};
use crate::sensors::SimStats;
use crate::world::Pose2D;

/// The restorable state of a [`crate::Simulator`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// Checks a decoded snapshot before it is applied: every pose finite.
    ///
    /// # Errors
    /// A pose or the body's pose is not finite.
    pub fn validate(&self) -> Result<()> {
        let (p, o) = (self.pose, self.odom);
        let finite = [p.x, p.y, p.theta, o.x, o.y, o.theta]
            .iter()
            .all(|v| v.is_finite())
            && self.body.iter().all(|v| v.is_finite());
        if finite {
            Ok(())
        } else {
            Err(SimError::invalid("checkpoint", "pose is not finite"))
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use hng_runtime::module::{decode_state, encode_state};

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
        let bytes = encode_state(&s).unwrap();
        assert_eq!(decode_state::<SimSnapshot>(&bytes).unwrap(), s);
        // Damage inside the file is the checksum's to catch (hng_runtime::checkpoint); a cut
        // or overlong state is refused here.
        assert!(decode_state::<SimSnapshot>(&bytes[..bytes.len() - 1]).is_err());
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(decode_state::<SimSnapshot>(&longer).is_err());
        let mut nan = s.clone();
        nan.pose.x = f64::NAN;
        assert!(nan.validate().is_err());
        assert!(s.validate().is_ok());
        Ok(())
    }

    #[test]
    fn a_restored_simulator_continues_the_same_streams() -> Result<()> {
        let mut a = crate::Simulator::new(crate::World::default_world())?;
        a.set_cmd_vel(0.5, 0.2)?;
        a.run_until(1_500_000_000);
        // Let the robot come to rest (command timeout), as a restored one starts at rest.
        a.run_until(3_000_000_000);
        let bytes = encode_state(&a.snapshot()).unwrap();
        let mut b = crate::Simulator::new(crate::World::default_world())?;
        b.restore(&decode_state::<SimSnapshot>(&bytes).unwrap())?;
        assert_eq!(b.now_ns(), a.now_ns());
        assert_eq!(b.stats(), a.stats());
        let (ga, gb) = (a.ground_truth(), b.ground_truth());
        assert_eq!((ga.x, ga.y, ga.theta), (gb.x, gb.y, gb.theta));
        assert_eq!(a.run_until(4_000_000_000), b.run_until(4_000_000_000));
        Ok(())
    }
}
