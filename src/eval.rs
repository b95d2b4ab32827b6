//! `hng eval`: measure the modules' algorithms on recorded data (paper: modules evaluated on
//! recorded inputs).
//!
//! - `hng eval planner MAP SCEN`: Planning's A* on a MovingAI map and scenario; prints
//!   `problems`, `mismatches` (lengths differing from the optimal ones) and `mean_us` (time
//!   per problem), plus `max_abs_err` and `mean_expanded`.
//! - `hng eval slam LOG [--map-out OUT.yaml] [--fov DEG] [--no-loop-closure]`: SLAM (front
//!   end and pose-graph back end) over a CARMEN log against its corrected poses; prints the
//!   per-scan relative error (`trans_err_mean_m`, `rot_err_mean_deg`, p95, max) beside
//!   odometry's (`odom_trans_err_mean_m`, `odom_rot_err_mean_deg`), the absolute trajectory
//!   error after alignment with loop closure (`ate_rmse_m`), without it
//!   (`ate_front_end_rmse_m`) and of odometry (`odom_ate_rmse_m`), `scans_per_s`,
//!   `realtime_factor` and more; `--map-out` writes the map as a map_server PGM + YAML pair.
//! - `hng eval slam --all DIR`: every `.log`/`.clf` file in DIR, one table row per log
//!   (`--map-out DIR2` writes `DIR2/<log>.pgm/.yaml`).
//!
//! `--json` prints one JSON object (one per line with `--all`); otherwise one `name value`
//! line per field, or a table. Errors name the file, line and field.

use std::path::PathBuf;

use anyhow::{Context as _, Result};
use clap::Subcommand;
use hng_modules::planning::eval_movingai;
use hng_modules::slam::{EvalOptions, SlamEval, eval_slam_with, logs_in};
use serde_json::{Map, Value, json};

