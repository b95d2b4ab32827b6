use super::*;
use std::os::unix::fs::PermissionsExt;
use std::path::Path;

fn opts() -> LoadOptions {
    LoadOptions {
        self_exe: Some(PathBuf::from("/bin/sh")),
        path: Some(OsString::from("/nonexistent-dir:/bin:/usr/bin")),
        check_binaries: true,
        check_module: None,
    }
}

fn file() -> &'static Path {
    Path::new("/etc/hng/test.launch.toml")
}

fn errors(src: &str) -> Vec<LaunchError> {
    match parse(src, file(), &opts()) {
        Ok(plan) => panic!("expected errors, got a plan: {plan:#?}"),
        Err(LaunchErrors(e)) => e,
    }
}

fn plan(src: &str) -> LaunchPlan {
    match parse(src, file(), &opts()) {
        Ok(p) => p,
        Err(e) => panic!("unexpected errors:\n{e}"),
    }
}

/// The single error of `src`, asserting its line and field.
fn one_error(src: &str, line: usize, field: Option<&str>) -> LaunchErrorKind {
    let errs = errors(src);
    assert_eq!(errs.len(), 1, "expected one error, got {errs:#?}");
    let e = &errs[0];
    assert_eq!(e.line, line, "wrong line for {e}");
    assert_eq!(e.field.as_deref(), field, "wrong field for {e}");
    assert_eq!(e.file, file());
    e.kind.clone()
}

const FULL: &str = r#"
system = "explorer"

[defaults]
restart = "on-failure"
backoff_initial_s = 0.05
backoff_max_s = 2
give_up_failures = 3
give_up_window_s = 10.0
heartbeat_period_s = 0.1
stop_timeout_s = 1
memory_max = "512MiB"
env = { RUST_LOG = "info", A = "1" }

[[module]]
name = "slam"
command = ["hng", "module", "slam"]
needs = ["scan"]
provides = ["map"]
restart = "always"
cpu_quota = "50%"
memory_max = "1GiB"
pids_max = 32
heartbeat_timeout_s = 1.0
checkpoint_period_s = 2
env = { A = "2" }

[[module]]
name = "lidar"
command = ["sleep", "1000"]
provides = ["scan"]
manager = false
heartbeat_period_s = "off"

[[module]]
name = "rm"
command = ["/bin/sh", "-c", "exit 0"]
manager = true
cpu_quota = 0.25
"#;

#[test]
fn full_example_is_valid_and_merged() {
    let p = plan(FULL);
    assert_eq!(p.system, "explorer");
    let names: Vec<&str> = p.modules.iter().map(|m| m.name.as_str()).collect();
    // lidar provides what slam needs, so it starts first.
    assert_eq!(names, ["lidar", "slam", "rm"]);
    let slam = &p.modules[1];
    assert_eq!(
        slam.program,
        PathBuf::from("/bin/sh"),
        "hng resolves to self_exe"
    );
    assert_eq!(slam.args, ["module", "slam"]);
    assert_eq!(slam.restart, RestartPolicy::Always);
    assert_eq!(slam.backoff_initial, Duration::from_millis(50));
    assert_eq!(slam.give_up_failures, 3);
    assert_eq!(
        slam.heartbeat,
        Some(HeartbeatSpec {
            period: Duration::from_millis(100),
            timeout: Duration::from_secs(1)
        })
    );
    assert_eq!(slam.checkpoint_period, Some(Duration::from_secs(2)));
    assert_eq!(slam.resources.cpu_quota, Some(0.5));
    assert_eq!(slam.resources.memory_max, Some(1 << 30));
    assert_eq!(slam.resources.pids_max, Some(32));
    assert_eq!(slam.env.get("A").map(String::as_str), Some("2"));
    assert_eq!(slam.env.get("RUST_LOG").map(String::as_str), Some("info"));
    let lidar = &p.modules[0];
    assert!(lidar.program.ends_with("sleep"), "{:?}", lidar.program);
    assert_eq!(
        lidar.heartbeat, None,
        "heartbeat_period = off overrides defaults"
    );
    assert_eq!(lidar.resources.memory_max, Some(512 << 20));
    assert_eq!(lidar.restart, RestartPolicy::OnFailure);
    let rm = &p.modules[2];
    assert!(rm.manager);
    assert_eq!(rm.resources.cpu_quota, Some(0.25));
    assert_eq!(
        rm.heartbeat.map(|h| h.timeout),
        Some(Duration::from_millis(300)),
        "timeout defaults to 3 periods"
    );
    assert!(p.warnings.is_empty(), "{:?}", p.warnings);
}

