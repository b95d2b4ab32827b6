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

/// The rendered scene both tests look at: the yard, a renderer with pixel noise of
/// `noise_sigma`, and the camera model the trackers need for it.
struct Scene {
    world: World,
    params: ImageParams,
    renderer: Renderer,
    camera: CameraModel,
}

fn scene(noise_sigma: f64) -> Scene {
    let world = yard();
    let params = ImageParams {
        noise_sigma,
        ..ImageParams::default()
    };
    let renderer = Renderer::new(&world, params).expect("renderer");
    let camera = hng::bench::vision::camera_model(&params);
    Scene {
        world,
        params,
        renderer,
        camera,
    }
}

#[test]
fn the_colour_tracker_finds_rendered_beacons_within_2_degrees_and_10_percent() {
    let Scene {
        world,
        params,
        renderer,
        camera,
    } = scene(3.0);
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

/// Both trackers on rendered images of one scene at falling light: the colour tracker rates
/// itself higher in good light and loses the beacon in the dark (0.15), where the histogram
/// tracker keeps it; near black (0.1) both rate themselves low. Where a tracker vouches for a
/// detection (Q >= 0.2) its bearing is within 2 degrees and its range within 12 %.
#[test]
fn the_histogram_tracker_keeps_the_beacon_in_the_dark_the_colour_tracker_loses() {
    use hng_modules::tracker_hist::{HistogramTracker, HistogramTrackerConfig};
    let Scene {
        world,
        params,
        renderer,
        camera,
    } = scene(2.0);
    let mut colour = ColourTracker::new(ColourTrackerConfig::default(), camera);
    let mut hist = HistogramTracker::new(HistogramTrackerConfig::default(), camera);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut img = vec![0u8; params.image_bytes()];
    let pose = Pose2D::new(1.0, 0.5, 0.1);
    let truth = |b: &Beacon| {
        let (dx, dy) = (b.position[0] - pose.x, b.position[1] - pose.y);
        (dy.atan2(dx) - pose.theta, dx.hypot(dy))
    };
    let mut table = Vec::new();
    for light in [1.0, 0.6, 0.3, 0.15, 0.1] {
        renderer.render(pose, light, Some(&mut rng), &mut img);
        for b in world
            .beacons
            .iter()
            .filter(|b| renderer.beacon_box(pose, b.id).is_some())
        {
            let c = colour.detect(&img, b.id);
            let h = hist.detect(&img, b.id);
            let (bearing, range) = truth(b);
            // Accuracy is asserted where a tracker vouches for its detection (Q >= 0.2).
            for d in [c, h].into_iter().flatten().filter(|d| d.quality >= 0.2) {
                assert!(
                    (d.bearing - bearing).abs() < 2f64.to_radians(),
                    "beacon {} at light {light}: {d:?} vs {bearing}",
                    b.id
                );
                assert!(
                    (d.range - range).abs() < 0.12 * range,
                    "beacon {} at light {light}: {d:?} vs {range}",
                    b.id
                );
            }
            let q = |d: Option<hng_modules::tracker::Detection>| d.map_or(0.0, |d| d.quality);
            table.push((light, b.id, q(c), q(h)));
        }
    }
    assert_eq!(
        table.len(),
        5,
        "one beacon in view at every light: {table:?}"
    );
    for (light, id, c, h) in &table {
        println!("light {light:4}: beacon {id}: colour Q {c:.2}, histogram Q {h:.2}");
    }
    for &(light, _, c, h) in &table {
        if light >= 0.6 {
            assert!(
                c > h + 0.1,
                "good light ({light}): colour {c} must beat histogram {h} by the hysteresis"
            );
        }
        if (0.12..=0.2).contains(&light) {
            assert!(
                c < 0.05 && h > c + 0.3,
                "dark ({light}): colour {c}, histogram {h}"
            );
        }
        if light < 0.12 {
            assert!(
                c < 0.05 && h < 0.2,
                "near black ({light}): both rate themselves low: {c} {h}"
            );
        }
    }
}
