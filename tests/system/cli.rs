//! The command line's small promises, with real processes: a reader that goes away ends a
//! tool quietly, read-only tools leave no file behind (and take with them system files left
//! where no system runs), launch-file problems (built-in module
//! names and configurations, durations that would switch safety off) are found before
//! anything starts, with the file's line and field.

use std::io::Read as _;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use hng_runtime::shm;

use crate::common::TestSystem;

const HNG: &str = env!("CARGO_BIN_EXE_hng");

/// Runs `hng ARGS` on `prefix` to its end.
fn hng<S: AsRef<std::ffi::OsStr>>(prefix: &str, args: &[S]) -> Output {
    Command::new(HNG)
        .args(args)
        .env("HNG_PREFIX", prefix)
        .output()
        .expect("hng")
}

/// Runs `hng ARGS` on `prefix` with its stdout a pipe that this side closes after reading
/// `keep` bytes; returns the exit status and stderr.
fn with_closed_pipe(
    prefix: &str,
    args: &[&str],
    keep: usize,
) -> (std::process::ExitStatus, String) {
    let mut child = Command::new(HNG)
        .args(args)
        .env("HNG_PREFIX", prefix)
        .env("HNG_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn hng");
    let mut out = child.stdout.take().expect("stdout");
    let mut buf = vec![0u8; keep];
    if keep > 0 {
        out.read_exact(&mut buf).expect("read the first bytes");
    }
    drop(out);
    let status = child.wait().expect("wait");
    let mut err = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = e.read_to_string(&mut err);
    }
    (status, err)
}

#[test]
fn a_closed_pipe_ends_topic_list_and_echo_quietly() {
    let mut sys = TestSystem::new("clipipe");
    sys.spawn_testmod("counter", "counter", "period_s = 0.005");
    // The counter's channel exists once it runs.
    crate::common::poll_until(
        Duration::from_secs(30),
        Duration::from_millis(20),
        || {
            let out = hng(&sys.prefix, &["topic", "list"]);
            String::from_utf8_lossy(&out.stdout).contains("test/count")
        },
        || "no test/count channel".to_owned(),
    );
    // `hng topic list | head -c 0`: the reader is gone before the first line.
    let (status, err) = with_closed_pipe(&sys.prefix, &["topic", "list"], 0);
    assert_eq!(status.code(), Some(0), "topic list: {err}");
    assert!(!err.contains("panicked"), "{err}");
    // `hng topic echo test/count | head -c 100`.
    let (status, err) = with_closed_pipe(&sys.prefix, &["topic", "echo", "test/count"], 100);
    assert_eq!(status.code(), Some(0), "topic echo: {err}");
    assert!(!err.contains("panicked"), "{err}");
    let (status, err) = with_closed_pipe(
        &sys.prefix,
        &["topic", "hz", "test/count", "--window", "0.2", "--json"],
        10,
    );
    assert_eq!(status.code(), Some(0), "topic hz: {err}");
    assert!(!err.contains("panicked"), "{err}");
    sys.stop_all();
}

#[test]
fn read_only_tools_without_a_system_fail_clearly_and_leave_no_file() {
    let prefix = shm::unique_prefix("clinone");
    for args in [
        vec!["contracts"],
        vec!["contracts", "--json"],
        vec!["top", "--once"],
        vec!["ps"],
        vec!["topic", "echo", "sim/scan", "--count", "1"],
        vec!["topic", "pub", "hng/teleop", "{\"linear_x\": 0.1}"],
    ] {
        let out = hng(&prefix, &args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(&prefix), "{args:?} names the prefix: {err}");
        assert!(!err.contains("panicked"), "{err}");
        let files = shm::prefix_files(&prefix);
        assert!(files.is_empty(), "{args:?} left {files:?}");
    }
}

/// A client that opened a channel of a system while it stopped (a `hng kill` during the
/// supervisor's clean-up, seen once in CI) creates that channel's wake segment after the prefix
/// was cleaned. Such system files, alone on a prefix where no system runs, go with the client's
/// exit; on a prefix where a system lives they stay (it is theirs).
#[test]
fn a_client_removes_system_files_left_on_a_prefix_where_no_system_runs() {
    let prefix = shm::unique_prefix("clileft");
    let wake = std::path::Path::new("/dev/shm").join(format!("{prefix}hngwake_0123456789abcdef"));
    std::fs::write(&wake, [0u8; 64]).expect("a wake segment");
    let out = hng(&prefix, &["kill", "camera"]);
    assert_eq!(out.status.code(), Some(1), "no system: {out:?}");
    let files = shm::prefix_files(&prefix);
    assert!(files.is_empty(), "left {files:?}");

    // Beside a file of a living node, the system's files are left alone.
    let node = std::path::Path::new("/dev/shm").join(format!("{prefix}some_node_file"));
    std::fs::write(&wake, [0u8; 64]).expect("a wake segment");
    std::fs::write(&node, [0u8; 8]).expect("a node's file");
    let _ = hng(&prefix, &["ps"]);
    assert!(wake.exists(), "a living system's wake segment was removed");
    shm::remove_prefix_files(&prefix);
}