#[test]
fn at_hng_alias_and_relative_paths() {
    let dir = std::env::temp_dir().join(format!("hng-launch-rel-{}", std::process::id()));
    let _ = std::fs::create_dir_all(dir.join("bin"));
    let exe = dir.join("bin/tool");
    let noexec = dir.join("bin/data");
    assert!(std::fs::write(&exe, "#!/bin/sh\n").is_ok());
    assert!(std::fs::write(&noexec, "x").is_ok());
    assert!(std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).is_ok());
    let launch = dir.join("sys.toml");
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"@hng\"]\n[[module]]\nname = \"b\"\ncommand = [\"bin/tool\"]\n[[module]]\nname = \"c\"\ncommand = [\"./bin/data\"]\n";
    let r = parse(src, &launch, &opts());
    let _ = std::fs::remove_dir_all(&dir);
    let errs = match r {
        Ok(p) => panic!("bin/data is not executable, got {p:#?}"),
        Err(LaunchErrors(e)) => e,
    };
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert_eq!(errs[0].line, 10);
    assert!(
        matches!(&errs[0].kind, LaunchErrorKind::MissingBinary { reason, .. } if reason.contains("not executable")),
        "{}",
        errs[0]
    );
}

#[test]
fn syntax_error_has_line_and_column() {
    let src = "system = \"s\"\n\n[[module]]\nname = \"a\nc = 1\n";
    let errs = errors(src);
    assert!(!errs.is_empty());
    assert!(
        errs.iter()
            .all(|e| matches!(e.kind, LaunchErrorKind::Syntax(_)))
    );
    assert_eq!(errs[0].line, 4, "{}", errs[0]);
    // The unterminated string is reported where the line ends.
    assert_eq!(errs[0].column, 10, "{}", errs[0]);
}

#[test]
fn unknown_field_in_module() {
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\", \"1\"]\nrestrat = \"always\"\n";
    let k = one_error(src, 5, Some("module[0].restrat"));
    assert!(
        matches!(&k, LaunchErrorKind::UnknownField(m) if m.contains("restrat")),
        "{k}"
    );
}

#[test]
fn unknown_field_in_defaults_and_top_level() {
    let src = "system = \"s\"\nsytem = 1\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n";
    let k = one_error(src, 2, Some("sytem"));
    assert!(matches!(k, LaunchErrorKind::UnknownField(_)), "{k}");
    let src = "system = \"s\"\n[defaults]\nheartbeat = 1\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n";
    let k = one_error(src, 3, Some("defaults.heartbeat"));
    assert!(matches!(k, LaunchErrorKind::UnknownField(_)), "{k}");
}

#[test]
fn wrong_types() {
    let src =
        "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\nmanager = \"yes\"\n";
    let k = one_error(src, 5, Some("module[0].manager"));
    assert!(matches!(k, LaunchErrorKind::WrongType(_)), "{k}");
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = \"sleep 1\"\n";
    let k = one_error(src, 4, Some("module[0].command"));
    assert!(matches!(k, LaunchErrorKind::WrongType(_)), "{k}");
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\nrestart = \"sometimes\"\n";
    let k = one_error(src, 5, Some("module[0].restart"));
    assert!(matches!(k, LaunchErrorKind::InvalidValue(_)), "{k}");
}

#[test]
fn missing_fields() {
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\n";
    let k = one_error(src, 2, Some("module[0]"));
    assert!(
        matches!(&k, LaunchErrorKind::MissingField(m) if m.contains("command")),
        "{k}"
    );
    let src = "[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n";
    let k = one_error(src, 1, None);
    assert!(
        matches!(&k, LaunchErrorKind::MissingField(m) if m.contains("system")),
        "{k}"
    );
}

#[test]
fn missing_binary() {
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\n  \"no-such-program-hng\", \"x\"]\n";
    let k = one_error(src, 5, Some("module[0].command"));
    assert!(
        matches!(&k, LaunchErrorKind::MissingBinary { program, .. } if program == "no-such-program-hng"),
        "{k}"
    );
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"/no/such/file\"]\n";
    let k = one_error(src, 4, Some("module[0].command"));
    assert!(matches!(k, LaunchErrorKind::MissingBinary { .. }), "{k}");
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = []\n";
    let k = one_error(src, 4, Some("module[0].command"));
    assert!(matches!(k, LaunchErrorKind::InvalidValue(_)), "{k}");
}

#[test]
fn duplicate_module_names() {
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n";
    let k = one_error(src, 7, Some("module[1].name"));
    assert_eq!(
        k,
        LaunchErrorKind::DuplicateModule {
            name: "a".into(),
            first_line: 3
        }
    );
}

