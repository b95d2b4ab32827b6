//! `hng eval nav`: the closed loop (planning, servo, security, localisation, the robot in the
//! simulator: `hng run`, every module its own process, in lockstep) on many start/goal
//! problems: the consecutive problems of one world on one running system ([`reuse`]: the
//! robot moved to each start), or with `--fresh` one system per problem ([`runner`]). One
//! JSON line per problem and a summary (see docs/navigation.md).
//!
//! Inputs: a MovingAI map and scenario (`--map M --scen S --resolution R`), a map_server world
//! and a problem list (`--world W --problems P`), or generated worlds (`--generate N --seed S
//! [--clutter D]`).

mod problems;
mod reuse;
mod runner;
mod stop;

use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::PathBuf;

use anyhow::{Context as _, Result, bail};
use clap::Args;
use serde_json::json;

use runner::{ProblemResult, RunOptions};

/// Options of `hng eval nav`.
#[derive(Debug, Args)]
pub struct EvalNavArgs {
    /// A MovingAI `.map` (with `--scen`).
    #[arg(long, requires = "scen", conflicts_with_all = ["world", "generate"])]
    pub map: Option<PathBuf>,
    /// The MovingAI `.scen` of `--map`.
    #[arg(long, requires = "map")]
    pub scen: Option<PathBuf>,
    /// Metres per MovingAI cell.
    #[arg(long, default_value_t = 1.0)]
    pub resolution: f64,
    /// A map_server world (with `--problems`).
    #[arg(long, requires = "problems", conflicts_with = "generate")]
    pub world: Option<PathBuf>,
    /// Problem list of `--world`: `start_x start_y goal_x goal_y [start_theta]` per line.
    #[arg(long, requires = "world")]
    pub problems: Option<PathBuf>,
    /// Generate this many worlds (one problem each).
    #[arg(long)]
    pub generate: Option<usize>,
    /// Seed of the generated worlds (and of the simulator's noise, unless `--sim-seed`).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Clutter of the generated worlds: fraction of the rooms' floor covered by boxes.
    #[arg(long, default_value_t = 0.04)]
    pub clutter: f64,
    /// Shortest straight-line distance between start and goal in generated worlds, m.
    #[arg(long, default_value_t = 5.0)]
    pub min_distance: f64,
    /// Skip the first N problems.
    #[arg(long, default_value_t = 0)]
    pub offset: usize,
    /// Run at most N problems.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Take every K-th problem (a spread sample of a long scenario).
    #[arg(long, default_value_t = 1)]
    pub every: usize,
    /// Simulation speed of each run (`max`: lockstep as fast as the modules go).
    #[arg(long, default_value = "max")]
    pub speed: String,
    /// Goal tolerance, m (the true pose must be within it).
    #[arg(long, default_value_t = 0.5)]
    pub tolerance: f64,
    /// Simulated time allowed per problem: this many seconds plus `--time-per-m` per metre
    /// of the optimum.
    #[arg(long, default_value_t = 40.0)]
    pub time_base: f64,
    /// Simulated seconds allowed per metre of the optimum.
    #[arg(long, default_value_t = 5.0)]
    pub time_per_m: f64,
    /// Noise seed of the simulator (default: `--seed`).
    #[arg(long)]
    pub sim_seed: Option<u64>,
    /// Folder for worlds and run directories (default: a temporary one, removed).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Keep every problem's run directory (failed ones are always kept under `--dir`).
    #[arg(long)]
    pub keep: bool,
    /// One JSON object per problem, then one summary object (`"summary": true`).
    #[arg(long)]
    pub json: bool,
    /// Also append the JSON lines to this file as problems finish.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// One fresh system per problem (`hng run` started and stopped for each), instead of
    /// consecutive problems of one world on one running system.
    #[arg(long)]
    pub fresh: bool,
}

