//! Integration tests of hng-simulator.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::path::Path;

use hng_simulator::{
    Beacon, BoxObstacle, GpsStatus, OccupancyGrid, OdometryConfig, Pose2D, Result, SensorKind,
    SensorOutput, SimError, Simulator, Wall, World, map, secs_to_ns, wrap_angle,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn quiet(mut w: World) -> World {
    w.sensors.lidar.range_sigma = 0.0;
    w.sensors.odometry = OdometryConfig::noise_free();
    w.sensors.gps.position_sigma = 0.0;
    w.sensors.gps.yaw_sigma = 0.0;
    w.sensors.camera.bearing_sigma = 0.0;
    w.sensors.camera.range_sigma = 0.0;
    w
}

/// Distance along the ray to a solid box, in f64; 0 when the origin is inside.
fn ray_box(o: [f64; 2], d: [f64; 2], b: &BoxObstacle) -> Option<f64> {
    let (s, c) = b.angle.sin_cos();
    let (px, py) = (o[0] - b.center[0], o[1] - b.center[1]);
    let lo = [c * px + s * py, -s * px + c * py];
    let ld = [c * d[0] + s * d[1], -s * d[0] + c * d[1]];
    let h = [b.size[0] / 2.0, b.size[1] / 2.0];
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for k in 0..2 {
        if ld[k].abs() < 1e-15 {
            if lo[k].abs() > h[k] {
                return None;
            }
        } else {
            let a = (-h[k] - lo[k]) / ld[k];
            let bb = (h[k] - lo[k]) / ld[k];
            t0 = t0.max(a.min(bb));
            t1 = t1.min(a.max(bb));
        }
    }
    (t0 <= t1).then_some(t0)
}

fn analytic(world: &World, o: [f64; 2], angle: f64) -> f64 {
    let d = [angle.cos(), angle.sin()];
    world
        .obstacle_boxes()
        .iter()
        .filter_map(|b| ray_box(o, d, b))
        .fold(f64::INFINITY, f64::min)
}

fn lidar_world() -> World {
    let mut w = quiet(World::empty(Pose2D::new(1.0, 0.3, 0.0)));
    w.walls = vec![
        Wall::new([-2.0, 0.0], [12.0, 0.0]), // floor the robot grazes along
        Wall::new([12.0, 0.0], [12.0, 6.0]),
        Wall::new([12.0, 6.0], [-2.0, 6.0]),
        Wall::new([-2.0, 6.0], [-2.0, 0.0]),
        Wall {
            from: [3.0, 2.0],
            to: [7.0, 3.1],
            thickness: 0.3,
            color: None,
        }, // slanted thick wall
        Wall::new([8.0, 1.0], [8.0, 4.0]),
    ];
    w.boxes = vec![BoxObstacle {
        center: [2.0, 4.5],
        size: [0.7, 0.4],
        angle: 0.4,
        color: None,
    }];
    w.sensors.lidar.beams = 3600;
    w.sensors.lidar.max_range = 9.0;
    w
}

#[test]
fn noise_free_lidar_matches_geometry_within_1mm_including_grazing_rays() -> Result<()> {
    let world = lidar_world();
    let mut sim = Simulator::new(world.clone())?;
    let poses = [
        Pose2D::new(1.0, 0.3, 0.0),
        Pose2D::new(0.0, 0.23, 0.01),
        Pose2D::new(5.0, 1.0, 1.0),
        Pose2D::new(10.0, 5.0, -2.5),
        Pose2D::new(-1.5, 5.7, 0.7),
        Pose2D::new(6.0, 4.0, 3.0),
    ];
    let (mut checked, mut grazing) = (0, 0);
    for pose in poses {
        sim.teleport(pose)?;
        let scan = sim.scan_lidar();
        let gt = sim.ground_truth();
        for (i, &r) in scan.ranges.iter().enumerate() {
            let angle = gt.theta + f64::from(scan.angle_min) + i as f64 * TAU / 3600.0;
            let expect = analytic(&world, [gt.x, gt.y], angle);
            let max = world.sensors.lidar.max_range;
            if (expect - max).abs() < 1e-3 {
                continue; // at the range limit either answer is right
            }
            if expect > max {
                assert_eq!(
                    r,
                    f32::INFINITY,
                    "pose {pose:?} beam {i}: expected no return"
                );
            } else {
                let err = (f64::from(r) - expect).abs();
                assert!(err < 1e-3, "pose {pose:?} beam {i}: {r} vs {expect}");
                // Grazing: the ray meets the floor wall at under 5 degrees.
                if angle.sin().abs() < 0.087 && expect > 2.0 && gt.y < 0.5 {
                    grazing += 1;
                }
            }
            checked += 1;
        }
    }
    assert!(checked > 20_000, "{checked}");
    assert!(grazing > 50, "only {grazing} grazing rays checked");
    Ok(())
}

#[test]
fn lidar_beam_layout_is_symmetric_for_partial_fov() -> Result<()> {
    let mut w = lidar_world();
    w.sensors.lidar.beams = 181;
    w.sensors.lidar.fov = PI;
    let scan = Simulator::new(w)?.scan_lidar();
    assert!((f64::from(scan.angle_min) + FRAC_PI_2).abs() < 1e-6);
    let last = scan.angle_min + 180.0 * scan.angle_increment;
    assert!((f64::from(last) - FRAC_PI_2).abs() < 1e-5);
    Ok(())
}

#[test]
fn robot_driven_at_a_wall_never_passes_through() -> Result<()> {
    let mut w = World::empty(Pose2D::new(2.0, 0.0, 0.0));
    w.walls = vec![Wall::new([5.0, -5.0], [5.0, 5.0])];
    w.robot.max_linear_speed = 3.0;
    w.robot.max_linear_accel = 10.0;
    let face = 5.0 - 0.025;
    let mut sim = Simulator::new(w)?;
    let mut events = 0;
    for _ in 0..3000 {
        sim.set_cmd_vel(3.0, 0.0)?;
        events += sim
            .step()
            .iter()
            .filter(|o| matches!(o, SensorOutput::Collision(_)))
            .count();
        let gt = sim.ground_truth();
        assert!(
            gt.x + 0.2 <= face + 0.005,
            "robot at x = {} went into the wall",
            gt.x
        );
    }
    let stats = sim.stats();
    assert_eq!(
        stats.collisions, 1,
        "pushing against the wall is one contact"
    );
    assert_eq!(events, 1);
    assert!(stats.min_clearance > -0.005, "{}", stats.min_clearance);
    assert!(
        (sim.ground_truth().x + 0.2 - face).abs() < 0.01,
        "stopped at {}",
        sim.ground_truth().x
    );
    Ok(())
}

#[test]
fn random_driving_in_default_world_never_crosses_a_wall() -> Result<()> {
    let mut w = World::default_world();
    w.robot.max_linear_speed = 2.0;
    let mut sim = Simulator::new(w)?;
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let mut cmd = (0.0, 0.0);
    let steps = secs_to_ns(300.0) / sim.dt_ns(); // five simulated minutes
    let mut prev = sim.ground_truth();
    for k in 0..steps {
        if k % 50 == 0 {
            cmd = (rng.random_range(-0.5..2.0), rng.random_range(-2.0..2.0));
        }
        sim.set_cmd_vel(cmd.0, cmd.1)?;
        sim.step();
        let gt = sim.ground_truth();
        let (dx, dy) = (gt.x - prev.x, gt.y - prev.y);
        let moved = dx.hypot(dy);
        if moved > 1e-6 {
            let hit = sim.cast_ray([prev.x, prev.y], dy.atan2(dx), moved);
            assert!(
                hit.is_none(),
                "step {k}: centre crossed an obstacle from {prev:?} to {gt:?}"
            );
        }
        assert!(
            sim.clearance() > -0.02,
            "step {k}: penetration {}",
            sim.clearance()
        );
        assert!(
            (0.2..=19.8).contains(&gt.x) && (0.2..=14.8).contains(&gt.y),
            "left the area: {gt:?}"
        );
        prev = gt;
    }
    assert!(
        sim.stats().collisions > 0,
        "random driving should bump into something"
    );
    Ok(())
}

#[test]
fn noise_free_odometry_integrates_the_commanded_motion() -> Result<()> {
    let start = Pose2D::new(5.0, 5.0, 0.5);
    let mut sim = Simulator::new(quiet(World::empty(start)))?;
    let (v, w) = (0.5, 0.3);
    let mut last_odom = None;
    // Reference: the same accelerate-then-cruise profile integrated exactly in the odom frame.
    let (mut rv, mut rw, mut rx, mut ry, mut rth) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let dt = 0.01;
    for _ in 0..1000 {
        sim.set_cmd_vel(v, w)?;
        rv += (v - rv).clamp(-2.0 * dt, 2.0 * dt);
        rw += (w - rw).clamp(-6.0 * dt, 6.0 * dt);
        let n = 100;
        for _ in 0..n {
            let h = dt / f64::from(n);
            rx += rv * (rth + rw * h / 2.0).cos() * h;
            ry += rv * (rth + rw * h / 2.0).sin() * h;
            rth += rw * h;
        }
        for o in sim.step() {
            if let SensorOutput::Odometry(od) = o {
                last_odom = Some(od);
            }
        }
    }
    let od = last_odom.ok_or_else(|| SimError::Invalid {
        field: "odom".into(),
        message: "none".into(),
    })?;
    // Against the reference integration of the commands.
    assert!(
        (od.x - rx).abs() < 0.01 && (od.y - ry).abs() < 0.01,
        "odom {od:?} vs ({rx}, {ry})"
    );
    assert!(
        wrap_angle(od.theta - rth).abs() < 0.005,
        "{} vs {rth}",
        od.theta
    );
    assert!(
        (od.linear_x - v).abs() < 1e-3 && (od.angular_z - w).abs() < 1e-3,
        "{od:?}"
    );
    // Against ground truth expressed in the odom frame (which starts at the start pose).
    let gt = sim.ground_truth();
    let (s, c) = start.theta.sin_cos();
    let (dx, dy) = (gt.x - start.x, gt.y - start.y);
    let (ox, oy) = (c * dx + s * dy, -s * dx + c * dy);
    assert!(
        (od.x - ox).abs() < 1e-4 && (od.y - oy).abs() < 1e-4,
        "{od:?} vs ({ox}, {oy})"
    );
    assert!(wrap_angle(od.theta - (gt.theta - start.theta)).abs() < 1e-4);
    Ok(())
}

#[test]
fn odometry_with_errors_drifts_from_ground_truth() -> Result<()> {
    let mut sim = Simulator::new(World::empty(Pose2D::new(0.0, 0.0, 0.0)))?;
    let mut last = None;
    for _ in 0..2000 {
        sim.set_cmd_vel(1.0, 0.2)?;
        for o in sim.step() {
            if let SensorOutput::Odometry(od) = o {
                last = Some(od);
            }
        }
    }
    let (od, gt) = (
        last.map(|o| (o.x, o.y)).unwrap_or_default(),
        sim.ground_truth(),
    );
    let err = (od.0 - gt.x).hypot(od.1 - gt.y);
    assert!(err > 0.01 && err < 3.0, "drift {err}");
    Ok(())
}

fn camera_frame(sim: &mut Simulator) -> Vec<hng_simulator::BeaconDetection> {
    sim.set_sensor_enabled(SensorKind::Camera, false);
    sim.set_sensor_enabled(SensorKind::Camera, true); // due at once
    sim.step()
        .into_iter()
        .find_map(|o| match o {
            SensorOutput::Camera(f) => Some(f.detections),
            _ => None,
        })
        .unwrap_or_default()
}

#[test]
fn camera_respects_fov_range_and_occlusion() -> Result<()> {
    let mut w = quiet(World::empty(Pose2D::new(0.0, 0.0, 0.0)));
    w.sensors.camera.fov = 2.0;
    w.sensors.camera.max_range = 8.0;
    w.walls = vec![Wall::new([2.0, -2.0], [2.0, -0.8])];
    let b = |id, x, y| Beacon {
        id,
        position: [x, y],
        radius: 0.1,
    };
    w.beacons = vec![
        b(1, 3.0, 0.0),
        b(2, 0.0, 3.0),
        b(3, 3.0, -2.0),
        b(4, 20.0, 0.0),
        b(5, 2.0, 1.5),
    ];
    let mut sim = Simulator::new(w)?;
    let seen = camera_frame(&mut sim);
    let ids: Vec<u32> = seen.iter().map(|d| d.id).collect();
    assert_eq!(
        ids,
        vec![1, 5],
        "beacon 2 outside the FOV, 3 occluded, 4 out of range"
    );
    let d5 = seen[1];
    assert!(
        (d5.distance - 2.5).abs() < 1e-3 && (d5.bearing - 1.5f64.atan2(2.0)).abs() < 1e-3,
        "{d5:?}"
    );
    sim.teleport(Pose2D::new(0.0, 0.0, FRAC_PI_2))?;
    let ids: Vec<u32> = camera_frame(&mut sim).iter().map(|d| d.id).collect();
    assert_eq!(ids, vec![2, 5]);
    Ok(())
}

fn drive_and_record(world: World, seconds: f64) -> Result<Vec<SensorOutput>> {
    let mut sim = Simulator::new(world)?;
    let mut all = Vec::new();
    let mut out = Vec::new();
    while sim.now_ns() < secs_to_ns(seconds) {
        out.clear();
        sim.step_into(&mut out);
        for o in &out {
            if let SensorOutput::Lidar(scan) = o {
                let (v, w) = hng_simulator::bench::wander(scan);
                sim.set_cmd_vel(v, w)?;
            }
        }
        all.extend(out.iter().cloned());
    }
    Ok(all)
}

#[test]
fn same_seed_gives_identical_streams_and_different_seed_does_not() -> Result<()> {
    let a = drive_and_record(World::default_world(), 20.0)?;
    let b = drive_and_record(World::default_world(), 20.0)?;
    assert!(a.len() > 3000);
    // Debug output of floats round-trips, so equal text means equal bits.
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
    let mut other = World::default_world();
    other.seed += 1;
    let c = drive_and_record(other, 20.0)?;
    let lidar = |s: &[SensorOutput]| {
        s.iter()
            .find_map(|o| match o {
                SensorOutput::Lidar(l) => Some(l.ranges.clone()),
                _ => None,
            })
            .unwrap_or_default()
    };
    assert_ne!(lidar(&a), lidar(&c));
    Ok(())
}

#[test]
fn sensors_publish_at_their_rates_and_can_be_switched_off() -> Result<()> {
    let mut w = World::default_world();
    w.sensors.camera.enabled = false; // hybrid: a real camera provides this channel
    let mut sim = Simulator::new(w)?;
    let out = sim.run_until(secs_to_ns(1.0));
    let count = |f: fn(&SensorOutput) -> bool| out.iter().filter(|o| f(o)).count();
    assert_eq!(count(|o| matches!(o, SensorOutput::Lidar(_))), 10);
    assert_eq!(count(|o| matches!(o, SensorOutput::Odometry(_))), 50);
    assert_eq!(count(|o| matches!(o, SensorOutput::Gps(_))), 5);
    assert_eq!(count(|o| matches!(o, SensorOutput::GroundTruth(_))), 100);
    assert_eq!(count(|o| matches!(o, SensorOutput::Camera(_))), 0);
    assert!(out.windows(2).all(|p| p[0].stamp_ns() <= p[1].stamp_ns()));
    sim.set_sensor_enabled(SensorKind::Lidar, false);
    let out = sim.run_until(secs_to_ns(2.0));
    assert!(!out.iter().any(|o| matches!(o, SensorOutput::Lidar(_))));
    Ok(())
}

#[test]
fn gps_quality_depends_on_the_zone() -> Result<()> {
    let mut sim = Simulator::new(World::default_world())?;
    let mut gps_at = |pose: Pose2D| -> Result<hng_simulator::GpsReading> {
        sim.teleport(pose)?;
        sim.set_sensor_enabled(SensorKind::Gps, false);
        sim.set_sensor_enabled(SensorKind::Gps, true);
        sim.step()
            .into_iter()
            .find_map(|o| match o {
                SensorOutput::Gps(g) => Some(g),
                _ => None,
            })
            .ok_or_else(|| SimError::Invalid {
                field: "gps".into(),
                message: "no reading".into(),
            })
    };
    let yard = gps_at(Pose2D::new(2.0, 2.0, 0.0))?;
    assert_eq!(yard.status, GpsStatus::Fix);
    assert!((yard.x - 2.0).abs() < 2.0 && yard.position_sigma == 0.3);
    let south = gps_at(Pose2D::new(11.0, 4.0, 0.0))?;
    assert_eq!(south.status, GpsStatus::Degraded);
    assert!((south.position_sigma - 1.5).abs() < 1e-12);
    let north = gps_at(Pose2D::new(11.0, 11.0, 0.0))?;
    assert_eq!(north.status, GpsStatus::NoFix);
    Ok(())
}

/// A simulator of an empty world whose robot was driven at `linear` m/s and `angular`
/// rad/s for 0.4 s, and is moving.
fn moving(linear: f64, angular: f64) -> Result<Simulator> {
    let mut sim = Simulator::new(World::empty(Pose2D::new(0.0, 0.0, 0.0)))?;
    sim.set_cmd_vel(linear, angular)?;
    sim.run_until(secs_to_ns(0.4));
    assert!(sim.ground_truth().linear_x > 0.5);
    Ok(sim)
}

#[test]
fn nan_and_infinite_commands_are_rejected_and_counted() -> Result<()> {
    let mut sim = moving(1.0, 0.0)?;
    assert!(matches!(
        sim.set_cmd_vel(f64::NAN, 0.0),
        Err(SimError::RejectedCommand { .. })
    ));
    assert!(sim.set_cmd_vel(0.0, f64::INFINITY).is_err());
    assert!(sim.set_cmd_vel(f64::NEG_INFINITY, f64::NAN).is_err());
    assert_eq!(sim.stats().rejected_commands, 3);
    sim.run_until(secs_to_ns(1.2));
    let gt = sim.ground_truth();
    assert!(gt.x.is_finite() && gt.y.is_finite() && gt.theta.is_finite());
    assert!(
        gt.linear_x.abs() < 1e-6 && gt.angular_z.abs() < 1e-6,
        "robot did not stop: {gt:?}"
    );
    Ok(())
}

#[test]
fn robot_stops_when_commands_stop_arriving() -> Result<()> {
    let mut sim = moving(1.0, 0.5)?;
    sim.run_until(secs_to_ns(2.0)); // timeout 0.5 s, then decelerate at 2 m/s²
    assert!(sim.ground_truth().linear_x.abs() < 1e-6);
    assert_eq!(sim.stats().command_timeouts, 1);
    Ok(())
}

/// Writes a map_server pair: `rows` are image rows top first, '#' occupied, '.' free.
fn write_map(
    dir: &Path,
    rows: &[&str],
    resolution: f64,
    origin: [f64; 2],
) -> Result<std::path::PathBuf> {
    let (w, h) = (rows[0].len(), rows.len());
    let mut pgm = format!("P5\n# test map\n{w} {h}\n255\n").into_bytes();
    for r in rows {
        pgm.extend(r.bytes().map(|c| if c == b'#' { 0u8 } else { 254 }));
    }
    write(&dir.join("l.pgm"), pgm)?;
    let yaml = format!(
        "image: l.pgm\nresolution: {resolution}\norigin: [{}, {}, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        origin[0], origin[1]
    );
    let path = dir.join("l.yaml");
    write(&path, yaml)?;
    Ok(path)
}

/// Writes a test file; an I/O error as the simulator's, for `?`.
fn write(path: &Path, contents: impl AsRef<[u8]>) -> Result<()> {
    std::fs::write(path, contents).map_err(|e| SimError::Invalid {
        field: "test io".into(),
        message: format!("{e}"),
    })
}

/// The error loading the map `yaml` once `text` is written to it (empty if it loads).
fn map_load_err(yaml: &Path, text: &str) -> Result<String> {
    write(yaml, text)?;
    Ok(OccupancyGrid::load(yaml)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default())
}

fn tempdir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap_or_else(|e| panic!("temp dir: {e}"))
}

