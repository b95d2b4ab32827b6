//! The fused localization (`hng module localization`: wheel odometry and GPS in an EKF) in the
//! built-in mission: it wins "Localization" over the raw GPS and SLAM, every goal ends within
//! the mission's 0.3 m of the true pose, and when it dies its clients go to another provider
//! and come back after its restart.

use std::process::Stdio;
use std::time::{Duration, Instant};

use crate::common::Reaped;
use crate::mission::{MissionRun, hng};

/// Polls `hng contracts` until both clients follow the fused localization (true) or the
/// mission ends (false).
fn fused_serves_both_clients(m: &MissionRun, run: &mut Reaped) -> bool {
    let deadline = Instant::now() + Duration::from_secs(120);
    while Instant::now() < deadline {
        if run.0.try_wait().expect("try_wait").is_some() {
            return false;
        }
        let out = hng()
            .args(["--prefix", &m.prefix, "contracts"])
            .output()
            .expect("hng contracts");
        let text = String::from_utf8_lossy(&out.stdout);
        let served = text
            .lines()
            .filter(|l| l.contains("Localization [") && l.contains("-> localization"))
            .count();
        if served >= 2 {
            return true;
        }
        std::thread::sleep(Duration::from_millis(300));
    }
    false
}

fn check_goals(s: &serde_json::Value, text: &str) {
    assert_eq!(s["success"], true, "{s}\n{text}");
    assert_eq!(s["collisions"], 0, "{s}");
    let goals = s["goals"].as_array().expect("goals");
    assert_eq!(goals.len(), 3, "{s}");
    for g in goals {
        assert_eq!(g["state"], "reached", "{g}");
        assert_eq!(g["tolerance_m"].as_f64(), Some(0.3), "{g}");
        let err = g["true_error_m"].as_f64().expect("true error");
        assert!(err <= 0.3, "goal {g}: true error {err} m\n{text}");
    }
}

#[test]
fn the_fused_localization_serves_and_every_goal_ends_within_0_3_m_of_the_truth() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("loc_fused");
    let mut run = Reaped(
        m.command(&["--speed", "10", "--no-gui"])
            .stdout(Stdio::piped())
            .spawn()
            .expect("hng run"),
    );
    let serving = fused_serves_both_clients(&m, &mut run);
    let (status, text, _) = run.finish();
    assert!(
        serving,
        "the fused localization never served Servo and Planning\n{text}"
    );
    assert!(status.success(), "{text}");
    check_goals(&m.summary(&text), &text);
    // Never replaced by the GPS or SLAM: no Localization switch at all.
    assert!(!text.contains("Localization: localization ->"), "{text}");
}

#[test]
fn when_the_fused_localization_dies_its_clients_switch_away_and_back_after_its_restart() {
    let _heavy = crate::common::heavy();
    let m = MissionRun::new("loc_killed");
    let mut run = Reaped(
        m.command(&["--speed", "5", "--no-gui"])
            .stdout(Stdio::piped())
            .spawn()
            .expect("hng run"),
    );
    assert!(fused_serves_both_clients(&m, &mut run), "never served");
    let killed = hng()
        .args(["--prefix", &m.prefix, "kill", "localization"])
        .stdout(Stdio::null())
        .status()
        .expect("hng kill");
    assert!(killed.success());
    let (_, text, _) = run.finish();
    for client in ["servo", "planning"] {
        let away = format!("contract switch: {client} Localization: localization -> ");
        let back = format!("contract switch: {client} Localization: ");
        let at = text
            .find(&away)
            .unwrap_or_else(|| panic!("{client} never left the dead provider\n{text}"));
        let returned = text[at + away.len()..]
            .lines()
            .any(|l| l.contains(&back) && l.ends_with("-> localization"));
        assert!(returned, "{client} never came back\n{text}");
    }
    assert!(text.contains("module localization restarted"), "{text}");
    let s = m.summary(&text);
    assert_eq!(s["collisions"], 0, "{s}");
}
