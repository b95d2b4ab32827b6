//! The built-in mission (`hng run` without a launch file): the launch plan of the simulated
//! robot with the modules of HNG v1.0, generated from the mission options.
//!
//! [`MissionOptions`] is what the user asked (`--world`, `--start`, `--goal`, `--speed`,
//! `--seed`, `--duration`); [`mission_plan`] turns it into the text of a launch file (shown by
//! `hng run --print-plan`), which goes through the same validation as any launch file. The
//! monitor ([`super::monitor`]) follows the mission and decides success.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::{Context as _, Result, bail};
use hng_simulator::{Pose2D, World};

/// Goals of the default mission in the default world (start 2, 2), all in the yard: east,
/// then north across the GPS-degraded zone under the tree (centre 3, 9, radius 1.5), then back
/// south-east.
pub const DEFAULT_GOALS: [(f64, f64); 3] = [(5.5, 3.0), (3.0, 11.0), (6.0, 6.5)];

/// The modules of the mission besides the simulator (whose start it waits for).
const MISSION_MODULES: [&str; 11] = [
    "laser",
    "camera",
    "robot",
    "security",
    "interface",
    "gps",
    "maps",
    "slam",
    "planning",
    "servo",
    "manager",
];

/// The fused localization module (odometry and GPS, docs/navigation.md), in the mission unless
/// `--no-fusion`.
const FUSION_MODULE: &str = "localization";

/// The mission's modules besides the simulator, in start order.
fn mission_modules(fusion: bool) -> Vec<&'static str> {
    let mut m = MISSION_MODULES.to_vec();
    if fusion && let Some(i) = m.iter().position(|n| *n == "gps") {
        m.insert(i + 1, FUSION_MODULE);
    }
    m
}

/// Position tolerance of the mission's goals, m. A goal counts as reached only when the
/// simulator's true pose is within it; the robot localizes by odometry fused with GPS (the
/// `localization` module, σ about 0.05-0.1 m against the GPS's 0.3 m per axis) and stops when
/// its own estimate is within 0.05 m, so its true error at a goal is that estimate's error
/// plus up to 0.05 m.
pub const GOAL_TOLERANCE_M: f64 = 0.3;

/// Default limit of simulated time for a mission, s.
pub const DEFAULT_DURATION_S: f64 = 240.0;

/// Default simulation speed (simulated seconds per wall second).
pub const DEFAULT_SPEED: &str = "6";

/// What the user asked of the mission.
#[derive(Debug, Clone)]
pub struct MissionOptions {
    /// World file (TOML or map_server YAML); `None`: the built-in world.
    pub world: Option<PathBuf>,
    /// Start pose; `None`: the world's.
    pub start: Option<Pose2D>,
    /// Goals; empty: the default mission's (only in the default world).
    pub goals: Vec<(f64, f64)>,
    /// `"realtime"`, a factor or `"max"`.
    pub speed: String,
    /// Noise seed (overrides the world's).
    pub seed: Option<u64>,
    /// Limit of simulated time, s.
    pub duration_s: f64,
    /// Position tolerance of every goal, m.
    pub tolerance_m: f64,
    /// Run the fused localization module (false: GPS and SLAM only, `--no-fusion`).
    pub fusion: bool,
    /// Goals come as episodes from the monitor (`--episodes`): the Manager starts without.
    pub episodes: bool,
}

impl Default for MissionOptions {
    fn default() -> Self {
        MissionOptions {
            world: None,
            start: None,
            goals: Vec::new(),
            speed: DEFAULT_SPEED.to_owned(),
            seed: None,
            duration_s: DEFAULT_DURATION_S,
            tolerance_m: GOAL_TOLERANCE_M,
            fusion: true,
            episodes: false,
        }
    }
}

/// A mission ready to launch: the launch file's text and what the monitor needs.
#[derive(Debug, Clone)]
pub struct Mission {
    /// The launch file.
    pub plan: String,
    /// The goals, in order.
    pub goals: Vec<(f64, f64)>,
    /// Start pose.
    pub start: Pose2D,
    /// Limit of simulated time, s.
    pub duration_s: f64,
    /// The map file Maps loads (written by [`Mission::prepare`] for TOML worlds).
    pub map: PathBuf,
    /// The world to rasterise into `map` (TOML worlds and the built-in one); `None` when the
    /// world is itself a map_server map.
    world_to_rasterise: Option<World>,
}

/// Parses `X,Y[,THETA]`.
pub fn parse_pose(s: &str) -> Result<Pose2D, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if !(2..=3).contains(&parts.len()) {
        return Err(format!("expected X,Y or X,Y,THETA, got {s:?}"));
    }
    let mut v = [0.0; 3];
    for (i, p) in parts.iter().enumerate() {
        v[i] = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{p:?} is not a finite number (in {s:?})"))?;
    }
    Ok(Pose2D::new(v[0], v[1], v[2]))
}

