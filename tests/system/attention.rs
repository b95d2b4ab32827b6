//! Client feedback (the E term of eq. 3) with real processes: a Localization source that
//! claims Q = 1 while wrong (the `liar` fixture: its pose moves 30 % as far as the robot, with
//! a claimed 2 cm uncertainty) wins the Servo's and Planning's "Localization" at first; once
//! the robot moves, the Servo rates it by consistency with odometry, and the feedback takes
//! the contract from it (to SLAM) within a bounded time.
//!
//! The same run shows Planning's rating of its "Mapping" provider by agreement with the scans:
//! a second Maps, `wrong_map`, serves the surveyed map with its origin 1.5 m off and claims
//! Q = 1, more than the true map's 0.95, so Planning takes it first; Planning's feedback takes
//! the contract from it to `maps` before the goal is given.

use hng_runtime::msg::OrderKind;

use crate::common::{Watch, dist, goal};
use crate::orders::{launch, write_map};
use crate::signals::Run;

const TESTMOD: &str = env!("CARGO_BIN_EXE_hng-testmod");

#[test]
fn a_lying_localization_loses_its_contract_through_the_servos_feedback() {
    let _heavy = crate::common::heavy();
    let (prefix, dir) = crate::signals::prefix_and_dir("feedback");
    let map = write_map(&dir, None);
    let wrong = shifted_map(&map, 1.5);
    // The true map claims a little less (Q 0.95, an older survey, within the contracts'
    // hysteresis of 0.1) than the wrong one (Q 1), so Planning takes the wrong one first.
    let mut plan = launch(&map, None, (2.0, 2.0, 0.0), &[])
        .replacen("wait_for = [", "wait_for = [\"wrong_map\", ", 1)
        .replacen(
            &format!("map = {map:?}\n"),
            &format!("map = {map:?}\nquality = 0.95\n"),
            1,
        );
    plan.push_str(&format!(
        "\n[[module]]\nname = \"liar\"\ncommand = [{TESTMOD:?}, \"liar\"]\n[module.config]\nstart = {{ x = 2.0, y = 2.0, theta = 0.0 }}\n"
    ));
    plan.push_str(&format!(
        "\n[[module]]\nname = \"wrong_map\"\ncommand = [\"hng\", \"module\", \"maps\"]\n[module.config]\nmap = {wrong:?}\nmap_out = \"wrong_map/map\"\n"
    ));
    let file = dir.join("feedback.toml");
    std::fs::write(&file, plan).expect("launch");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    watch.until("the liar selected by the Servo and Planning", |w| {
        w.sim_s() > 1.0
            && w.provider_of("servo", 2).as_deref() == Some("liar")
            && w.provider_of("planning", 3).as_deref() == Some("liar")
    });
    // Planning's Mapping: the wrong map first (the tie), then away from it by its feedback.
    // From the history of Planning's contract tables: the whole move (wrong_map, SLAM's, then
    // maps, once within 150 ms of wall time) may be over before this wait begins, while the
    // one above waits for the liar (1 run in 10 under load failed on the latest table).
    let mut t_map = f64::NAN;
    watch.until("Planning's Mapping from wrong_map to maps", |w| {
        let id = |name: &str| w.contracts.get(name).map(|t| t.module_id);
        let (wrong, maps) = (id("wrong_map"), id("maps"));
        let mut wrong_first = false;
        for (stamp, client, need, provider) in &w.provider_changes {
            if client != "planning" || *need != 2 {
                continue;
            }
            wrong_first |= Some(*provider) == wrong;
            if wrong_first && Some(*provider) == maps {
                t_map = *stamp;
                return true;
            }
        }
        false
    });
    eprintln!(
        "feedback: Planning's Mapping moved from wrong_map to maps at {t_map:.2} s (simulated)"
    );
    let s = watch.order(goal(OrderKind::Goal, &[(5.5, 3.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.until("the liar still selected (Planning and Servo active)", |w| {
        w.provider_of("servo", 2).as_deref() == Some("liar")
    });
    // The robot stands where it was spawned until the goal: the first true pose. (The pose the
    // watch read last may be one of the motion already: then every pose before it, the first
    // too, is more than 5 cm away, and the motion would seem to start at 0 s.)
    let start = watch
        .track
        .first()
        .map_or((f64::NAN, f64::NAN), |p| (p.1, p.2));
    watch.until("the robot moving", |w| dist(w.xy(), start) > 0.05);
    // The times are the stamps (simulated) of the true poses and of the contract tables, not
    // when the watch, no lockstep participant, read them.
    let t_move = watch
        .track
        .iter()
        .find(|(_, x, y)| dist((*x, *y), start) > 0.05)
        .map_or(f64::NAN, |p| p.0);
    let mut servo = None;
    watch.until("the Servo's Localization away from the liar", |w| {
        servo = left_liar(w, "servo", 2);
        servo.is_some()
    });
    let (t_switch, to) = servo.expect("the Servo left the liar");
    let mut planning = None;
    watch.until("Planning's Localization away from the liar", |w| {
        planning = left_liar(w, "planning", 3);
        planning.is_some()
    });
    let (t_planning, _) = planning.expect("Planning left the liar");
    eprintln!(
        "feedback: the liar lost the Servo's Localization {:.2} s (simulated) after the robot \
         started moving (to {to:?}), Planning's {:.2} s after",
        t_switch - t_move,
        t_planning - t_move
    );
    let moves: Vec<String> = watch
        .provider_changes
        .iter()
        .filter(|(stamp, client, need, _)| client == "planning" && *need == 2 && *stamp > t_move)
        .map(|(stamp, _, _, provider)| {
            let name = watch.module_name(*provider);
            format!("{} at {stamp:.2} s", name.as_deref().unwrap_or("none"))
        })
        .collect();
    eprintln!(
        "feedback: the robot started moving at {t_move:.2} s; Planning's Mapping after: {moves:?}"
    );
    assert_eq!(to.as_deref(), Some("slam"));
    assert!(t_map <= 6.0, "{t_map:.2} s");
    // Measured by the stamps (session 21, 20 runs at load 16-18): -0.05-1.73 s. The tail of
    // 3.6-6.1 s seen before (5 of 80 runs at load 17-22) was the start of motion read wrong:
    // `start` was the pose the watch had read last, sometimes one of the motion already, and
    // then the first pose of all counted as "moving" (0.01 s); one run of 27 before the fix
    // showed it (3.90 s). Without the feedback the liar keeps its contracts and the waits
    // above time out.
    assert!(t_switch - t_move <= 4.0, "{:.2} s", t_switch - t_move);
    assert!(t_planning - t_move <= 4.5, "{:.2} s", t_planning - t_move);

    drop(watch);
    run.stop_ok();
}

/// When `client` first left the liar for its need `need` (the stamp of its contract table,
/// simulated s), and for which provider.
fn left_liar(w: &Watch, client: &str, need: u16) -> Option<(f64, Option<String>)> {
    let liar = w.contracts.get("liar")?.module_id;
    let mut on_liar = false;
    for (stamp, c, n, provider) in &w.provider_changes {
        if c != client || *n != need {
            continue;
        }
        if *provider == liar {
            on_liar = true;
        } else if on_liar {
            return Some((*stamp, w.module_name(*provider)));
        }
    }
    None
}

/// A copy of the map_server map `yaml` with its origin moved by `d` m in x and y (the same
/// picture, the walls in the wrong places), written beside it; its path.
fn shifted_map(yaml: &str, d: f64) -> String {
    let text = std::fs::read_to_string(yaml).expect("map yaml");
    let dir = std::path::Path::new(yaml).parent().expect("dir");
    let mut out = String::new();
    for line in text.lines() {
        if let Some(rest) = line.trim().strip_prefix("origin:") {
            let v: Vec<f64> = rest
                .trim()
                .trim_matches(['[', ']'])
                .split(',')
                .map(|x| x.trim().parse().expect("origin"))
                .collect();
            out.push_str(&format!("origin: [{}, {}, {}]\n", v[0] + d, v[1] + d, v[2]));
        } else if let Some(img) = line.trim().strip_prefix("image:") {
            let img = dir.join(img.trim());
            out.push_str(&format!("image: {}\n", img.display()));
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    let path = dir.join("wrong_map.yaml");
    std::fs::write(&path, out).expect("wrong map");
    path.to_str().expect("path").to_owned()
}