/// Mean of some values (`None` if empty).
fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The summary of an evaluation as JSON.
pub fn summary(results: &[ProblemResult]) -> serde_json::Value {
    let n = results.len();
    let ok: Vec<&ProblemResult> = results.iter().filter(|r| r.success).collect();
    let ratios: Vec<f64> = ok.iter().filter_map(|r| r.path_ratio).collect();
    let clear: Vec<f64> = results.iter().filter_map(|r| r.min_clearance_m).collect();
    let worst = clear.iter().copied().fold(f64::INFINITY, f64::min);
    // Clearance where the map allows: the problems whose map leaves at least `want` on some
    // path, and how many of them kept it.
    let want = 0.25;
    let roomy: Vec<&ProblemResult> = results
        .iter()
        .filter(|r| r.problem.clearance_available_m.is_some_and(|a| a >= want))
        .collect();
    let kept = roomy
        .iter()
        .filter(|r| r.min_clearance_m.is_some_and(|c| c >= want))
        .count();
    // The planner's share: the same for the path Planning plans on the true map.
    let plan_kept = roomy
        .iter()
        .filter(|r| r.problem.plan_clearance_m.is_some_and(|c| c >= want))
        .count();
    let plan_worst = results
        .iter()
        .filter_map(|r| r.problem.plan_clearance_m)
        .fold(f64::INFINITY, f64::min);
    let walls: Vec<f64> = results.iter().map(|r| r.wall_s).collect();
    let sim: f64 = results.iter().map(|r| r.time_s).sum();
    // Wall time per metre of the optimum (start-up and shut-down included), over the problems
    // with an optimum: the benchmark's "one 30 m problem" is 30 times it.
    let (wall_opt, metres) = results
        .iter()
        .filter_map(|r| r.problem.optimum_m.map(|m| (r.wall_s, m)))
        .fold((0.0, 0.0), |(w, m), (rw, rm)| (w + rw, m + rm));
    let wall_per_m = (metres > 0.0).then(|| wall_opt / metres);
    let mut cpu: BTreeMap<String, f64> = BTreeMap::new();
    for r in results {
        for (k, v) in &r.cpu_s {
            *cpu.entry(k.clone()).or_default() += v;
        }
    }
    let cpu_per_sim_s: BTreeMap<String, f64> = cpu
        .iter()
        .map(|(k, v)| (k.clone(), if sim > 0.0 { v / sim } else { 0.0 }))
        .collect();
    let mut reasons: BTreeMap<String, usize> = BTreeMap::new();
    for r in results.iter().filter(|r| !r.success) {
        let why = r.reason.clone().unwrap_or_default();
        // Group by the reason's first clause.
        let key: String = why.split([':', ';']).next().unwrap_or("").trim().to_owned();
        *reasons.entry(key).or_default() += 1;
    }
    json!({
        "summary": true,
        "problems": n,
        "successes": ok.len(),
        "success_rate": if n > 0 { ok.len() as f64 / n as f64 } else { 0.0 },
        "collisions": results.iter().map(|r| r.collisions).sum::<u64>(),
        "problems_with_collision": results.iter().filter(|r| r.collisions > 0).count(),
        "mean_path_ratio": mean(&ratios),
        "max_path_ratio": ratios.iter().copied().reduce(f64::max),
        "worst_clearance_m": worst.is_finite().then_some(worst),
        "mean_min_clearance_m": mean(&clear),
        "roomy_problems": roomy.len(),
        "roomy_problems_keeping_0_25_m": kept,
        "roomy_problems_whose_plan_keeps_0_25_m": plan_kept,
        "worst_plan_clearance_m": plan_worst.is_finite().then_some(plan_worst),
        "stuck_time_s": results.iter().map(|r| r.stuck_time_s).sum::<f64>(),
        "stalls": results.iter().map(|r| r.stalls).sum::<u64>(),
        "recoveries": results.iter().map(|r| r.recoveries).sum::<u64>(),
        "true_poses_lost": results.iter().map(|r| r.true_poses_lost).sum::<u64>(),
        "sim_time_s": sim,
        "wall_s_total": walls.iter().sum::<f64>(),
        "wall_s_mean": mean(&walls),
        "wall_s_max": walls.iter().copied().reduce(f64::max),
        "wall_s_per_m": wall_per_m,
        "wall_s_per_30_m": wall_per_m.map(|w| 30.0 * w),
        "wall_s_per_sim_s": (sim > 0.0).then(|| walls.iter().sum::<f64>() / sim),
        "cpu_s": cpu,
        "cpu_s_per_sim_s": cpu_per_sim_s,
        "failures": reasons,
    })
}