#[test]
fn map_server_pgm_loads_with_y_flipped() -> Result<()> {
    let dir = tempdir();
    // An L: the left column and the bottom row of the image are occupied.
    let rows = [
        "#.........",
        "#.........",
        "#.........",
        "#.........",
        "#.........",
        "#.........",
        "#.........",
        "##########",
    ];
    let yaml = write_map(dir.path(), &rows, 0.5, [-1.0, 2.0])?;
    let grid = OccupancyGrid::load(&yaml)?;
    assert_eq!((grid.width(), grid.height()), (10, 8));
    assert_eq!(
        grid.get(5, 0),
        Some(map::OCCUPIED),
        "bottom image row is grid row 0"
    );
    assert_eq!(grid.get(5, 7), Some(map::FREE));
    assert_eq!(grid.get(0, 7), Some(map::OCCUPIED));
    assert_eq!(hng_simulator::grid_boxes(&grid).len(), 2, "one box per bar");
    let mut world = quiet(World::from_occupancy_map(
        &yaml,
        Pose2D::new(1.5, 4.0, -FRAC_PI_2),
    )?);
    world.sensors.lidar.beams = 4;
    let mut sim = Simulator::new(world)?;
    let scan = sim.scan_lidar();
    // Beams at -π, -π/2, 0, π/2 relative to a heading of -π/2: +x, -y... order by angle_min = -π.
    // Beam 0 (heading - π = +π/2 world): free up; beam 1 (-π world = -x): left bar face at x = -0.5;
    // beam 2 (heading = -y): bottom bar top face at y = 2.5; beam 3 (0 world = +x): free.
    assert_eq!(scan.ranges[0], f32::INFINITY);
    assert!((scan.ranges[1] - 2.0).abs() < 1e-3, "{:?}", scan.ranges);
    assert!((scan.ranges[2] - 1.5).abs() < 1e-3, "{:?}", scan.ranges);
    assert_eq!(scan.ranges[3], f32::INFINITY);
    Ok(())
}

