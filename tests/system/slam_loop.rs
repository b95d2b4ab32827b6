//! SLAM's loop closure on a simulated loop: scans from the simulator (a library here, no
//! processes), poses from the SLAM library. Lives in the root package because hng-modules never
//! links the simulator.

use hng_modules::nalgebra::{Isometry2, Vector2};
use hng_modules::slam::{BackendConfig, LaserConfig, Slam, SlamConfig};
use hng_simulator::{Pose2D, Simulator, World};

/// A closed loop (twice round the yard of the default world, 0.25 m between scans), a
/// short-range lidar and biased odometry: loop closure at least halves the final pose error.
#[test]
fn loop_closure_reduces_the_final_error_on_a_simulated_loop() {
    let world = World::default_world();
    let mut sim = Simulator::new(world).expect("simulator");
    // A loop through the yard (x < 8): out along y = 2, up x = 6.5, back along y = 13.5,
    // down x = 1.5, twice round, 0.25 m between scans.
    let corners: [(f64, f64); 4] = [(1.5, 2.0), (6.5, 2.0), (6.5, 13.5), (1.5, 13.5)];
    let mut truth: Vec<Isometry2<f64>> = Vec::new();
    for _lap in 0..2 {
        for c in 0..4 {
            let (a, b) = (corners[c], corners[(c + 1) % 4]);
            let heading = (b.1 - a.1).atan2(b.0 - a.0);
            let len = (b.0 - a.0).hypot(b.1 - a.1);
            let n = (len / 0.25).round() as usize;
            for i in 0..n {
                let t = i as f64 / n as f64;
                truth.push(Isometry2::new(
                    Vector2::new(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)),
                    heading,
                ));
            }
        }
    }
    truth.push(truth[0]);
    let scans: Vec<(LaserConfig, Vec<f32>)> = truth
        .iter()
        .map(|p| {
            sim.teleport(Pose2D::new(
                p.translation.x,
                p.translation.y,
                p.rotation.angle(),
            ))
            .expect("teleport");
            let s = sim.scan_lidar();
            (
                LaserConfig {
                    angle_min: f64::from(s.angle_min),
                    angle_increment: f64::from(s.angle_increment),
                    range_min: f64::from(s.range_min),
                    // A short-range lidar: in the open yard it sees about one wall at a
                    // time, so the front end drifts along it with the odometry's error.
                    range_max: 3.0,
                },
                s.ranges,
            )
        })
        .collect();
    // Odometry 3 % long and turning 1.5 degrees too far per metre.
    let run = |loop_closure: bool| {
        let mut slam = Slam::new(
            SlamConfig::default(),
            BackendConfig {
                loop_closure,
                ..BackendConfig::default()
            },
            truth[0],
        );
        for k in 0..truth.len() {
            let d = if k == 0 {
                Isometry2::identity()
            } else {
                let t = truth[k - 1].inverse() * truth[k];
                let dist = t.translation.vector.norm();
                t * Isometry2::new(Vector2::new(0.03 * dist, 0.0), (1.5f64 * dist).to_radians())
            };
            slam.process(&d, &scans[k].0, &scans[k].1);
        }
        slam.finish();
        let end = *slam.trajectory().last().expect("poses");
        let err = (truth[truth.len() - 1].inverse() * end)
            .translation
            .vector
            .norm();
        (err, slam.stats())
    };
    let (without, _) = run(false);
    let (with, stats) = run(true);
    println!("final error without loop closure {without:.3} m, with {with:.3} m, {stats:?}");
    assert!(stats.closures > 0, "{stats:?}");
    // Measured: 0.54 m without, 0.145 m with (91 closures).
    assert!(with < 0.5 * without, "with {with} m, without {without} m");
}