/// Parses `X,Y`.
pub fn parse_goal(s: &str) -> Result<(f64, f64), String> {
    let p = parse_pose(s)?;
    if s.split(',').count() != 2 {
        return Err(format!("expected X,Y, got {s:?}"));
    }
    Ok((p.x, p.y))
}

/// Parses a speed: `realtime`, `max` or a positive factor.
pub fn parse_speed(s: &str) -> Result<String, String> {
    match s {
        "realtime" | "max" => Ok(s.to_owned()),
        _ => match s.parse::<f64>() {
            Ok(f) if f.is_finite() && f > 0.0 => Ok(s.to_owned()),
            _ => Err(format!(
                "expected `realtime`, `max` or a positive factor, got {s:?}"
            )),
        },
    }
}

fn is_yaml(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml"))
}

/// A TOML string literal.
fn quoted(s: &str) -> String {
    // A JSON string is a valid TOML basic string.
    serde_json::to_string(s).unwrap_or_else(|_| format!("{s:?}"))
}

fn speed_value(s: &str) -> String {
    match s.parse::<f64>() {
        Ok(f) => format!("{f}"),
        Err(_) => quoted(s),
    }
}

impl Mission {
    /// Builds the mission: loads the world (errors name the file and line), checks the goals,
    /// writes nothing. `run_dir` is where [`Mission::prepare`] will put the map.
    pub fn new(opts: &MissionOptions, run_dir: &Path) -> Result<Mission> {
        let world_path = match &opts.world {
            Some(p) => Some(
                std::fs::canonicalize(p).with_context(|| format!("world file {}", p.display()))?,
            ),
            None => None,
        };
        let (world, yaml) = match &world_path {
            None => (World::default_world(), false),
            Some(p) if is_yaml(p) => {
                let Some(start) = opts.start else {
                    bail!(
                        "the world {} is a map_server map: give the start pose with --start X,Y[,THETA]",
                        p.display()
                    );
                };
                (World::from_occupancy_map(p, start)?, true)
            }
            Some(p) => (World::load(p)?, false),
        };
        let start = opts.start.unwrap_or(world.robot.start);
        let goals = if !opts.goals.is_empty() || opts.episodes {
            opts.goals.clone()
        } else if opts.world.is_none() && opts.start.is_none() {
            DEFAULT_GOALS.to_vec()
        } else {
            bail!("give the goal with --goal X,Y (the default goals are for the default world)");
        };
        if !(opts.tolerance_m.is_finite() && opts.tolerance_m > 0.0) {
            bail!(
                "--tolerance must be a positive distance in metres, got {}",
                opts.tolerance_m
            );
        }
        if !(opts.duration_s.is_finite() && opts.duration_s > 0.0) {
            bail!(
                "--duration must be a positive number of seconds, got {}",
                opts.duration_s
            );
        }
        let (map, world_to_rasterise) = match (&world_path, yaml) {
            (Some(p), true) => (p.clone(), None),
            _ => (run_dir.join("mission").join("map.yaml"), Some(world)),
        };
        let plan = render_plan(opts, world_path.as_deref(), start, &goals, &map);
        Ok(Mission {
            plan,
            goals,
            start,
            duration_s: opts.duration_s,
            map,
            world_to_rasterise,
        })
    }

    /// Writes the map Maps loads (the ground-truth rasterisation of a TOML world).
    pub fn prepare(&self) -> Result<()> {
        if let Some(w) = &self.world_to_rasterise {
            if let Some(dir) = self.map.parent() {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
            }
            w.write_occupancy_map(&self.map, 0.05)
                .with_context(|| format!("writing the map {}", self.map.display()))?;
        }
        Ok(())
    }
}