#[test]
fn written_ground_truth_map_reloads_with_the_same_walls() -> Result<()> {
    let dir = tempdir();
    let world = quiet(World::default_world());
    let yaml = dir.path().join("gt.yaml");
    world.write_occupancy_map(&yaml, 0.05)?;
    let grid = OccupancyGrid::load(&yaml)?;
    assert!(grid.width() > 390 && grid.height() > 290);
    let from_map = quiet(World::from_occupancy_map(&yaml, world.robot.start)?);
    let a = Simulator::new(world)?.scan_lidar();
    let b = Simulator::new(from_map)?.scan_lidar();
    let close = a
        .ranges
        .iter()
        .zip(&b.ranges)
        .filter(|(x, y)| (*x == *y) || (**x - **y).abs() < 0.1)
        .count();
    assert!(close >= 340, "only {close} of 360 beams agree");
    Ok(())
}

fn parse_err(src: &str) -> String {
    match World::from_toml_str(src, "world.toml") {
        Ok(_) => panic!("expected an error for:\n{src}"),
        Err(e) => e.to_string(),
    }
}

const GOOD: &str = "[robot]\nstart = { x = 1.0, y = 2.0 }\n\n[[walls]]\nfrom = [0, 0]\nto = [5, 0]\n\n[[walls]]\nfrom = [0, 1]\nto = [5, 1]\nthickness = 0.1\n\n[sensors.lidar]\nbeams = 90\n";