fn print_table(results: &[ProblemResult], s: &serde_json::Value) {
    println!(
        "{:>4} {:<24} {:>7} {:>7} {:>6} {:>7} {:>7} {:>6} {:>6} {:>4}  result",
        "#", "source", "opt m", "path m", "ratio", "clear m", "plan m", "sim s", "wall s", "rec"
    );
    for r in results {
        let p = &r.problem;
        println!(
            "{:>4} {:<24} {:>7.2} {:>7.2} {:>6} {:>7} {:>7} {:>6.1} {:>6.1} {:>4}  {}",
            p.id,
            p.source.chars().take(24).collect::<String>(),
            p.optimum_m.unwrap_or(f64::NAN),
            r.path_length_m,
            r.path_ratio.map_or("-".into(), |x| format!("{x:.3}")),
            r.min_clearance_m.map_or("-".into(), |x| format!("{x:.3}")),
            p.plan_clearance_m.map_or("-".into(), |x| format!("{x:.3}")),
            r.time_s,
            r.wall_s,
            r.recoveries,
            if r.success {
                "ok".to_owned()
            } else {
                format!("FAILED: {}", r.reason.as_deref().unwrap_or(""))
            }
        );
    }
    let f = |k: &str| s[k].as_f64().map_or("-".into(), |x| format!("{x:.3}"));
    println!(
        "success {}/{} ({}), collisions {}, mean path ratio {}, worst clearance {} m, \
         roomy problems keeping 0.25 m: {}/{} (their plans: {}/{}), recoveries {}, wall time mean {} s ({} s per m, {} s per 30 m)",
        s["successes"],
        s["problems"],
        f("success_rate"),
        s["collisions"],
        f("mean_path_ratio"),
        f("worst_clearance_m"),
        s["roomy_problems_keeping_0_25_m"],
        s["roomy_problems"],
        s["roomy_problems_whose_plan_keeps_0_25_m"],
        s["roomy_problems"],
        s["recoveries"],
        f("wall_s_mean"),
        f("wall_s_per_m"),
        f("wall_s_per_30_m"),
    );
    println!("cpu s per simulated s: {}", s["cpu_s_per_sim_s"]);
    if let Some(m) = s["failures"].as_object()
        && !m.is_empty()
    {
        println!("failures by reason: {}", s["failures"]);
    }
}

