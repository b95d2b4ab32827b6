//! The showcase (`examples/showcase/launch.toml`, issue 17): every Table 1 module its own
//! process, in the showcase world (a hall with a partition, three beacons, a dark corner), run
//! as a user runs it (`hng run` of the launch file from the repository's root, lockstep). The
//! test is the operator: waypoints along the south wall, where attention starts offering
//! "follow wall right", and stops once the robot leaves the wall; a goal past the partition
//! (and a turn under teleop if need be), until a tracker finds beacon 3 by itself (no
//! designation) and attention offers "reach beacon 3"; then `hng order reach-beacon 3` (the CLI, a real
//! process) and the reacher drives the robot to within 0.5 m of the beacon (true pose). On the
//! way, Planning's whole path to the goal is read on `planning/path`, then an empty one.

use hng_runtime::msg::{Behaviours, OrderKind, PLANNED_PATH_CHANNEL, PathInfo, SIDE_RIGHT, Twist};
use hng_runtime::{Node, NodeOptions, shm};
use nix::sys::signal::Signal;

use crate::orders::{Watch, dist, goal};
use crate::signals::Run;

/// The launch file, relative to the repository's root (the tests' working directory).
const LAUNCH: &str = "examples/showcase/launch.toml";
/// Beacon 3 of the showcase world.
const BEACON: (f64, f64) = (17.5, 8.0);

fn has(b: &Behaviours, kind: OrderKind, param: i32) -> bool {
    b.items()
        .iter()
        .any(|i| i.kind == kind as u32 && i.param == param)
}

fn offers(w: &Watch, kind: OrderKind, param: i32) -> bool {
    w.behaviours.is_some_and(|b| has(&b, kind, param))
}

#[test]
fn the_showcase_offers_a_wall_then_a_beacon_and_hng_order_reaches_the_beacon() {
    let _heavy = crate::common::heavy();
    let prefix = shm::unique_prefix("showcase");
    let mut watch = Watch::new(&prefix);
    let node = Node::new(NodeOptions::new("showcase-path").prefix(&prefix)).expect("node");
    let paths = node
        .slice_subscriber::<PathInfo>(PLANNED_PATH_CHANNEL)
        .expect("planned path");
    // The latest planned path: (goal id, number of poses, last pose).
    let mut path: Option<(u32, usize, (f64, f64))> = None;
    let read_path = |path: &mut Option<(u32, usize, (f64, f64))>| {
        while let Some(p) = paths.receive().expect("path") {
            let last = p.data().last().map_or((f64::NAN, f64::NAN), |q| (q.x, q.y));
            *path = Some((p.header().goal_id, p.data().len(), last));
        }
    };
    let mut run = Run::start_on(&prefix, &[LAUNCH]);
    watch.until(
        "simulated time running, Planning contracted, behaviours",
        |w| {
            w.sim_s() > 1.0
                && w.pose.is_some()
                && w.behaviours.is_some()
                && w.provider_of("interface", 2).as_deref() == Some("planning")
        },
    );
    // At the start, 2.5 m from every wall and facing none of the beacons: neither offered.
    let first = watch.behaviours.expect("behaviours");
    assert!(
        !has(&first, OrderKind::FollowWall, SIDE_RIGHT) && !has(&first, OrderKind::ReachBeacon, 3),
        "{first:?}"
    );

    // Along the south wall, 1 m from it: "follow wall right" appears.
    let s = watch.order(goal(OrderKind::Waypoints, &[(6.0, 1.0), (13.0, 1.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    let seq = s.seq;
    watch.until("follow wall right offered along the south wall", |w| {
        offers(w, OrderKind::FollowWall, SIDE_RIGHT)
    });
    let at = watch.xy();
    eprintln!(
        "showcase: follow wall right offered at ({:.2}, {:.2}), {:.2} m from the south wall",
        at.0, at.1, at.1
    );
    assert!(at.1 < 1.6, "offered {:.2} m from the wall", at.1);
    watch.until("the waypoints reached", |w| {
        w.statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached"))
    });

    // Past the partition, into the open north-east: the wall is no longer offered.
    let s = watch.order(goal(OrderKind::Goal, &[(17.0, 4.5)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    let seq = s.seq;
    // Planning's whole path to it on planning/path, ending at the goal.
    watch.until("the planned path to the goal on planning/path", |_| {
        read_path(&mut path);
        path.is_some_and(|(id, n, last)| id != 0 && n >= 2 && dist(last, (17.0, 4.5)) < 0.3)
    });
    eprintln!("showcase: planned path to (17, 4.5): {path:?}");
    watch.until("the goal past the partition reached", |w| {
        w.statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached"))
    });
    // Once the order ends (back to autonomy, the Manager has no goal): an empty path.
    watch.until("an empty planned path once the goal is reached", |_| {
        read_path(&mut path);
        path.is_some_and(|(id, n, _)| id == 0 && n == 0)
    });
    watch.until("follow wall right withdrawn away from the wall", |w| {
        !offers(w, OrderKind::FollowWall, SIDE_RIGHT)
    });
    // Turn in place until a tracker finds beacon 3 by itself and attention offers it.
    let s = watch.order(hng_runtime::msg::Order::new(OrderKind::Teleop));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.drive = Some(Twist {
        angular_z: 0.6,
        ..Default::default()
    });
    watch.until("reach beacon 3 offered", |w| {
        offers(w, OrderKind::ReachBeacon, 3)
    });
    watch.drive = None;
    let seen_from = dist(watch.xy(), BEACON);
    eprintln!("showcase: reach beacon 3 offered {seen_from:.2} m from it");
    // The list changed as the robot went: neither at first, then the wall, then the beacon
    // (seen from the end of the south corridor, so possibly while the wall is still
    // offered), and the wall withdrawn once the robot left it.
    let changes: Vec<(bool, bool)> = watch
        .offers
        .iter()
        .map(|b| {
            (
                has(b, OrderKind::FollowWall, SIDE_RIGHT),
                has(b, OrderKind::ReachBeacon, 3),
            )
        })
        .collect();
    eprintln!("showcase: (follow wall right, reach beacon 3) offered in each list: {changes:?}");
    let wall = changes.iter().position(|c| c.0).expect("wall offered");
    let beacon = changes.iter().position(|c| c.1).expect("beacon offered");
    assert!(
        changes[0] == (false, false) && wall < beacon && changes[wall..].iter().any(|c| !c.0),
        "{changes:?}"
    );

    // `hng order reach-beacon 3`, the CLI: the reacher drives to it.
    let collisions = watch.collisions();
    let out = run.hng(&["order", "reach-beacon", "3"]);
    assert!(out.status.success(), "{out:?}");
    watch.until("the reacher contracted", |w| {
        w.provider_of("interface", 5).as_deref() == Some("reacher")
    });
    watch.until("the robot near the beacon", |w| dist(w.xy(), BEACON) < 1.0);
    watch.until_still("the robot at rest at the beacon", 1.0);
    let d = dist(watch.xy(), BEACON);
    eprintln!(
        "showcase: hng order reach-beacon 3 from {seen_from:.2} m: at rest {d:.3} m from the beacon's centre"
    );
    assert!(d <= 0.5, "stopped {d:.3} m from the beacon");
    assert_eq!(watch.collisions(), collisions, "a collision on the way");

    drop(watch);
    run.signal(Signal::SIGTERM);
    let status = run.wait();
    run.assert_left_nothing();
    assert_eq!(status.code(), Some(0));
}