#[test]
fn good_world_file_parses() -> Result<()> {
    let w = World::from_toml_str(GOOD, "world.toml")?;
    assert_eq!(w.walls.len(), 2);
    assert_eq!(w.walls[0].thickness, 0.05);
    assert_eq!(w.sensors.lidar.beams, 90);
    assert_eq!(w.robot.start, Pose2D::new(1.0, 2.0, 0.0));
    Ok(())
}

#[test]
fn malformed_world_files_name_line_and_field() {
    let e = parse_err(&GOOD.replace("beams = 90", "beams = \"many\""));
    assert!(
        e.starts_with("world.toml:14:9: field `sensors.lidar.beams`"),
        "{e}"
    );
    let e = parse_err(&GOOD.replace("thickness = 0.1", "thickness = -0.1"));
    assert!(
        e.starts_with("world.toml:11:1: field `walls[1].thickness`"),
        "{e}"
    );
    let e = parse_err(&GOOD.replace("[sensors.lidar]", "[sensors.lidar]\nbogus = 1"));
    assert!(
        e.starts_with("world.toml:14:1: field `sensors.lidar.bogus`")
            && e.contains("unknown field"),
        "{e}"
    );
    let e = parse_err(&GOOD.replace("y = 2.0", "y = \"two\""));
    assert!(
        e.starts_with("world.toml:2:") && e.contains("field `robot.start.y`"),
        "{e}"
    );
    let e = parse_err(&GOOD.replace("to = [5, 0]\n", ""));
    assert!(
        e.starts_with("world.toml:4:") && e.contains("walls[0].to") && e.contains("missing field"),
        "{e}"
    );
    let e = parse_err("seed = 1\n");
    assert!(e.contains("field `robot`"), "{e}");
    let e = parse_err(&format!("{GOOD}[[sensors.gps.zones]]\nkind = \"outage\"\n"));
    assert!(
        e.starts_with("world.toml:15:1: field `sensors.gps.zones[0]`") && e.contains("exactly one"),
        "{e}"
    );
    let e = parse_err(&GOOD.replace(
        "[sensors.lidar]\nbeams = 90",
        "[sensors.lidar]\nmin_range = 20.0",
    ));
    assert!(
        e.starts_with("world.toml:14:1: field `sensors.lidar.min_range`"),
        "{e}"
    );
    // Durations are seconds in `_s` keys; an old key names its new spelling.
    let e = parse_err(&format!("dt = 0.01\n{GOOD}"));
    assert!(
        e.starts_with("world.toml:1:1: field `dt`") && e.contains("`dt` is now `dt_s` (seconds)"),
        "{e}"
    );
    let e = parse_err(&GOOD.replace("y = 2.0 }", "y = 2.0 }\ncmd_timeout = 0.5"));
    assert!(
        e.starts_with("world.toml:3:1: field `robot.cmd_timeout`")
            && e.contains("`cmd_timeout` is now `cmd_timeout_s` (seconds)"),
        "{e}"
    );
    let e = parse_err(&format!("dt_s = -0.01\n{GOOD}"));
    assert!(e.starts_with("world.toml:1:1: field `dt_s`"), "{e}");
}

