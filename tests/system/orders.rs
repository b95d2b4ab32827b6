//! The operator's orders through the Interface (adjustable autonomy, docs/autonomy.md), with
//! real processes in accelerated lockstep simulation: bad orders refused with their reason and
//! nothing moving; a goal order reached within 0.3 m of true error (SLAM localization);
//! teleop with its deadman; the emergency stop stopping a moving robot; orders switched while
//! the robot moves, re-wiring the contracts without collision; `hng order` and
//! `hng behaviours` against the running system.

use hng_runtime::msg::{Order, OrderKind, Twist};

use crate::common::{Watch, dist, goal, launch_file};
use crate::signals::Run;

const HNG: &str = env!("CARGO_BIN_EXE_hng");

/// The launch file of a robot under orders: the Table 1 modules with SLAM as the only
/// Localization (GPS's 0.3 m noise would not reach a goal within 0.3 m) and the surveyed map,
/// the Manager with no goals (autonomy holds), in lockstep. `extra` modules (name, config
/// TOML lines) are added; `world` is a world file (default: the built-in world).
pub(crate) fn launch(
    map: &str,
    world: Option<&str>,
    start: (f64, f64, f64),
    extra: &[(&str, &str)],
) -> String {
    let mut names = vec![
        "laser",
        "robot",
        "security",
        "interface",
        "maps",
        "slam",
        "planning",
        "servo",
        "manager",
    ];
    names.extend(extra.iter().map(|e| e.0));
    let list = names
        .iter()
        .map(|n| format!("{n:?}"))
        .collect::<Vec<_>>()
        .join(", ");
    let (x, y, t) = start;
    let start = format!("{{ x = {x:?}, y = {y:?}, theta = {t:?} }}");
    let world = world.map_or(String::new(), |w| format!("world = {w:?}\n"));
    let sim =
        format!("{world}start = {start}\nspeed = 4\nwait_for = [{list}]\nlockstep = [{list}]");
    let map = format!("map = {map:?}");
    let slam = format!("initial_pose = {start}");
    let mut modules = vec![
        ("simulator", "", sim.as_str()),
        ("laser", "", ""),
        ("robot", "", ""),
        ("security", "", ""),
        ("interface", "", "video = false"),
        ("maps", "", map.as_str()),
        ("slam", "", slam.as_str()),
        ("planning", "", "goal = \"interface/goal\""),
        ("servo", "", ""),
        ("manager", "manager = true", "goals = []"),
    ];
    modules.extend(extra.iter().map(|(name, config)| (*name, "", *config)));
    launch_file("orders", 5.0, 20.0, &modules)
}

/// The map of `world` (default: built-in) for Maps, written into `dir`.
pub(crate) fn write_map(dir: &std::path::Path, world: Option<&str>) -> String {
    let map = dir.join("map.yaml");
    let mut c = std::process::Command::new(HNG);
    c.args(["sim", "map"]).arg(&map);
    if let Some(w) = world {
        c.args(["--world", w]);
    }
    let out = c.output().expect("hng sim map");
    assert!(out.status.success(), "hng sim map: {out:?}");
    map.to_str().expect("path").to_owned()
}

fn forward(v: f64) -> Twist {
    Twist {
        linear_x: v,
        ..Default::default()
    }
}

