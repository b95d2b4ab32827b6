//! `hng eval`: measure the modules' algorithms on recorded data (paper: modules evaluated on
//! recorded inputs).
//!
//! - `hng eval planner MAP SCEN`: Planning's A* on a MovingAI map and scenario; prints
//!   `problems`, `mismatches` (lengths differing from the optimal ones) and `mean_us` (time
//!   per problem), plus `max_abs_err` and `mean_expanded`.
//! - `hng eval slam LOG [--map OUT.yaml]`: SLAM's scan matching over a CARMEN log against its
//!   corrected poses; prints `scans`, `trans_err_mean_m`, `trans_err_p95_m`,
//!   `rot_err_mean_deg`, `rot_err_p95_deg` and more; `--map` writes the built map as a
//!   map_server PGM + YAML pair.
//!
//! `--json` prints one JSON object; otherwise one `name value` line per field. Errors name the
//! file, line and field.

use std::path::PathBuf;

use anyhow::{Context as _, Result};
use clap::Subcommand;
use hng_modules::planning::eval_movingai;
use hng_modules::slam::eval_slam;
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
    /// SLAM's scan matching over a CARMEN log, against the log's corrected poses.
    Slam {
        /// The CARMEN log (ODOM and FLASER lines).
        log: PathBuf,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
        /// Write the built map: OUT.yaml and OUT.pgm (map_server format).
        #[arg(long, value_name = "OUT.yaml")]
        map: Option<PathBuf>,
    },
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
        EvalCommand::Slam { log, json, map } => {
            let e = eval_slam(&log, map.as_deref()).context("SLAM evaluation failed")?;
            let mut fields = object(json!({
                "scans": e.scans,
                "trans_err_mean_m": e.trans_err_mean_m,
                "trans_err_p95_m": e.trans_err_p95_m,
                "rot_err_mean_deg": e.rot_err_mean_deg,
                "rot_err_p95_deg": e.rot_err_p95_deg,
                "trans_err_max_m": e.trans_err_max_m,
                "rot_err_max_deg": e.rot_err_max_deg,
                "odom_trans_err_mean_m": e.odom_trans_err_mean_m,
                "odom_rot_err_mean_deg": e.odom_rot_err_mean_deg,
                "fallbacks": e.fallbacks,
                "mean_quality": e.mean_quality,
                "mean_us_per_scan": e.mean_us_per_scan,
            }));
            if let Some(m) = &map {
                fields.insert(
                    "map_yaml".into(),
                    m.with_extension("yaml").display().to_string().into(),
                );
                fields.insert(
                    "map_pgm".into(),
                    m.with_extension("pgm").display().to_string().into(),
                );
            }
            print(fields, json);
            Ok(())
        }
    }
}
