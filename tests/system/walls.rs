//! Wall detection, wall following and attention with real processes in accelerated lockstep
//! simulation: in a 20 x 10 m room the robot is driven by teleop towards the south wall; the
//! behaviours list offers "follow wall right" only once that wall is near; the follow-wall
//! order then keeps 0.6 ± 0.15 m from the wall for at least 90 % of 20 m of wall that
//! includes the south-east (inner) corner; then teleop straight at the north wall is stopped
//! short of it by Security.

use hng_runtime::msg::{Order, OrderKind, SIDE_RIGHT, Twist};

use crate::common::Watch;
use crate::orders::{launch, write_map};
use crate::signals::Run;

/// A 20 x 10 m room (walls only).
fn room() -> String {
    format!(
        "name = \"wall-room\"\nseed = 5\n\n[robot]\nstart = {{ x = 2.0, y = 2.2, theta = 0.0 }}\n{}",
        crate::common::room_walls(20.0, 10.0)
    )
}

/// Distance from (x, y) to the segment a-b.
fn seg_dist(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let t = (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
    crate::common::dist(p, (a.0 + t * dx, a.1 + t * dy))
}

/// Distance to the followed walls: the south wall and the east wall.
fn followed_dist(p: (f64, f64)) -> f64 {
    seg_dist(p, (0.0, 0.0), (20.0, 0.0)).min(seg_dist(p, (20.0, 0.0), (20.0, 10.0)))
}

fn offers_follow_right(w: &Watch) -> bool {
    w.behaviours.is_some_and(|b| {
        b.items()
            .iter()
            .any(|i| i.kind == OrderKind::FollowWall as u32 && i.param == SIDE_RIGHT)
    })
}

#[test]
fn the_robot_follows_a_wall_round_a_corner_and_attention_offers_it_only_near_one() {
    let _heavy = crate::common::heavy();
    let (prefix, dir) = crate::signals::prefix_and_dir("walls");
    let world = dir.join("room.toml");
    std::fs::write(&world, room()).expect("world");
    let world = world.to_str().expect("path").to_owned();
    let map = write_map(&dir, Some(&world));
    let file = dir.join("walls.toml");
    let extra = [("walls", ""), ("wall_follower", "")];
    std::fs::write(&file, launch(&map, Some(&world), (2.0, 2.2, 0.0), &extra)).expect("launch");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    watch.until("simulated time running and a behaviours list", |w| {
        w.sim_s() > 1.0 && w.pose.is_some() && w.behaviours.is_some()
    });
    // 2.2 m from the south wall: not offered, and refused.
    assert!(!offers_follow_right(&watch), "{:?}", watch.behaviours);
    let mut follow = Order::new(OrderKind::FollowWall);
    follow.side = SIDE_RIGHT;
    let s = watch.order(follow);
    assert_eq!(s.accepted, 0);
    assert!(
        s.reason().contains("no wall detected on the right"),
        "{}",
        s.reason()
    );

    // Teleop towards the wall: the offer appears once it is within 1.5 m.
    let s = watch.order(Order::new(OrderKind::Teleop));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    let theta = |w: &Watch| w.pose.map_or(0.0, |(p, _)| p.theta);
    watch.drive = Some(Twist {
        angular_z: -0.8,
        ..Default::default()
    });
    watch.until("heading 30 degrees right", |w| theta(w) < -0.5);
    watch.drive = Some(Twist {
        linear_x: 0.3,
        ..Default::default()
    });
    watch.until("follow wall right offered near the wall", |w| {
        offers_follow_right(w) || w.xy().1 < 0.9
    });
    let d_offer = followed_dist(watch.xy());
    eprintln!("follow wall right offered at {d_offer:.2} m from the wall");
    assert!(offers_follow_right(&watch), "not offered at {d_offer:.2} m");
    assert!(d_offer < 1.6, "offered {d_offer:.2} m from the wall");
    watch.until("closer to the wall", |w| w.xy().1 < 1.1);
    watch.drive = Some(Twist {
        angular_z: 0.8,
        ..Default::default()
    });
    watch.until("heading east again", |w| theta(w) > -0.05);
    watch.drive = None;

    // Follow it: acquisition, then 20 m of wall with the inner corner.
    let collisions = watch.collisions();
    let s = watch.order(follow);
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.until("the wall follower contracted", |w| {
        w.provider_of("interface", 4).as_deref() == Some("wall_follower")
    });
    watch.until("the robot within 0.15 m of 0.6 m", |w| {
        (followed_dist(w.xy()) - 0.6).abs() < 0.15
    });
    let from = watch.track.len();
    let mut travelled = 0.0;
    let mut seen = from;
    watch.until("20 m of wall followed", |w| {
        for k in seen.max(from + 1)..w.track.len() {
            let (a, b) = (w.track[k - 1], w.track[k]);
            travelled += crate::common::dist((a.1, a.2), (b.1, b.2));
        }
        seen = w.track.len();
        travelled >= 20.0
    });
    let (mut inside, mut total, mut worst) = (0.0, 0.0, 0.0f64);
    for k in from + 1..seen {
        let (a, b) = (watch.track[k - 1], watch.track[k]);
        let step = crate::common::dist((a.1, a.2), (b.1, b.2));
        let d = followed_dist((b.1, b.2));
        total += step;
        worst = worst.max((d - 0.6).abs());
        if (d - 0.6).abs() <= 0.15 {
            inside += step;
        }
    }
    let frac = inside / total;
    let end = watch.xy();
    eprintln!(
        "wall following: {:.1} % of {total:.1} m within 0.6 +- 0.15 m (worst error {worst:.2} m), end ({:.2}, {:.2})",
        100.0 * frac,
        end.0,
        end.1
    );
    assert!(
        end.0 > 19.0 && end.1 > 1.5,
        "the corner was not turned: {end:?}"
    );
    assert!(frac >= 0.9, "only {:.1} % within the band", 100.0 * frac);
    assert_eq!(
        watch.collisions(),
        collisions,
        "a collision while following"
    );

    // Teleop straight at the north wall: Security stops the robot short of it.
    let s = watch.order(Order::new(OrderKind::Teleop));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.until("the follower released", |w| {
        w.provider_of("interface", 4).is_none()
    });
    // Face north first (turning in place is never limited).
    watch.drive = Some(Twist {
        angular_z: 0.8,
        ..Default::default()
    });
    watch.until("facing north", |w| {
        w.pose
            .is_some_and(|(p, _)| (p.theta - std::f64::consts::FRAC_PI_2).abs() < 0.1)
    });
    watch.drive = Some(Twist {
        linear_x: 0.6,
        ..Default::default()
    });
    let t0 = watch.sim_s();
    watch.until("driving at the wall for 15 simulated s", |w| {
        w.sim_s() > t0 + 15.0
    });
    let gap = 10.0 - watch.xy().1;
    watch.drive = None;
    eprintln!("teleop at the wall: stopped with its centre {gap:.2} m from the wall");
    assert_eq!(watch.collisions(), collisions, "teleop drove into the wall");
    assert!(gap > 0.25, "centre {gap:.2} m from the wall (radius 0.2 m)");

    drop(watch);
    run.stop_ok();
}