#[derive(Debug, Subcommand)]
pub enum EvalCommand {
    /// Planning's A* on a MovingAI map and scenario file, against the optimal lengths.
    Planner {
        /// The `.map` file.
        map: PathBuf,
        /// The `.scen` file.
        scen: PathBuf,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// SLAM over a CARMEN log (or every log in a folder), against the log's corrected poses.
    Slam {
        /// The CARMEN log (ODOM and FLASER or ROBOTLASER1 lines).
        #[arg(required_unless_present = "all", conflicts_with = "all")]
        log: Option<PathBuf>,
        /// Evaluate every .log/.clf file in this folder, one table row each.
        #[arg(long, value_name = "DIR")]
        all: Option<PathBuf>,
        /// Print JSON: one object (one per line with --all).
        #[arg(long)]
        json: bool,
        /// Write the map: OUT.yaml and OUT.pgm (map_server format); with --all, a folder.
        #[arg(long, visible_alias = "map", value_name = "OUT.yaml")]
        map_out: Option<PathBuf>,
        /// Field of view of FLASER scans in degrees (default 180; see docs/slam.md).
        #[arg(long, value_name = "DEG")]
        fov: Option<f64>,
        /// The front end alone: no pose graph, no loop closure.
        #[arg(long)]
        no_loop_closure: bool,
    },
    /// The closed loop on many start/goal problems (MovingAI, a world and a problem list, or
    /// generated worlds): success, path, clearance, recoveries (docs/navigation.md).
    Nav(crate::eval_nav::EvalNavArgs),
    /// Compare the poses of two recordings (a run and a module replayed alone against it).
    Replay(crate::recording::EvalReplayArgs),
}

fn print(fields: Map<String, Value>, json: bool) {
    if json {
        println!("{}", Value::Object(fields));
    } else {
        let width = fields.keys().map(String::len).max().unwrap_or(0);
        for (k, v) in &fields {
            let v = match v {
                Value::Number(n) => match n.as_f64() {
                    Some(f) if !n.is_u64() && !n.is_i64() => format!("{f:.6}"),
                    _ => n.to_string(),
                },
                Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            println!("{k:<width$}  {v}");
        }
    }
}

fn object(v: Value) -> Map<String, Value> {
    match v {
        Value::Object(m) => m,
        _ => Map::new(),
    }
}

pub fn run(cmd: EvalCommand) -> Result<()> {
    match cmd {
        EvalCommand::Replay(args) => crate::recording::eval_replay(&args),
        EvalCommand::Nav(args) => crate::eval_nav::run(&args),
        EvalCommand::Planner { map, scen, json } => {
            let e = eval_movingai(&map, &scen).context("planner evaluation failed")?;
            print(
                object(json!({
                    "problems": e.problems,
                    "mismatches": e.mismatches,
                    "mean_us": e.mean_us,
                    "max_abs_err": e.max_abs_err,
                    "mean_expanded": e.mean_expanded,
                })),
                json,
            );
            Ok(())
        }
        EvalCommand::Slam {
            log,
            all,
            json,
            map_out,
            fov,
            no_loop_closure,
        } => {
            let mut opts = EvalOptions::default();
            if let Some(f) = fov {
                anyhow::ensure!(
                    f.is_finite() && f > 0.0 && f <= 360.0,
                    "--fov {f}: degrees in (0, 360]"
                );
                opts.log.fov = Some(f.to_radians());
            }
            opts.backend.loop_closure = !no_loop_closure;
            if let Some(dir) = all {
                let logs = logs_in(&dir).context("SLAM evaluation failed")?;
                if let Some(out) = &map_out {
                    std::fs::create_dir_all(out)
                        .with_context(|| format!("{}: cannot create", out.display()))?;
                }
                let mut rows = Vec::new();
                for l in logs {
                    let mut o = opts.clone();
                    o.map_out = map_out
                        .as_ref()
                        .and_then(|d| l.file_stem().map(|s| d.join(s).with_extension("yaml")));
                    let e = eval_slam_with(&l, &o).context("SLAM evaluation failed")?;
                    if json {
                        println!("{}", Value::Object(slam_fields(&e, o.map_out.as_deref())));
                    }
                    rows.push(e);
                }
                if !json {
                    print_table(&rows);
                }
                return Ok(());
            }
            let Some(log) = log else {
                anyhow::bail!("give a LOG or --all DIR");
            };
            opts.map_out = map_out;
            let e = eval_slam_with(&log, &opts).context("SLAM evaluation failed")?;
            print(slam_fields(&e, opts.map_out.as_deref()), json);
            Ok(())
        }
    }
}

fn slam_fields(e: &SlamEval, map: Option<&std::path::Path>) -> Map<String, Value> {
    let mut fields = object(json!({
        "log": e.log.display().to_string(),
        "scans": e.scans,
        "beams": e.beams,
        "skipped_lines": e.skipped_lines,
        "invalid_ranges": e.invalid_ranges,
        "trans_err_mean_m": e.trans_err_mean_m,
        "trans_err_p95_m": e.trans_err_p95_m,
        "rot_err_mean_deg": e.rot_err_mean_deg,
        "rot_err_p95_deg": e.rot_err_p95_deg,
        "trans_err_max_m": e.trans_err_max_m,
        "rot_err_max_deg": e.rot_err_max_deg,
        "front_end_trans_err_mean_m": finite(e.front_end_trans_err_mean_m),
        "front_end_rot_err_mean_deg": finite(e.front_end_rot_err_mean_deg),
        "odom_trans_err_mean_m": e.odom_trans_err_mean_m,
        "odom_rot_err_mean_deg": e.odom_rot_err_mean_deg,
        "ate_rmse_m": e.ate_rmse_m,
        "ate_front_end_rmse_m": finite(e.ate_front_end_rmse_m),
        "odom_ate_rmse_m": e.odom_ate_rmse_m,
        "fallbacks": e.fallbacks,
        "mean_quality": e.mean_quality,
        "nodes": e.nodes,
        "loop_closures": e.loop_closures,
        "loop_closures_tried": e.loop_closures_tried,
        "scans_per_s": e.scans_per_s,
        "front_end_scans_per_s": finite(e.front_end_scans_per_s),
        "log_duration_s": e.log_duration_s,
        "realtime_factor": finite(e.realtime_factor()),
    }));
    if let Some(m) = map {
        fields.insert(
            "map_yaml".into(),
            m.with_extension("yaml").display().to_string().into(),
        );
        fields.insert(
            "map_pgm".into(),
            m.with_extension("pgm").display().to_string().into(),
        );
    }
    fields
}

/// `null` in JSON for a figure that was not measured.
fn finite(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

fn print_table(rows: &[SlamEval]) {
    println!(
        "{:<28} {:>5} {:>5} | {:>23} {:>23} | {:>20} {:>8} | {:>8} {:>6}",
        "log",
        "beams",
        "scans",
        "rel cm slam/front/odo",
        "rel deg slam/front/odo",
        "ATE m lc/no-lc/odo",
        "closures",
        "scans/s",
        "x real"
    );
    for e in rows {
        let name = e
            .log
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        println!(
            "{:<28} {:>5} {:>5} | {:>7.2} {:>7.2} {:>7.2} {:>7.3} {:>7.3} {:>7.3} | {:>6.3} {:>6.3} {:>6.3} {:>8} | {:>8.1} {:>6.0}",
            name,
            e.beams,
            e.scans,
            e.trans_err_mean_m * 100.0,
            e.front_end_trans_err_mean_m * 100.0,
            e.odom_trans_err_mean_m * 100.0,
            e.rot_err_mean_deg,
            e.front_end_rot_err_mean_deg,
            e.odom_rot_err_mean_deg,
            e.ate_rmse_m,
            e.ate_front_end_rmse_m,
            e.odom_ate_rmse_m,
            e.loop_closures,
            e.scans_per_s,
            e.realtime_factor()
        );
    }
}
