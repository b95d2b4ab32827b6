//! Runs the SLAM evaluation on a CARMEN log and prints the figures.
//!
//! `cargo run --release -p hng-modules --example slam_eval -- <log> [map_base|-] [local_scans] [fov_deg]`

use std::path::PathBuf;

use hng_modules::slam::{EvalOptions, eval_slam_with};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let log = PathBuf::from(
        args.next()
            .ok_or("usage: slam_eval <log> [map_base|-] [local_scans] [fov_deg]")?,
    );
    let mut opts = EvalOptions {
        map_out: args.next().filter(|s| s != "-").map(PathBuf::from),
        ..EvalOptions::default()
    };
    if let Some(n) = args.next() {
        opts.slam.local_map_scans = n.parse()?;
    }
    if let Some(d) = args.next() {
        opts.log.fov = Some(d.parse::<f64>()?.to_radians());
    }
    let eval = eval_slam_with(&log, &opts)?;
    println!("{eval:#?}");
    Ok(())
}
