//! `hng eval planner|slam`: the real binary on the MovingAI data and the CARMEN logs kept in
//! `tests/data/` (always present), and its error messages on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Test data kept in the repository (`tests/data`): never skipped.
fn repo_data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(rel)
}

fn hng(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hng"))
        .args(args)
        .env("HNG_LOG", "warn")
        .output()
        .expect("run hng")
}

/// A file `name` holding `text` in a new scratch directory (removed when the directory
/// is dropped).
fn scratch_file(name: &str, text: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("scratch dir");
    let path = dir.path().join(name);
    std::fs::write(&path, text).expect("write the scratch file");
    (dir, path)
}

fn json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "hng failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

fn f(v: &serde_json::Value, k: &str) -> f64 {
    v[k].as_f64()
        .unwrap_or_else(|| panic!("field {k} missing in {v}"))
}

#[test]
fn eval_planner_finds_every_optimal_length_on_arena() {
    let (map, scen) = (
        repo_data("movingai/arena.map"),
        repo_data("movingai/arena.map.scen"),
    );
    let (map, scen) = (map.to_string_lossy(), scen.to_string_lossy());
    let v = json(&hng(&["eval", "planner", &map, &scen, "--json"]));
    assert_eq!(v["problems"], 160, "{v}");
    assert_eq!(v["mismatches"], 0, "{v}");
    assert!(f(&v, "mean_us") > 0.0);
    let text = hng(&["eval", "planner", &map, &scen]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.lines()
            .any(|l| l.starts_with("mismatches") && l.ends_with(" 0")),
        "{text}"
    );
}

#[test]
fn eval_planner_errors_name_file_line_and_field() {
    let map = repo_data("movingai/arena.map");
    let (_dir, scen) = scratch_file(
        "bad.scen",
        "version 1\n0\tarena.map\t49\t49\t1\t11\t1\t12\t1\n0\tarena.map\t49\t49\t1\tx\t1\t12\t1\n",
    );
    let out = hng(&[
        "eval",
        "planner",
        &map.to_string_lossy(),
        &scen.to_string_lossy(),
        "--json",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.scen:3"), "names the line: {err}");
    assert!(err.contains("field"), "names the field: {err}");
}

fn carmen(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/carmen")
        .join(name)
}

#[test]
fn eval_slam_errors_name_the_file_and_line() {
    let out = hng(&["eval", "slam", "/nonexistent/log.clf", "--json"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/log.clf"));
    let (_dir, log) = scratch_file(
        "short.log",
        "ODOM 0 0 0 0 0 0 1 h 1\nFLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 2 h 2\nFLASER 3 1.0 2.0\n",
    );
    let out = hng(&["eval", "slam", &log.to_string_lossy()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("short.log:3: FLASER field `range[2]`: missing (line too short)"),
        "{err}"
    );
    let empty = tempfile::tempdir().expect("scratch dir");
    let out = hng(&["eval", "slam", "--all", &empty.path().to_string_lossy()]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no .log or .clf files"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn eval_slam_reports_relative_and_absolute_errors_and_writes_the_map() {
    let log = carmen("seattle-corrected.log");
    let dir = tempfile::tempdir().expect("scratch dir");
    let yaml = dir.path().join("seattle.yaml");
    let v = json(&hng(&[
        "eval",
        "slam",
        &log.to_string_lossy(),
        "--json",
        "--map-out",
        &yaml.to_string_lossy(),
    ]));
    assert_eq!(v["scans"], 241, "{v}");
    assert_eq!(v["beams"], 361, "{v}");
    assert!(f(&v, "trans_err_mean_m") <= 0.03, "{v}");
    assert!(f(&v, "rot_err_mean_deg") <= 0.5, "{v}");
    assert!(
        f(&v, "trans_err_mean_m") < f(&v, "odom_trans_err_mean_m"),
        "{v}"
    );
    assert!(f(&v, "ate_rmse_m") < f(&v, "odom_ate_rmse_m"), "{v}");
    assert!(f(&v, "ate_front_end_rmse_m") > 0.0, "{v}");
    assert!(f(&v, "scans_per_s") > 0.0, "{v}");
    assert!(f(&v, "trans_err_p95_m") >= f(&v, "trans_err_mean_m") * 0.5);
    let y = std::fs::read_to_string(&yaml).expect("map yaml written");
    assert!(
        y.contains("image: seattle.pgm") && y.contains("resolution"),
        "{y}"
    );
    let pgm = std::fs::read(dir.path().join("seattle.pgm")).expect("map pgm written");
    assert!(pgm.starts_with(b"P5"));
}

#[test]
fn eval_slam_all_evaluates_every_log_in_a_folder() {
    let dir = tempfile::tempdir().expect("scratch dir");
    // Two geometries (180 and 361 beams) from the two quickest logs: every log's accuracy is
    // real_data's subject; this test's is the folder form.
    for name in ["aces-corrected.log", "seattle-corrected.log"] {
        std::fs::copy(carmen(name), dir.path().join(name)).expect("copy log");
    }
    std::fs::write(dir.path().join("notes.txt"), "not a log").expect("write");
    let rows = crate::common::json_lines(&hng(&[
        "eval",
        "slam",
        "--all",
        &dir.path().to_string_lossy(),
        "--json",
        "--no-loop-closure",
    ]));
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[0]["beams"], 180);
    assert_eq!(rows[1]["beams"], 361);
    for r in &rows {
        assert!(
            f(r, "trans_err_mean_m") < f(r, "odom_trans_err_mean_m"),
            "{r}"
        );
        assert_eq!(r["loop_closures"], 0, "{r}");
    }
    let table = hng(&[
        "eval",
        "slam",
        "--all",
        &dir.path().to_string_lossy(),
        "--no-loop-closure",
    ]);
    let text = String::from_utf8_lossy(&table.stdout);
    assert!(text.lines().count() == 3, "header and two rows: {text}");
    assert!(text.contains("seattle-corrected.log"), "{text}");
}