#[test]
fn orders_of_every_level_do_what_they_say_and_bad_ones_move_nothing() {
    let _heavy = crate::common::heavy();
    let (prefix, dir) = crate::signals::prefix_and_dir("orders");
    let map = write_map(&dir, None);
    let file = dir.join("orders.toml");
    std::fs::write(&file, launch(&map, None, (2.0, 2.0, 0.0), &[])).expect("launch");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    watch.until("simulated time running and Planning contracted", |w| {
        w.sim_s() > 1.0
            && w.pose.is_some()
            && w.statuses.last().is_some_and(|s| s.active == 0)
            && w.provider_of("interface", 2).as_deref() == Some("planning")
    });
    let rest = watch.xy();

    // Bad orders: refused with their reason, counted, and nothing moves.
    let dropped = watch.interface_dropped;
    let mut nan = goal(OrderKind::Goal, &[(f64::NAN, 3.0)]);
    let bad: Vec<(Order, &str)> = vec![
        (
            Order {
                kind: 42,
                ..Default::default()
            },
            "unknown order kind 42",
        ),
        (std::mem::take(&mut nan), "point 1 x is not finite"),
        (goal(OrderKind::Goal, &[(1e7, 3.0)]), "is beyond"),
        (goal(OrderKind::Waypoints, &[]), "1 to 16 points"),
        (
            Order {
                kind: OrderKind::FollowWall as u32,
                side: 3,
                ..Default::default()
            },
            "side 3 is neither",
        ),
        (
            Order {
                kind: OrderKind::FollowWall as u32,
                side: 1,
                ..Default::default()
            },
            "no \"Follow wall\" provider",
        ),
        (
            Order {
                kind: OrderKind::ReachBeacon as u32,
                beacon_id: 77,
                ..Default::default()
            },
            "beacon 77 is not known",
        ),
    ];
    let n_bad = bad.len() as u64;
    for (o, why) in bad {
        let s = watch.order(o);
        assert_eq!(s.accepted, 0, "{o:?} accepted: {}", s.reason());
        assert!(
            s.reason().contains(why),
            "{:?} does not say {why:?}",
            s.reason()
        );
        assert_eq!(s.active, 0, "a refused order changed nothing");
    }
    // NaN teleop commands: dropped and counted too.
    watch.drive = Some(forward(f64::NAN));
    let sent = watch.drive_sent;
    watch.until("10 NaN commands sent", |w| w.drive_sent >= sent + 10);
    watch.drive = None;
    let n_nan = watch.drive_sent - sent;
    watch.until("the refusals and drops counted", |w| {
        w.interface_dropped >= dropped + n_bad + n_nan
    });
    let t0 = watch.sim_s();
    watch.until("one more simulated second", |w| w.sim_s() > t0 + 1.0);
    assert!(dist(watch.xy(), rest) < 0.01, "bad orders moved the robot");

    // A goal order: reached within 0.3 m of true error, then the order ends (autonomy).
    let target = (5.5, 3.0);
    let s = watch.order(goal(OrderKind::Goal, &[target]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    assert_eq!(s.active, 1);
    let seq = s.seq;
    watch.until("the goal order reached", |w| {
        w.statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached"))
    });
    watch.until_still("the robot at rest at the goal", 0.5);
    let err = dist(watch.xy(), target);
    eprintln!("goal order: true error {err:.3} m");
    assert!(err <= 0.3, "goal reached {err:.3} m from the truth");

    // Teleop: the commands drive it; when they stop, the deadman stops it.
    let s = watch.order(Order::new(OrderKind::Teleop));
    assert_eq!((s.accepted, s.in_force), (1, OrderKind::Teleop as u32));
    watch.until("Planning released under teleop", |w| {
        w.provider_of("interface", 2).is_none()
    });
    let start = watch.xy();
    watch.drive = Some(Twist {
        linear_x: 0.25,
        angular_z: 0.3,
        ..Default::default()
    });
    watch.until("the robot moving under teleop", |w| {
        dist(w.xy(), start) > 0.3
    });
    watch.drive = None;
    let moved_until = watch.until_still("the deadman stopping the robot", 0.5);
    // From the Interface's receipt of the last command (the stamp of its forward), not from
    // when the test stopped sending: the test is outside lockstep, and under load the
    // simulation ran on for a while before the last command got there.
    let released = watch.last_forwarded.expect("teleop commands forwarded");
    let stopped_after = moved_until - released;
    eprintln!("teleop deadman: at rest {stopped_after:.2} s after the last command forwarded");
    // Deadman 0.5 s + braking from 0.25 m/s at 2 m/s^2 (0.13 s) + a scan period.
    assert!(stopped_after < 0.9, "deadman took {stopped_after:.2} s");

    // Emergency stop while moving: the robot stops within 0.3 s (+ one scan period of
    // Security's relay) and teleop commands then move nothing.
    watch.drive = Some(forward(0.25));
    let start = watch.xy();
    watch.until("the robot moving again", |w| dist(w.xy(), start) > 0.2);
    let s = watch.order(Order::new(OrderKind::Stop));
    assert_eq!((s.accepted, s.in_force), (1, OrderKind::Stop as u32));
    let t_stop = s.header.stamp_ns as f64 * 1e-9;
    let moving_until = watch.until_still("the robot stopped", 0.5);
    let stop_time = moving_until - t_stop;
    eprintln!("stop order: robot at rest {stop_time:.3} s (simulated) after the order");
    assert!(
        stop_time <= 0.35,
        "stopped {stop_time:.3} s after the order"
    );
    let held = watch.xy();
    let t0 = watch.sim_s();
    watch.until("1 s of teleop under stop", |w| w.sim_s() > t0 + 1.0);
    assert!(
        dist(watch.xy(), held) < 0.01,
        "teleop moved a stopped robot"
    );
    watch.drive = None;

    // Switching orders while moving: a far goal, then waypoints elsewhere, then another goal,
    // then release; no collision, and Planning is re-contracted for each.
    let collisions = watch.collisions();
    let s = watch.order(goal(OrderKind::Goal, &[(3.0, 11.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.until("Planning contracted for the goal", |w| {
        w.provider_of("interface", 2).as_deref() == Some("planning")
    });
    let start = watch.xy();
    watch.until("moving to the goal", |w| dist(w.xy(), start) > 0.8);
    let s = watch.order(goal(OrderKind::Waypoints, &[(6.0, 6.5), (5.5, 3.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    let seq = s.seq;
    watch.until("the first waypoint passed", |w| {
        dist(w.xy(), (6.0, 6.5)) < 0.5
    });
    let s = watch.order(goal(OrderKind::Goal, &[(2.0, 2.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    assert!(
        !watch
            .statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached")),
        "the waypoints were replaced before their end"
    );
    let seq = s.seq;
    watch.until("the last goal reached", |w| {
        w.statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached"))
    });
    assert_eq!(
        watch.collisions(),
        collisions,
        "a collision while switching"
    );
    let s = watch.order(Order::new(OrderKind::Release));
    assert_eq!((s.accepted, s.active), (1, 0));

    // `hng order` from the terminal: refusals exit 1 with the reason; show tells the state.
    let out = run.hng(&["order", "follow-wall", "left"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("refused by the Interface"), "{err}");
    let out = run.hng(&["order", "goal", "1,nan"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not finite"));
    let out = run.hng(&["order", "stop"]);
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("stop in force"));
    let out = run.hng(&["order", "show", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(v["in_force"], "stop");
    let out = run.hng(&["behaviours", "--once", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let kinds: Vec<&str> = v["items"]
        .as_array()
        .expect("items")
        .iter()
        .filter_map(|i| i["kind"].as_str())
        .collect();
    assert!(
        kinds.contains(&"goal") && !kinds.contains(&"follow_wall"),
        "{kinds:?}"
    );

    drop(watch);
    run.stop_ok();
}