#[test]
fn malformed_map_files_name_line_and_field() -> Result<()> {
    let dir = tempdir();
    let yaml = write_map(dir.path(), &["#.", ".#"], 0.5, [0.0, 0.0])?;
    let text = std::fs::read_to_string(&yaml).unwrap_or_default();
    let e = map_load_err(&yaml, &text.replace("resolution: 0.5", "resolution: fine"))?;
    assert!(
        e.contains("l.yaml:2:") && e.contains("field `resolution`"),
        "{e}"
    );
    let e = map_load_err(&yaml, &text.replace("resolution: 0.5", "resolution: -1"))?;
    assert!(e.contains("l.yaml:2:1: field `resolution`"), "{e}");
    let e = map_load_err(&yaml, &format!("{text}colour: red\n"))?;
    assert!(
        e.contains("l.yaml:7:") && e.contains("field `colour`"),
        "{e}"
    );
    write(&dir.path().join("l.pgm"), b"P5\n2 2\n255\n\x00")?;
    let e = map_load_err(&yaml, &text)?;
    assert!(e.contains("l.pgm:3:1: field `raster`"), "{e}");
    Ok(())
}

#[test]
fn world_file_can_reference_a_map() -> Result<()> {
    let dir = tempdir();
    write_map(dir.path(), &["###", "#.#", "###"], 1.0, [0.0, 0.0])?;
    let src =
        "[robot]\nstart = { x = 1.5, y = 1.5 }\nradius = 0.3\n\n[[maps]]\nyaml = \"l.yaml\"\n";
    let path = dir.path().join("w.toml");
    write(&path, src)?;
    let w = World::load(&path)?;
    assert!(!w.map_boxes.is_empty());
    let scan = Simulator::new(quiet(w))?.scan_lidar();
    assert!(
        scan.ranges.iter().all(|r| *r > 0.49 && *r < 0.72),
        "{:?}",
        &scan.ranges[..10]
    );
    Ok(())
}