/// `hng eval nav`.
pub fn run(a: &EvalNavArgs) -> Result<()> {
    hng_supervisor::mission::parse_speed(&a.speed).map_err(anyhow::Error::msg)?;
    if !(a.tolerance.is_finite() && a.tolerance > 0.0) {
        bail!(
            "--tolerance must be a positive distance, got {}",
            a.tolerance
        );
    }
    let temp = a.dir.is_none();
    let dir = match &a.dir {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("hng-eval-nav-{}", std::process::id())),
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut list = if let (Some(map), Some(scen)) = (&a.map, &a.scen) {
        problems::movingai(map, scen, a.resolution, &dir, 0, None)?
    } else if let (Some(world), Some(p)) = (&a.world, &a.problems) {
        problems::listed(world, p)?
    } else if let Some(n) = a.generate {
        let cfg = hng_simulator::generate::GenConfig {
            clutter: a.clutter,
            ..Default::default()
        };
        problems::generated(n, a.seed, &cfg, a.min_distance, &dir)?
    } else {
        bail!("give --map and --scen, --world and --problems, or --generate N");
    };
    let every = a.every.max(1);
    list = list
        .into_iter()
        .skip(a.offset)
        .step_by(every)
        .take(a.limit.unwrap_or(usize::MAX))
        .collect();
    let opts = RunOptions {
        exe: std::env::current_exe().context("finding the hng executable")?,
        speed: a.speed.clone(),
        tolerance_m: a.tolerance,
        duration_base_s: a.time_base,
        duration_per_m_s: a.time_per_m,
        seed: Some(a.sim_seed.unwrap_or(a.seed)),
        dir: dir.join("runs"),
        keep: a.keep,
    };
    let mut out = match &a.out {
        Some(p) => Some(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .with_context(|| format!("opening {}", p.display()))?,
        ),
        None => None,
    };
    if let Err(e) = stop::install() {
        eprintln!("hng eval nav: warning: termination signals not handled ({e})");
    }
    let mut results = Vec::new();
    let mut stopped = None;
    let total = list.len();
    let mut emit = |r: ProblemResult| -> Result<()> {
        let line = serde_json::to_string(&r)?;
        if a.json {
            println!("{line}");
        } else {
            eprintln!(
                "problem {}/{} {}: {} ({:.1} s wall)",
                r.problem.id,
                total,
                r.problem.source,
                if r.success {
                    "ok".to_owned()
                } else {
                    format!("FAILED: {}", r.reason.as_deref().unwrap_or(""))
                },
                r.wall_s
            );
        }
        if let Some(f) = &mut out {
            writeln!(f, "{line}")?;
        }
        results.push(r);
        Ok(())
    };
    // Runs of finished problems (or worlds) still stopping; at most two at a time.
    let mut stopping: Vec<runner::Stopping> = Vec::new();
    let mut i = 0;
    while i < list.len() {
        stopping.retain_mut(|s| !s.poll());
        while stopping.len() >= 2 {
            stopping.remove(0).wait();
        }
        if a.fresh {
            let p = &list[i];
            let (r, still) = runner::run(p, &opts)?;
            stopping.extend(still);
            if let Some(sig) = stop::requested() {
                // Stopped by a signal: the interrupted problem is not a result.
                stopped = Some((sig, p.id));
                break;
            }
            emit(r)?;
            i += 1;
            continue;
        }
        // The consecutive problems of this world, on one system.
        let world = &list[i].world;
        let n = list[i..].iter().take_while(|p| &p.world == world).count();
        let end = reuse::run_world(&list[i..i + n], &opts, &mut emit)?;
        stopping.extend(end.stopping);
        i += end.done;
        if let Some(sig) = end.signal.or_else(stop::requested) {
            stopped = Some((sig, list.get(i).map_or(0, |p| p.id)));
            break;
        }
    }
    if let Some((sig, id)) = stopped {
        eprintln!(
            "hng eval nav: stopped by signal {sig} during problem {id}; {} problem(s) done",
            results.len()
        );
    }
    let stopped = stopped.map(|(sig, _)| sig);
    for s in stopping {
        s.wait();
    }
    let s = summary(&results);
    if a.json {
        println!("{s}");
    } else {
        print_table(&results, &s);
    }
    if let Some(f) = &mut out {
        writeln!(f, "{s}")?;
    }
    if let Some(sig) = stopped {
        eprintln!("worlds and runs kept in {}", dir.display());
        std::process::exit(128 + sig);
    }
    let failed = results.iter().any(|r| !r.success);
    if temp && !failed && !a.keep {
        let _ = std::fs::remove_dir_all(&dir);
    } else {
        eprintln!("worlds and runs kept in {}", dir.display());
    }
    Ok(())
}
