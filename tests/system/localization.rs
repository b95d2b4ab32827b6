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
        if !run.running() {
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
    let mut run = m.start(&["--speed", "10", "--no-gui"], Stdio::inherit());
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
    let mut run = m.start(&["--speed", "5", "--no-gui"], Stdio::inherit());
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

/// The robot is carried elsewhere mid-mission (`sim/teleport`) and the operator says where
/// (`operator/initial_pose`): the fused localization is there within half a second of
/// simulated time (without the estimate it would gate the far GPS fixes for 2 s and stay
/// behind), and the mission goes on from there to its goal. At twice real time: this test is
/// no lockstep participant, so simulated time runs on while it is scheduled out between the
/// two messages, and a slow simulation keeps that share of the measurement small.
#[test]
fn a_robot_carried_elsewhere_and_told_where_it_is_localizes_there_at_once_and_reaches_its_goal() {
    use hng_runtime::msg::{FrameId, Header, Pose2D, PoseWithCovariance};
    use hng_runtime::wait::{WaitMode, Waiter};
    use hng_runtime::{Node, NodeOptions};
    use hng_simulator::module::SimTeleport;

    let _heavy = crate::common::heavy();
    let m = MissionRun::new("loc_carried");
    let node = Node::new(NodeOptions::new("carrier").prefix(&m.prefix)).expect("node");
    // Recorders' buffers: a loaded test process loses no pose between two polls.
    let truth = node
        .tap_subscriber::<PoseWithCovariance>("sim/ground_truth")
        .expect("truth");
    let fused = node
        .tap_subscriber::<PoseWithCovariance>("localization/pose")
        .expect("pose");
    let teleport = node
        .publisher::<SimTeleport>("sim/teleport")
        .expect("teleport");
    let estimate = node
        .publisher::<PoseWithCovariance>(hng_modules::initial_pose::INITIAL_POSE_CHANNEL)
        .expect("estimate");
    let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
    waiter.attach(&truth).expect("attach");
    waiter.attach(&fused).expect("attach");
    let mut run = m.start(
        &[
            "--speed",
            "10",
            "--no-gui",
            "--start",
            "2,2,0",
            "--goal",
            "6.5,12",
            "--duration",
            "90",
        ],
        Stdio::inherit(),
    );
    let there = Pose2D::new(6.5, 7.0, std::f64::consts::FRAC_PI_2);
    let stamp = |p: &PoseWithCovariance| p.header.stamp_ns as f64 * 1e-9;
    let deadline = Instant::now() + Duration::from_secs(120);
    let (mut truths, mut poses, mut sent) = (Vec::new(), Vec::new(), false);
    while run.running() {
        assert!(Instant::now() < deadline, "the mission did not end in time");
        while let Some(t) = truth.receive().expect("truth") {
            if !sent && stamp(&t) > 1.0 {
                // The estimate first: the test may be preempted between the two, and the
                // localization is then measured from the jump, which comes after.
                estimate
                    .publish(PoseWithCovariance {
                        header: Header {
                            frame_id: FrameId::MAP,
                            ..Header::default()
                        },
                        pose: there,
                        covariance: [0.0; 9],
                    })
                    .expect("publish");
                teleport
                    .publish(SimTeleport {
                        pose: there,
                        ..SimTeleport::default()
                    })
                    .expect("publish");
                sent = true;
            }
            truths.push(*t);
        }
        while let Some(p) = fused.receive().expect("pose") {
            poses.push(*p);
        }
        waiter.wait(Some(Duration::from_millis(10))).expect("wait");
    }
    let (status, text, _) = run.finish();
    // The jump: the first true pose more than 3 m from the one before (the robot drives at
    // most 0.5 m/s).
    let d = |a: &PoseWithCovariance, b: &PoseWithCovariance| {
        (a.pose.x - b.pose.x).hypot(a.pose.y - b.pose.y)
    };
    let jump = truths
        .windows(2)
        .find(|w| d(&w[0], &w[1]) > 3.0)
        .map(|w| stamp(&w[1]))
        .unwrap_or_else(|| panic!("the robot was never carried\n{text}"));
    // The first fused pose after it within 0.3 m of the true pose of its time.
    let localized = poses
        .iter()
        .filter(|p| stamp(p) >= jump)
        .find(|p| {
            truths
                .iter()
                .min_by(|a, b| {
                    (stamp(a) - stamp(p))
                        .abs()
                        .total_cmp(&(stamp(b) - stamp(p)).abs())
                })
                .is_some_and(|t| d(t, p) < 0.3)
        })
        .map(stamp)
        .unwrap_or_else(|| panic!("never localized at the new place\n{text}"));
    assert!(
        localized - jump < 0.5,
        "localized {} s of simulated time after the jump\n{text}",
        localized - jump
    );
    assert!(status.success(), "{text}");
    let s = m.summary(&text);
    assert_eq!(s["collisions"], 0, "{s}");
    assert_eq!(s["goals"][0]["state"], "reached", "{s}");
}
