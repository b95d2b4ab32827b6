//! The visual tracker against the simulator's camera: images rendered from known poses, the
//! tracker's bearing and range checked against the geometry (no processes: both are
//! libraries; the camera module wires them later).

use hng_modules::tracker::{CameraModel, ColourTracker, ColourTrackerConfig};
use hng_simulator::render::{ImageParams, Renderer};
use hng_simulator::{Beacon, Pose2D, Wall, World};
use rand::SeedableRng;

fn yard() -> World {
    let mut w = World::empty(Pose2D::new(0.0, 0.0, 0.0));
    w.walls = vec![
        Wall::new([-1.0, -4.0], [9.0, -4.0]),
        Wall::new([9.0, -4.0], [9.0, 4.0]),
        Wall::new([9.0, 4.0], [-1.0, 4.0]),
        Wall::new([-1.0, 4.0], [-1.0, -4.0]),
    ];
    w.beacons = vec![
        Beacon {
            id: 3,
            position: [6.0, 1.0],
            radius: 0.1,
        },
        Beacon {
            id: 4,
            position: [4.0, -2.0],
            radius: 0.1,
        },
    ];
    w
}

#[test]
fn the_colour_tracker_finds_rendered_beacons_within_2_degrees_and_10_percent() {
    let world = yard();
    let params = ImageParams {
        noise_sigma: 3.0,
        ..ImageParams::default()
    };
    let renderer = Renderer::new(&world, params).expect("renderer");
    let camera = CameraModel {
        width: params.width,
        height: params.height,
        fov: params.fov,
        beacon_height: params.beacon_height,
    };
    let mut tracker = ColourTracker::new(ColourTrackerConfig::default(), camera);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut img = vec![0u8; params.image_bytes()];
    let mut checked = 0;
    for (x, y, theta) in [
        (0.0, 0.0, 0.0),
        (1.0, 0.5, 0.2),
        (2.0, -1.0, -0.3),
        (3.0, 0.0, 0.1),
        (0.5, 1.5, -0.2),
    ] {
        let pose = Pose2D::new(x, y, theta);
        renderer.render(pose, 1.0, Some(&mut rng), &mut img);
        for b in &world.beacons {
            let (dx, dy) = (b.position[0] - x, b.position[1] - y);
            let bearing = (dy.atan2(dx) - theta + std::f64::consts::PI)
                .rem_euclid(2.0 * std::f64::consts::PI)
                - std::f64::consts::PI;
            let range = dx.hypot(dy);
            let visible = renderer.beacon_box(pose, b.id).is_some();
            let d = tracker.detect(&img, b.id);
            assert_eq!(d.is_some(), visible, "beacon {} from {pose:?}: {d:?}", b.id);
            if let Some(d) = d {
                assert!(
                    (d.bearing - bearing).abs() < 2f64.to_radians(),
                    "beacon {} from {pose:?}: bearing {} vs {bearing}",
                    b.id,
                    d.bearing
                );
                assert!(
                    (d.range - range).abs() < 0.1 * range,
                    "beacon {} from {pose:?}: range {} vs {range}",
                    b.id,
                    d.range
                );
                checked += 1;
            }
        }
    }
    assert!(checked >= 6, "only {checked} detections checked");
    // In the dark the tracker loses the beacon its self-evaluation already rated poorly.
    let pose = Pose2D::new(0.0, 0.0, 0.0);
    let quality_at = |light: f64, tracker: &mut ColourTracker, img: &mut Vec<u8>| {
        renderer.render::<rand_chacha::ChaCha8Rng>(pose, light, None, img);
        tracker.detect(img, 3).map_or(0.0, |d| d.quality)
    };
    let bright = quality_at(1.0, &mut tracker, &mut img);
    let dusk = quality_at(0.35, &mut tracker, &mut img);
    let night = quality_at(0.1, &mut tracker, &mut img);
    assert!(bright > 0.8, "{bright}");
    assert!(dusk < bright && night < 0.05, "{bright} {dusk} {night}");
}
