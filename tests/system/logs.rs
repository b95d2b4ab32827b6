//! Quiet by default: `hng run` keeps module output in per-module log files that `hng logs`
//! shows; `-v` echoes it on the terminal.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use hng_runtime::shm;

const HNG: &str = env!("CARGO_BIN_EXE_hng");

fn hng(prefix: &str, run_dir: &Path, args: &[&str]) -> Output {
    Command::new(HNG)
        .args(args)
        .env("HNG_PREFIX", prefix)
        .env("HNG_RUN_DIR", run_dir)
        .env_remove("HNG_LOG")
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .output()
        .expect("run hng")
}

/// Runs a one-module system whose module writes a line to stdout and one to stderr, waits for
/// both in its log file, stops the system with `hng stop`; returns `hng run`'s output.
fn run_echoer(tag: &str, extra: &[&str]) -> (String, PathBuf, Output) {
    let prefix = shm::unique_prefix(tag);
    let dir = std::env::temp_dir().join(format!("hng-logs-{}", prefix.trim_end_matches('_')));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    let launch = dir.join("launch.toml");
    std::fs::write(
        &launch,
        "system = \"logs\"\n\n[[module]]\nname = \"echoer\"\n\
         command = [\"/bin/sh\", \"-c\", \"echo to-stdout; echo to-stderr >&2; exec sleep 1000\"]\n",
    )
    .expect("launch file");
    let run_dir = dir.join("run");
    let mut args = vec!["run", "--no-rm", "--no-gui"];
    args.extend_from_slice(extra);
    let launch = launch.to_string_lossy().into_owned();
    args.push(&launch);
    let child = Command::new(HNG)
        .args(&args)
        .env("HNG_PREFIX", &prefix)
        .env("HNG_RUN_DIR", &run_dir)
        .env_remove("HNG_LOG")
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("hng run");
    // The module's two lines reach its file through the supervisor's pipe thread.
    let file = run_dir.join("logs").join("echoer.log");
    let read = || std::fs::read_to_string(&file).unwrap_or_default();
    crate::common::poll_until(
        Duration::from_secs(30),
        Duration::from_millis(10),
        || {
            let text = read();
            text.contains("to-stdout") && text.contains("to-stderr")
        },
        || {
            format!(
                "the module's lines never reached {}: {:?}",
                file.display(),
                read()
            )
        },
    );
    let stop = hng(&prefix, &run_dir, &["stop"]);
    assert!(
        stop.status.success(),
        "hng stop: {}",
        String::from_utf8_lossy(&stop.stderr)
    );
    let out = child.wait_with_output().expect("hng run ends");
    assert!(out.status.success(), "hng run: {out:?}");
    assert!(
        shm::prefix_files(&prefix).is_empty(),
        "files left in /dev/shm"
    );
    (prefix, dir, out)
}

#[test]
fn module_output_goes_to_log_files_that_hng_logs_shows_and_the_terminal_stays_quiet() {
    let (prefix, dir, out) = run_echoer("logsquiet", &[]);
    let run_dir = dir.join("run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stderr.trim().is_empty(), "stderr is quiet: {stderr}");
    assert!(
        !stdout.contains("to-stdout") && !stdout.contains("INFO"),
        "stdout has no module or log lines: {stdout}"
    );
    let shown = hng(&prefix, &run_dir, &["logs", "echoer"]);
    assert!(shown.status.success(), "{shown:?}");
    let text = String::from_utf8_lossy(&shown.stdout);
    assert!(
        text.contains("to-stdout") && text.contains("to-stderr"),
        "{text}"
    );
    let last = hng(&prefix, &run_dir, &["logs", "echoer", "-n", "1"]);
    assert_eq!(String::from_utf8_lossy(&last.stdout).lines().count(), 1);
    // The supervisor's own log holds what the terminal did not show.
    let own = hng(&prefix, &run_dir, &["logs", "hng"]);
    let own = String::from_utf8_lossy(&own.stdout);
    assert!(own.contains("echoer: started"), "{own}");
    let list = hng(&prefix, &run_dir, &["logs"]);
    let list = String::from_utf8_lossy(&list.stdout);
    assert!(list.contains("echoer") && list.contains("hng"), "{list}");
    let missing = hng(&prefix, &run_dir, &["logs", "nosuch"]);
    assert!(!missing.status.success());
    assert!(
        String::from_utf8_lossy(&missing.stderr).contains("nosuch"),
        "{missing:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn verbose_runs_echo_module_lines_with_their_name() {
    let (_, dir, out) = run_echoer("logsverbose", &["-v"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("[echoer] to-stdout") && stderr.contains("[echoer] to-stderr"),
        "{stderr}"
    );
    assert!(stderr.contains("echoer: started"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}