/// The launch file of a mission.
fn render_plan(
    opts: &MissionOptions,
    world: Option<&Path>,
    start: Pose2D,
    goals: &[(f64, f64)],
    map: &Path,
) -> String {
    let mut s = String::new();
    let start_t = format!(
        "{{ x = {:?}, y = {:?}, theta = {:?} }}",
        start.x, start.y, start.theta
    );
    let _ = writeln!(
        s,
        "# hng's built-in mission: the simulated robot with the modules of HNG v1.0 (paper Table 1)."
    );
    let _ = writeln!(s, "system = \"hng-mission\"");
    let _ = writeln!(s, "clock = \"sim\"\n");
    let _ = writeln!(
        s,
        r#"[defaults]
restart = "on-failure"
heartbeat_period_s = 0.5
heartbeat_timeout_s = 3.0
start_timeout_s = 10.0
checkpoint_period_s = 0.5
stop_timeout_s = 2.0
backoff_initial_s = 0.05
backoff_max_s = 0.5
backoff_reset_after_s = 2.0
give_up_failures = 50
give_up_window_s = 60.0
"#
    );
    let module = |s: &mut String, name: &str, cmd: &str| {
        let _ = writeln!(
            s,
            "[[module]]\nname = \"{name}\"\ncommand = [\"hng\", \"module\", \"{cmd}\"]"
        );
    };
    module(&mut s, "simulator", "simulator");
    let _ = writeln!(s, "\n[module.config]");
    if let Some(w) = world {
        let _ = writeln!(s, "world = {}", quoted(&w.to_string_lossy()));
    }
    let _ = writeln!(s, "start = {start_t}");
    let _ = writeln!(s, "speed = {}", speed_value(&opts.speed));
    if let Some(seed) = opts.seed {
        let _ = writeln!(s, "seed = {seed}");
    }
    let modules = mission_modules(opts.fusion);
    let list = modules
        .iter()
        .map(|m| quoted(m))
        .collect::<Vec<_>>()
        .join(", ");
    // Paused start: simulated time waits until every module is up.
    let _ = writeln!(s, "wait_for = [{list}]");
    // Lockstep: simulated time advances only when every module has handled the last step,
    // so the mission gives the same result at any speed.
    let _ = writeln!(s, "lockstep = [{list}]");
    let _ = writeln!(s);
    for (name, cmd) in [
        ("laser", "laser"),
        ("camera", "camera"),
        ("robot", "robot"),
        ("security", "security"),
        ("interface", "interface"),
        ("gps", "gps"),
    ] {
        module(&mut s, name, cmd);
        let _ = writeln!(s);
    }
    if opts.fusion {
        module(&mut s, FUSION_MODULE, FUSION_MODULE);
        let _ = writeln!(s);
    }
    module(&mut s, "maps", "maps");
    let _ = writeln!(
        s,
        "\n[module.config]\nmap = {}\n",
        quoted(&map.to_string_lossy())
    );
    module(&mut s, "slam", "slam");
    let _ = writeln!(s, "\n[module.config]\ninitial_pose = {start_t}\n");
    // Planning pursues the goal the Interface passes on: the Manager's, or the operator's
    // while a goal order is in force (docs/autonomy.md).
    module(&mut s, "planning", "planning");
    let _ = writeln!(s, "\n[module.config]\ngoal = \"interface/goal\"\n");
    module(&mut s, "servo", "servo");
    let _ = writeln!(s);
    module(&mut s, "manager", "manager");
    let _ = writeln!(s, "manager = true\n\n[module.config]\ngoals = [");
    for (x, y) in goals {
        let _ = writeln!(
            s,
            "  {{ x = {x:?}, y = {y:?}, tolerance = {:?} }},",
            opts.tolerance_m
        );
    }
    let _ = writeln!(s, "]");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_goals_and_speeds_parse() {
        assert_eq!(parse_pose("1,2").unwrap(), Pose2D::new(1.0, 2.0, 0.0));
        assert_eq!(parse_pose("1, 2, 0.5").unwrap(), Pose2D::new(1.0, 2.0, 0.5));
        assert!(parse_pose("1").is_err());
        assert!(parse_pose("1,nan").is_err());
        assert!(parse_goal("1,2,3").is_err());
        assert_eq!(parse_goal("3,4").unwrap(), (3.0, 4.0));
        assert!(parse_speed("max").is_ok());
        assert!(parse_speed("7.5").is_ok());
        assert!(parse_speed("-1").is_err());
        assert!(parse_speed("fast").is_err());
    }

    #[test]
    fn the_default_mission_plan_validates() {
        let m = Mission::new(&MissionOptions::default(), Path::new("/tmp/x")).unwrap();
        assert_eq!(m.goals.len(), DEFAULT_GOALS.len());
        let opts = hng_watchdog::LoadOptions::default();
        let plan = hng_watchdog::launch::parse(&m.plan, Path::new("<mission>"), &opts);
        let plan = plan.unwrap_or_else(|e| panic!("{e}\n{}", m.plan));
        assert!(plan.sim_clock);
        assert_eq!(plan.modules.len(), 13);
        // The simulator's paused start waits for every other module of the plan.
        let mut others: Vec<&str> = plan
            .modules
            .iter()
            .map(|m| m.name.as_str())
            .filter(|n| *n != "simulator")
            .collect();
        others.sort_unstable();
        let mut waited = mission_modules(true);
        assert!(waited.contains(&"localization"));
        waited.sort_unstable();
        assert_eq!(others, waited);
        assert!(m.plan.contains("wait_for = [\"laser\""), "{}", m.plan);
    }

    #[test]
    fn a_map_server_world_needs_a_start_and_a_goal() {
        let yaml = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../simulator/worlds/example_map.yaml"
        );
        let opts = MissionOptions {
            world: Some(yaml.into()),
            ..MissionOptions::default()
        };
        let e = Mission::new(&opts, Path::new("/tmp/x")).unwrap_err();
        assert!(format!("{e:#}").contains("--start"), "{e:#}");
        let opts = MissionOptions {
            start: Some(Pose2D::new(10.5, 0.5, 0.0)),
            ..opts
        };
        let e = Mission::new(&opts, Path::new("/tmp/x")).unwrap_err();
        assert!(format!("{e:#}").contains("--goal"), "{e:#}");
    }
}