/// Prints the numbers `hng bench sim` reports. Run in release:
/// `cargo test -p hng-simulator --release --test sim -- --ignored --nocapture bench_numbers`.
#[test]
#[ignore = "timing; run explicitly in release mode"]
fn bench_numbers() -> Result<()> {
    let mut samples = hng_simulator::bench::scan_360(2000)?;
    samples.sort_unstable();
    let pct = |p: usize| samples[(samples.len() - 1) * p / 100];
    println!(
        "scan_360: median {} ns, p10 {} ns, p90 {} ns",
        pct(50),
        pct(10),
        pct(90)
    );
    let rtf = hng_simulator::bench::headless_10hz(600.0)?;
    println!("headless_10hz: {rtf:.0}x real time");
    Ok(())
}

#[test]
fn example_world_file_loads_with_its_map() -> Result<()> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("worlds/example.toml");
    let w = World::load(&path)?;
    assert_eq!(w.name, "corridor");
    assert!(!w.map_boxes.is_empty());
    assert!(!w.sensors.camera.enabled);
    // Drive east through the doorway into the annex without hitting anything.
    let mut w = quiet(w);
    w.robot.start = Pose2D::new(8.5, 2.0, 0.0);
    let mut sim = Simulator::new(w)?;
    let scan = sim.scan_lidar();
    let ahead = scan.ranges[180]; // beam 180 of 360 points forward
    assert!(
        (f64::from(ahead) - 5.25).abs() < 1e-3,
        "annex east wall at x = 13.75: {ahead}"
    );
    Ok(())
}
