//! `hng mission show|set|add|clear|skip` against a real Manager process.

use std::process::{Command, Output};
use std::time::Duration;

use hng_modules::manager::MissionPlan;

use crate::common::{TestSystem, wait_for_report};

fn hng(prefix: &str, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hng"))
        .args(["--prefix", prefix, "mission"])
        .args(args)
        .env("HNG_LOG", "warn")
        .output()
        .expect("run hng mission")
}

fn show(prefix: &str) -> MissionPlan {
    let out = hng(prefix, &["show", "--json"]);
    assert!(
        out.status.success(),
        "hng mission show: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("mission JSON")
}

fn ok(prefix: &str, args: &[&str]) -> String {
    let out = hng(prefix, args);
    assert!(
        out.status.success(),
        "hng mission {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn states(p: &MissionPlan) -> Vec<(u32, &str)> {
    p.goals.iter().map(|g| (g.id, g.state.as_str())).collect()
}

#[test]
fn mission_cli_shows_and_changes_the_running_mission() {
    let mut sys = TestSystem::new("mission-cli");
    let node = sys.node("mission-cli-test");
    sys.spawn(
        Command::new(env!("CARGO_BIN_EXE_hng"))
            .args(["module", "manager"])
            .env("HNG_MODULE_NAME", "manager")
            .env("HNG_MODULE_CONFIG", "goals = [{ x = 1.0, y = 2.0 }]")
            .env("HNG_LOG", "warn")
            .env("HNG_WAIT", "blocking:0")
            .env_remove("HNG_CHECKPOINT_DIR"),
    );
    wait_for_report(&node, "manager", Duration::from_secs(20), |_| true);

    let p = show(&sys.prefix);
    assert_eq!((p.goals_total, p.current_goal_id), (1, 1));
    assert_eq!(states(&p), [(1, "active")]);
    assert_eq!((p.goals[0].x, p.goals[0].y), (1.0, 2.0));

    let text = ok(
        &sys.prefix,
        &["add", "3,4", "5,-6,1.5", "--tolerance", "0.5"],
    );
    assert!(text.contains("3 goals"), "{text}");
    let p = show(&sys.prefix);
    assert_eq!(states(&p), [(1, "active"), (2, "pending"), (3, "pending")]);
    assert_eq!((p.goals[2].y, p.goals[2].theta), (-6.0, Some(1.5)));
    assert_eq!(p.goals[1].tolerance_m, 0.5);

    ok(&sys.prefix, &["skip"]);
    let p = show(&sys.prefix);
    assert_eq!(states(&p), [(1, "refused"), (2, "active"), (3, "pending")]);
    assert_eq!(p.goals_refused, 1);

    ok(&sys.prefix, &["set", "7,8"]);
    let p = show(&sys.prefix);
    assert_eq!(
        states(&p),
        [(1, "refused"), (4, "active")],
        "ids are never reused"
    );

    // Bad input: a clear error, and the mission is unchanged.
    let revision = p.revision;
    let out = hng(&sys.prefix, &["add", "1,x"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("\"x\" is not a number"), "{err}");
    let out = hng(&sys.prefix, &["add", "1,2", "--tolerance", "-1"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("goals[0].tolerance"), "{err}");
    assert_eq!(show(&sys.prefix).revision, revision);

    ok(&sys.prefix, &["clear"]);
    let p = show(&sys.prefix);
    assert!(p.done && p.current_goal_id == 0, "{p:?}");

    sys.stop_cleanly();
}

#[test]
fn mission_cli_without_a_system_says_so() {
    let sys = TestSystem::new("mission-none");
    let out = hng(&sys.prefix, &["show"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no Manager runs under prefix"), "{err}");
}
