//! A miniature `hng run`: load a launch file, supervise it for N seconds,
//! print events and a final `hng ps`-style status, then stop in order.
//!
//! `cargo run -p hng-watchdog --example run -- <launch.toml> [seconds]`

use std::process::ExitCode;
use std::time::{Duration, Instant};

use hng_watchdog::systemd::SdNotify;
use hng_watchdog::{LoadOptions, Supervisor, SupervisorOptions, launch};

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let Some(file) = args.next() else {
        eprintln!("usage: run <launch.toml> [seconds]");
        return ExitCode::from(2);
    };
    let secs: u64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(3);
    let plan = match launch::load(file.as_ref(), &LoadOptions::default()) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(1);
        }
    };
    for w in &plan.warnings {
        eprintln!("warning: {w}");
    }
    let mut opts = SupervisorOptions::default();
    opts.env
        .insert("HNG_PREFIX".into(), format!("hng_{}_", plan.system));
    let mut sup = match Supervisor::new(plan.modules, opts) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(1);
        }
    };
    let mut sd = SdNotify::from_env();
    sup.start_all();
    sd.ready();
    let t0 = Instant::now();
    let end = t0 + Duration::from_secs(secs);
    while Instant::now() < end {
        let now = Instant::now();
        let mut timeout = end.saturating_duration_since(now);
        if let Some(ping) = sd.next_ping_in(now) {
            timeout = timeout.min(ping);
        }
        match sup.poll(timeout) {
            Ok(events) => {
                for e in events {
                    println!("[{:>8.3}] {e}", (e.at - t0).as_secs_f64());
                }
            }
            Err(e) => {
                eprintln!("{e}");
                break;
            }
        }
        sd.ping_if_due(Instant::now());
    }
    match serde_json::to_string_pretty(&sup.status(Instant::now())) {
        Ok(json) => println!("{json}"),
        Err(e) => eprintln!("status: {e}"),
    }
    sd.stopping();
    match sup.shutdown() {
        Ok(events) => {
            for e in events {
                println!("[{:>8.3}] {e}", (e.at - t0).as_secs_f64());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::from(1)
        }
    }
}