#[test]
fn built_in_module_names_configs_and_bad_or_old_durations_are_checked_before_anything_starts() {
    let prefix = shm::unique_prefix("clibad");
    let dir = std::env::temp_dir().join(format!("hng-clibad-{}", prefix.trim_end_matches('_')));
    std::fs::create_dir_all(&dir).expect("dir");
    let file = dir.join("bad.toml");
    let text = [
        "system = \"bad\"",                               // 1
        "",                                               // 2
        "[defaults]",                                     // 3
        "heartbeat_period_s = 0.0",                       // 4
        "give_up_window_s = 0.0",                         // 5
        "",                                               // 6
        "[[module]]",                                     // 7
        "name = \"a\"",                                   // 8
        "command = [\"hng\", \"module\", \"plannign\"]",  // 9
        "",                                               // 10
        "[[module]]",                                     // 11
        "name = \"b\"",                                   // 12
        "command = [\"hng\", \"module\", \"interface\"]", // 13
        "start_timeout_s = 0.0",                          // 14
        "",                                               // 15
        "[module.config]",                                // 16
        "teleop_in = \"hng/teleop\"",                     // 17
        "colour = \"red\"",                               // 18
        "",                                               // 19
        "[[module]]",                                     // 20
        "name = \"c\"",                                   // 21
        "command = [\"hng\", \"module\", \"robot\"]",     // 22
        "heartbeat_period = \"200ms\"",                   // 23
        "stop_timeout_s = -1",                            // 24
        "[module.config]",                                // 25
        "max_linear_speed = \"fast\"",                    // 26
    ];
    std::fs::write(&file, text.join("\n")).expect("write");
    let out = Command::new(HNG)
        .args(["run", "--no-rm", "--no-gui"])
        .arg(&file)
        .env("HNG_PREFIX", &prefix)
        .output()
        .expect("hng run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "exit code 2: {err}");
    let name = file.display().to_string();
    for (line, needle) in [
        (4, "heartbeat_period_s"),
        (5, "give_up_window_s"),
        (9, "no built-in module \"plannign\""),
        (14, "start_timeout_s"),
        (18, "colour"),
        (
            23,
            "`module[2].heartbeat_period`: `heartbeat_period` is now `heartbeat_period_s` (seconds): write heartbeat_period_s = 0.2",
        ),
        (24, "`module[2].stop_timeout_s`: -1 s is negative"),
        (26, "max_linear_speed"),
    ] {
        assert!(
            err.lines()
                .any(|l| l.contains(&format!("{name}:{line}:")) && l.contains(needle)),
            "line {line} ({needle}) reported: {err}"
        );
    }
    assert!(err.contains("module[1].config.colour"), "{err}");
    assert!(shm::prefix_files(&prefix).is_empty(), "nothing started");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn iox2_config_is_iceoryx2_toml_with_the_prefix_and_reads_back() {
    let prefix = shm::unique_prefix("cliiox");
    let out = hng(&prefix, &["iox2-config"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    let v: toml::Table = toml::from_str(&text).expect("TOML");
    assert_eq!(v["global"]["prefix"].as_str(), Some(prefix.as_str()));
    // iceoryx2's service, node and event files go to the system's own folder on tmpfs.
    assert_eq!(
        v["global"]["root-path"].as_str(),
        Some(format!("/dev/shm/{prefix}iox/").as_str()),
        "{text}"
    );
    // iceoryx2 itself reads it back as the configuration hng uses for the prefix.
    let dir = std::env::temp_dir().join(format!("hng-cliiox-{}", prefix.trim_end_matches('_')));
    std::fs::create_dir_all(&dir).expect("dir");
    let file = dir.join("iceoryx2.toml");
    std::fs::write(&file, text.as_bytes()).expect("write");
    use iceoryx2::prelude::*;
    let path = FilePath::new(file.to_string_lossy().as_bytes()).expect("file path");
    let read = iceoryx2::config::Config::from_file(&path).expect("iceoryx2 reads it");
    let ours = hng_runtime::channel::iceoryx_config(&prefix).expect("hng's config");
    assert_eq!(read, ours);
    assert!(
        shm::prefix_files(&prefix).is_empty(),
        "printing creates nothing"
    );

    // A prefix too long for iceoryx2's socket paths is refused, saying the limit, by a tool and
    // by `hng run` before anything starts.
    let long = format!(
        "{prefix}{}",
        "x".repeat(shm::MAX_PREFIX_LEN + 1 - prefix.len())
    );
    let launch = dir.join("sleeper.toml");
    std::fs::write(
        &launch,
        "system = \"s\"\n\n[[module]]\nname = \"sleeper\"\ncommand = [\"/bin/sleep\", \"1000\"]\n",
    )
    .expect("write");
    let run = [
        "run".to_owned(),
        "--no-rm".to_owned(),
        "--no-gui".to_owned(),
        launch.display().to_string(),
    ];
    for args in [vec!["iox2-config".to_owned()], run.to_vec()] {
        let out = hng(&long, &args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("25 bytes, longer than the 24 allowed") && err.contains("108 bytes"),
            "{args:?}: {err}"
        );
        assert!(
            shm::prefix_files(&long).is_empty(),
            "{args:?} created files"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
