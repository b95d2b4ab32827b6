//! The problems of `hng eval nav`: start and goal in a world, with the grid optimum and the
//! clearance the map leaves along the way. From MovingAI maps and scenarios, from a
//! map_server world and a problem list, or from generated worlds.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result, bail};
use hng_modules::footprint::ROBOT_RADIUS_M;
use hng_modules::planning::movingai::{read_map, read_scen};
use hng_modules::planning::{
    Costmap, CostmapConfig, GridPlanner, NEIGHBOURS, OccupancyGrid, PlannerConfig, path_clearance,
};
use hng_modules::planning_module::{PlanningCore, PlanningParams};
use hng_runtime::msg::{Goal, Pose2D};
use hng_simulator::generate::{GenConfig, generate, world_seed};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// One navigation problem.
#[derive(Debug, Clone, Serialize)]
pub struct Problem {
    /// Number of the problem in this evaluation (from 1).
    pub id: usize,
    /// Where it comes from (`arena.map.scen:12`, `generated 7 (seed 1)`, `problems.txt:3`).
    pub source: String,
    /// The world, a map_server YAML.
    #[serde(skip)]
    pub world: PathBuf,
    /// Start pose x, y, theta.
    pub start: [f64; 3],
    /// Goal x, y.
    pub goal: [f64; 2],
    /// The grid optimum, m: the scenario's for MovingAI (8-connected, point robot), else the
    /// shortest 8-connected path of the robot's footprint (lethal band) on the 0.1 m grid.
    pub optimum_m: Option<f64>,
    /// The widest clearance the map leaves on any path from start to goal (the robot's gap to
    /// obstacles at the narrowest place of the roomiest path, start and goal included), m.
    pub clearance_available_m: Option<f64>,
    /// The robot's gap to obstacles along the path Planning plans from start to goal on this
    /// map (its default parameters; the true map), m: the planner's share of the clearance,
    /// apart from how the Servo then drives it. `None` if it plans no path.
    pub plan_clearance_m: Option<f64>,
}

/// Planning's own path on a map, judged for its clearance (see
/// [`Problem::plan_clearance_m`]).
struct PlanJudge {
    core: PlanningCore,
    grid: OccupancyGrid,
    goals: u32,
}

impl PlanJudge {
    fn new(grid: &OccupancyGrid) -> PlanJudge {
        let mut core = PlanningCore::new(PlanningParams::default());
        core.set_map(grid);
        PlanJudge {
            core,
            grid: grid.clone(),
            goals: 0,
        }
    }

    /// The robot's gap along the path planned from `start` to `goal`, m.
    fn gap(&mut self, start: [f64; 2], goal: [f64; 2], tolerance_m: f64) -> Option<f64> {
        self.goals += 1;
        self.core.set_goal(Goal {
            id: self.goals,
            pose: Pose2D::new(goal[0], goal[1], 0.0),
            tolerance_m,
            ..Goal::default()
        });
        self.core.update(&Pose2D::new(start[0], start[1], 0.0));
        if !self.core.has_path() {
            return None;
        }
        let d = path_clearance(&self.grid, self.core.path_points(), 50, 5.0);
        Some(d.min(5.0) - ROBOT_RADIUS_M)
    }
}

/// Goal tolerance of the plans judged for their clearance, m (`hng run`'s default goal).
const PLAN_TOLERANCE_M: f64 = 0.3;

/// The costmap used to judge problems (the planner's own, default footprint).
fn costmap(grid: &OccupancyGrid) -> Costmap {
    Costmap::build(grid, &CostmapConfig::default())
}