#[test]
fn two_managers() {
    let src = "system = \"s\"\n[[module]]\nname = \"rm1\"\ncommand = [\"sleep\"]\nmanager = true\n[[module]]\nname = \"rm2\"\ncommand = [\"sleep\"]\nmanager = true\n";
    let k = one_error(src, 9, Some("module[1].manager"));
    assert_eq!(
        k,
        LaunchErrorKind::TwoManagers {
            first: "rm1".into(),
            first_line: 5
        }
    );
}

#[test]
fn needs_provides_cycle() {
    let src = "system = \"s\"\n\
[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\nneeds = [\"y\"]\nprovides = [\"x\"]\n\
[[module]]\nname = \"b\"\ncommand = [\"sleep\"]\nneeds = [\"x\"]\nprovides = [\"y\"]\n\
[[module]]\nname = \"c\"\ncommand = [\"sleep\"]\nneeds = [\"nobody\"]\n";
    let k = one_error(src, 5, Some("module \"a\".needs"));
    match k {
        LaunchErrorKind::Cycle(path) => assert_eq!(path, ["a", "b", "a"]),
        other => panic!("not a cycle: {other}"),
    }
}

#[test]
fn unprovided_need_is_a_warning() {
    let src = "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\nneeds = [\"x\"]\n";
    let p = plan(src);
    assert_eq!(p.warnings.len(), 1, "{:?}", p.warnings);
}

#[test]
fn invalid_values_in_module_and_defaults() {
    let src = r#"system = "s"
[defaults]
backoff_initial_s = "10 parsecs"
memory_max = "lots"
[[module]]
name = "a"
command = ["sleep"]
heartbeat_period_s = 0.1
heartbeat_timeout_s = 0.05
cpu_quota = -1
stop_timeout_s = "5s"
[[module]]
name = "b c"
command = ["sleep"]
pids_max = 0
give_up_window_s = -1
backoff_max_s = nan
start_timeout_s = inf
"#;
    let errs = errors(src);
    let got: Vec<(usize, Option<&str>)> =
        errs.iter().map(|e| (e.line, e.field.as_deref())).collect();
    assert_eq!(
        got,
        [
            (3, Some("defaults.backoff_initial_s")),
            (4, Some("defaults.memory_max")),
            (9, Some("module[0].heartbeat_timeout_s")),
            (10, Some("module[0].cpu_quota")),
            (11, Some("module[0].stop_timeout_s")),
            (13, Some("module[1].name")),
            (15, Some("module[1].pids_max")),
            (16, Some("module[1].give_up_window_s")),
            (17, Some("module[1].backoff_max_s")),
            (18, Some("module[1].start_timeout_s")),
        ],
        "{errs:#?}"
    );
    assert!(
        errs.iter()
            .all(|e| matches!(e.kind, LaunchErrorKind::InvalidValue(_)))
    );
    let text = |line: usize| {
        errs.iter()
            .find(|e| e.line == line)
            .map(|e| e.kind.to_string())
            .unwrap_or_default()
    };
    assert!(
        text(11).contains("write 5 instead of \"5s\""),
        "{}",
        text(11)
    );
    assert!(text(16).contains("negative"), "{}", text(16));
    assert!(text(17).contains("finite"), "{}", text(17));
    assert!(text(18).contains("finite"), "{}", text(18));
}

#[test]
fn old_duration_keys_name_their_new_spelling_all_at_once() {
    let src = r#"system = "s"
[defaults]
heartbeat_period = "200ms"
stop_timeout = "2s"
[[module]]
name = "a"
command = ["sleep"]
checkpoint_period = "off"
start_timeout = 5
colour = "blue"
"#;
    let errs = errors(src);
    let got: Vec<(usize, usize, Option<&str>, String)> = errs
        .iter()
        .map(|e| (e.line, e.column, e.field.as_deref(), e.kind.to_string()))
        .collect();
    fn want<'a>(
        line: usize,
        field: &'a str,
        message: &str,
    ) -> (usize, usize, Option<&'a str>, String) {
        (line, 1, Some(field), message.to_owned())
    }
    assert_eq!(
        got[..4],
        [
            want(
                3,
                "defaults.heartbeat_period",
                "`heartbeat_period` is now `heartbeat_period_s` (seconds): write heartbeat_period_s = 0.2"
            ),
            want(
                4,
                "defaults.stop_timeout",
                "`stop_timeout` is now `stop_timeout_s` (seconds): write stop_timeout_s = 2"
            ),
            want(
                8,
                "module[0].checkpoint_period",
                "`checkpoint_period` is now `checkpoint_period_s` (seconds): write checkpoint_period_s = \"off\""
            ),
            want(
                9,
                "module[0].start_timeout",
                "`start_timeout` is now `start_timeout_s` (seconds)"
            ),
        ],
        "{errs:#?}"
    );
    // The rest of the module is still checked.
    assert_eq!(got.len(), 5, "{errs:#?}");
    assert_eq!(got[4].2, Some("module[0].colour"), "{errs:#?}");
    assert!(
        errs.iter()
            .all(|e| matches!(e.kind, LaunchErrorKind::UnknownField(_)))
    );
}

