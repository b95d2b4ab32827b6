//! Runs the SLAM evaluation on a CARMEN log and prints the figures.
//!
//! `cargo run --release -p hng-modules --example slam_eval -- <log> [map_base] [local_scans]`

use std::path::PathBuf;

use hng_modules::slam::{SlamConfig, eval_slam_with};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let log = PathBuf::from(
        args.next()
            .ok_or("usage: slam_eval <log> [map_base] [local_scans]")?,
    );
    let out = args.next().filter(|s| s != "-").map(PathBuf::from);
    let mut cfg = SlamConfig::default();
    if let Some(n) = args.next() {
        cfg.local_map_scans = n.parse()?;
    }
    if let Some(d) = args.next() {
        cfg.laser.angle_min = d.parse::<f64>()?.to_radians();
    }
    let eval = eval_slam_with(&log, out.as_deref(), cfg)?;
    println!("{eval:#?}");
    Ok(())
}