/// The bottleneck clearance of the widest path between two cells of `c` (maximin over
/// 8-connected paths of the cells' distance to obstacles), as the robot's gap: minus its
/// radius. `None` if not connected through cells of positive clearance.
pub fn available_clearance(c: &Costmap, s: (i64, i64), g: (i64, i64)) -> Option<f64> {
    use std::collections::BinaryHeap;
    let grid = c.grid();
    let w = i64::from(grid.width());
    let si = grid.index(s.0, s.1)?;
    let gi = grid.index(g.0, g.1)?;
    let n = grid.data().len();
    let mut best = vec![f64::NEG_INFINITY; n];
    let clear = |i: usize| c.clearance(i as i64 % w, i as i64 / w).unwrap_or(0.0);
    // (bottleneck so far, cell), widest first. Clearances are finite or +inf; keep order by
    // the bits of non-negative floats.
    let key = |v: f64| v.clamp(0.0, 1e9).to_bits();
    let mut heap = BinaryHeap::new();
    best[si] = clear(si);
    heap.push((key(best[si]), si));
    while let Some((k, i)) = heap.pop() {
        if k != key(best[i]) {
            continue;
        }
        if i == gi {
            let v = best[i].min(1e9);
            return (v > 0.0).then_some(v - ROBOT_RADIUS_M);
        }
        let (x, y) = (i as i64 % w, i as i64 / w);
        for (dx, dy) in NEIGHBOURS {
            let Some(j) = grid.index(x + dx, y + dy) else {
                continue;
            };
            let b = best[i].min(clear(j));
            if b > best[j] && b > 0.0 {
                best[j] = b;
                heap.push((key(b), j));
            }
        }
    }
    None
}

/// Optimum (footprint, plain 8-connected) and available clearance of a problem in `c`.
fn judge(c: &Costmap, start: [f64; 2], goal: [f64; 2]) -> (Option<f64>, Option<f64>) {
    let g = c.grid();
    let s = g.world_to_cell(start[0], start[1]);
    let e = g.world_to_cell(goal[0], goal[1]);
    let mut p = GridPlanner::new(PlannerConfig::default());
    let opt = p
        .plan_cells(g, s, e)
        .ok()
        .map(|path| path.length_cells * g.resolution());
    (opt, available_clearance(c, s, e))
}

/// MovingAI `map` and `scen` at `resolution` m per cell: the map is written as a map_server
/// world into `dir`; problems `offset..offset+limit` of the scenario.
pub fn movingai(
    map: &Path,
    scen: &Path,
    resolution: f64,
    dir: &Path,
    offset: usize,
    limit: Option<usize>,
) -> Result<Vec<Problem>> {
    if !(resolution.is_finite() && resolution > 0.0) {
        bail!("--resolution must be a positive number of metres per cell, got {resolution}");
    }
    let m = read_map(map)?;
    let scen_problems = read_scen(scen)?;
    let grid = m
        .to_occupancy_grid(resolution)
        .with_context(|| format!("map {}", map.display()))?;
    let stem = map
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "map".into());
    let world = dir.join(format!("{stem}-{resolution}.yaml"));
    grid.save(&world)
        .with_context(|| format!("writing {}", world.display()))?;
    let c = costmap(&grid);
    let scen_name = scen
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let centre = |cell: (i64, i64)| {
        let (x, y) = m.to_grid_cell(cell.0, cell.1);
        grid.cell_to_world(x, y)
    };
    let take = limit.unwrap_or(usize::MAX);
    let mut judge_plan = PlanJudge::new(&grid);
    let mut out = Vec::new();
    for sp in scen_problems.iter().skip(offset).take(take) {
        let s = centre(sp.start);
        let g = centre(sp.goal);
        let cs = c.grid().world_to_cell(s[0], s[1]);
        let cg = c.grid().world_to_cell(g[0], g[1]);
        out.push(Problem {
            id: out.len() + 1,
            source: format!("{scen_name}:{}", sp.line),
            world: world.clone(),
            start: [s[0], s[1], 0.0],
            goal: g,
            optimum_m: Some(sp.optimal_length * resolution),
            clearance_available_m: available_clearance(&c, cs, cg),
            plan_clearance_m: judge_plan.gap(s, g, PLAN_TOLERANCE_M),
        });
    }
    Ok(out)
}

