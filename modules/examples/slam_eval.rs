//! Runs the SLAM evaluation on CARMEN logs (files, or every log of a folder) and prints one
//! line of figures per log (`-v`: every field).
//!
//! `cargo run --release -p hng-modules --example slam_eval -- [-v] <log|dir>...`
//!
//! Parameters to try, from the environment (defaults otherwise): `LOCAL` (local-map scans),
//! `MATCH_RANGE` (m), `CANDS` (wide-search candidates refined), `WIDE_BELOW` (score under
//! which the wide search runs), `FREE` (free-space penalty), `UNKNOWN` (score of a point in never-observed
//! space when ranking matches; `off`: plain score), `UNKNOWN_FLOOR` (1: also in the coarse search's field), `FOV` (degrees, `FLASER` field of view), `LOOP_MIN_SCORE` (closure
//! acceptance), `NO_LC` (1: front end alone).

use std::path::PathBuf;

use hng_modules::slam::{EvalOptions, eval_slam_with, logs_in};

fn env<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut verbose = false;
    let mut logs: Vec<PathBuf> = Vec::new();
    for a in std::env::args().skip(1) {
        if a == "-v" {
            verbose = true;
            continue;
        }
        let p = PathBuf::from(a);
        if p.is_dir() {
            logs.extend(logs_in(&p)?);
        } else {
            logs.push(p);
        }
    }
    if logs.is_empty() {
        return Err("usage: slam_eval [-v] <log|dir>...".into());
    }
    let mut opts = EvalOptions::default();
    if let Some(n) = env("LOCAL") {
        opts.slam.local_map_scans = n;
    }
    if let Some(r) = env("MATCH_RANGE") {
        opts.slam.match_max_range = r;
    }
    if let Some(c) = env("CANDS") {
        opts.slam.wide.candidates = c;
    }
    if let Some(f) = env("FREE") {
        opts.slam.free_space_penalty = f;
    }
    if let Some(f) = env::<u8>("UNKNOWN_FLOOR") {
        opts.slam.wide.unknown_floor = f == 1;
    }
    if let Some(u) = env("UNKNOWN") {
        opts.slam.unknown_score = Some(u);
    } else if std::env::var("UNKNOWN").is_ok_and(|v| v == "off") {
        opts.slam.unknown_score = None;
    }
    if let Some(w) = env("WIDE_BELOW") {
        opts.slam.wide_below_score = w;
    }
    if let Some(d) = env::<f64>("FOV") {
        opts.log.fov = Some(d.to_radians());
    }
    if let Some(m) = env("LOOP_MIN_SCORE") {
        opts.backend.loop_min_score = m;
    }
    if env::<u8>("NO_LC") == Some(1) {
        opts.backend.loop_closure = false;
    }
    for log in logs {
        let e = eval_slam_with(&log, &opts)?;
        if verbose {
            println!("{e:#?}");
        }
        let name = log.file_name().unwrap_or_default().to_string_lossy();
        println!("{name:<28} {}", e.summary());
    }
    Ok(())
}