#[test]
fn the_printed_plan_says_durations_in_seconds() {
    let p = plan(FULL);
    let json = serde_json::to_value(&p.modules[1]).expect("a plan serializes");
    assert_eq!(json["backoff_initial_s"], 0.05);
    assert_eq!(json["checkpoint_period_s"], 2.0);
    assert_eq!(json["heartbeat"]["timeout_s"], 1.0);
    let lidar = serde_json::to_value(&p.modules[0]).expect("a plan serializes");
    assert_eq!(lidar["checkpoint_period_s"], "off");
}

#[test]
fn all_errors_reported_together() {
    let src = r#"system = "s"
[[module]]
name = "a"
command = ["sleep"]
colour = "blue"
[[module]]
name = "b"
command = ["not-a-real-binary-hng"]
[[module]]
name = "b"
command = ["sleep"]
manager = true
[[module]]
name = "d"
command = ["sleep"]
manager = true
"#;
    let errs = errors(src);
    let lines: Vec<usize> = errs.iter().map(|e| e.line).collect();
    assert_eq!(lines, [5, 8, 10, 16], "{errs:#?}");
    let text = LaunchErrors(errs).to_string();
    assert!(text.starts_with("4 errors in launch file"), "{text}");
    assert!(
        text.contains("/etc/hng/test.launch.toml:5:1: `module[0].colour`"),
        "{text}"
    );
}

#[test]
fn line_col_counts_characters() {
    let src = "ab\néé = 1\n";
    assert_eq!(line_col(src, 0), (1, 1));
    assert_eq!(line_col(src, 3), (2, 1));
    assert_eq!(line_col(src, 7), (2, 3));
    assert_eq!(line_col(src, 1000), (3, 1));
}

#[test]
fn load_reports_unreadable_file() {
    let e = load(Path::new("/nonexistent/launch.toml"), &opts());
    assert!(matches!(e, Err(LaunchErrors(v)) if matches!(v[0].kind, LaunchErrorKind::Read(_))));
}

#[test]
fn shipped_example_file_is_valid() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/explorer.launch.toml");
    let plan = match load(&file, &LoadOptions::default()) {
        Ok(p) => p,
        Err(e) => panic!("{e}"),
    };
    let names: Vec<&str> = plan.modules.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["rm", "lidar", "slam"]);
}

#[test]
fn module_config_table_clock_and_checkpoint_dir() {
    let p = plan(
        r#"
system = "s"
clock = "sim"
checkpoint_dir = "state"

[[module]]
name = "a"
command = ["sleep", "1"]

[module.config]
period_s = 0.005
output = "test/count"
nested = { x = 1.5 }

[[module]]
name = "b"
command = ["sleep", "1"]
"#,
    );
    assert!(p.sim_clock);
    assert_eq!(p.checkpoint_dir, Some(PathBuf::from("/etc/hng/state")));
    let cfg: toml::Table = toml::from_str(&p.modules[0].config).expect("config is TOML");
    assert_eq!(cfg.get("period_s").and_then(|v| v.as_float()), Some(0.005));
    assert_eq!(
        cfg.get("nested")
            .and_then(|v| v.get("x"))
            .and_then(|v| v.as_float()),
        Some(1.5)
    );
    assert_eq!(p.modules[1].config, "");
    assert!(!plan("system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n").sim_clock);
}

#[test]
fn bad_clock_and_config_type() {
    let kind = one_error(
        "system = \"s\"\nclock = \"fast\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\n",
        2,
        Some("clock"),
    );
    assert!(
        matches!(kind, LaunchErrorKind::InvalidValue(ref m) if m.contains("sim")),
        "{kind:?}"
    );
    let kind = one_error(
        "system = \"s\"\n[[module]]\nname = \"a\"\ncommand = [\"sleep\"]\nconfig = 3\n",
        5,
        Some("module[0].config"),
    );
    assert!(matches!(kind, LaunchErrorKind::WrongType(_)), "{kind:?}");
}