/// A map_server world and a problem list: one problem per line, `start_x start_y goal_x
/// goal_y [start_theta]` (spaces or commas; `#` starts a comment).
pub fn listed(world: &Path, list: &Path) -> Result<Vec<Problem>> {
    let grid = OccupancyGrid::load(world)?;
    let c = costmap(&grid);
    let mut judge_plan = PlanJudge::new(&grid);
    let text =
        std::fs::read_to_string(list).with_context(|| format!("reading {}", list.display()))?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .collect();
        if !(4..=5).contains(&fields.len()) {
            bail!(
                "{}:{}: expected `start_x start_y goal_x goal_y [start_theta]`, got {} fields",
                list.display(),
                n + 1,
                fields.len()
            );
        }
        let names = ["start_x", "start_y", "goal_x", "goal_y", "start_theta"];
        let mut v = [0.0; 5];
        for (i, f) in fields.iter().enumerate() {
            v[i] = f
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .with_context(|| {
                    format!(
                        "{}:{}: field `{}`: {f:?} is not a finite number",
                        list.display(),
                        n + 1,
                        names[i]
                    )
                })?;
        }
        let (opt, avail) = judge(&c, [v[0], v[1]], [v[2], v[3]]);
        out.push(Problem {
            id: out.len() + 1,
            source: format!("{}:{}", list.display(), n + 1),
            world: world.to_path_buf(),
            start: [v[0], v[1], v[4]],
            goal: [v[2], v[3]],
            optimum_m: opt,
            clearance_available_m: avail,
            plan_clearance_m: judge_plan.gap([v[0], v[1]], [v[2], v[3]], PLAN_TOLERANCE_M),
        });
    }
    if out.is_empty() {
        bail!("{}: no problems", list.display());
    }
    Ok(out)
}

/// `n` generated worlds of `seed`, one problem each: start and goal at least `min_dist_m`
/// apart, both with room for the robot (0.4 m from every obstacle), the goal reachable.
/// Worlds written into `dir`.
pub fn generated(
    n: usize,
    seed: u64,
    cfg: &GenConfig,
    min_dist_m: f64,
    dir: &Path,
) -> Result<Vec<Problem>> {
    let mut out = Vec::new();
    for i in 0..n {
        let ws = world_seed(seed, i as u64);
        let world = generate(cfg, ws);
        let path = dir.join(format!("generated-{seed}-{i}.yaml"));
        world
            .grid
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        let c = costmap(&world.grid);
        let g = c.grid();
        let mut rng = ChaCha8Rng::seed_from_u64(ws ^ 0x5EED);
        let roomy = |x: i64, y: i64| c.clearance(x, y).is_some_and(|d| d >= 0.4);
        let (w, h) = (i64::from(g.width()), i64::from(g.height()));
        let mut planner = GridPlanner::new(PlannerConfig::default());
        let mut found = None;
        for _ in 0..400 {
            let s = (rng.random_range(0..w), rng.random_range(0..h));
            let e = (rng.random_range(0..w), rng.random_range(0..h));
            if !roomy(s.0, s.1) || !roomy(e.0, e.1) {
                continue;
            }
            let (ps, pe) = (g.cell_to_world(s.0, s.1), g.cell_to_world(e.0, e.1));
            if (ps[0] - pe[0]).hypot(ps[1] - pe[1]) < min_dist_m {
                continue;
            }
            if let Ok(path) = planner.plan_cells(g, s, e) {
                let theta = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
                found = Some((ps, pe, theta, path.length_cells * g.resolution(), s, e));
                break;
            }
        }
        let Some((ps, pe, theta, opt, s, e)) = found else {
            tracing::warn!("generated world {i} (seed {seed}): no problem found, skipped");
            continue;
        };
        out.push(Problem {
            id: out.len() + 1,
            source: format!("generated {i} (seed {seed})"),
            world: path,
            start: [ps[0], ps[1], theta],
            goal: pe,
            optimum_m: Some(opt),
            clearance_available_m: available_clearance(&c, s, e),
            plan_clearance_m: PlanJudge::new(&world.grid).gap(ps, pe, PLAN_TOLERANCE_M),
        });
    }
    Ok(out)
}
