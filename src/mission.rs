//! `hng mission show|set|add|clear|skip`: read and change the running Manager's mission.
//!
//! Changes go to the Manager as [`Mission`] messages on `hng/mission` (at most
//! [`MAX_MISSION_GOALS`] goals each: a longer list is sent as a replace or append followed by
//! appends); each is acknowledged by the Manager's [`MissionPlan`] document on
//! `manager/mission`, whose `revision` counts the changes it applied. The command returns once
//! the Manager has applied all of them and prints the mission as it now stands.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context as _, Result, bail};
use clap::{Args, Subcommand};
use hng_modules::manager::{
    GoalConfig, MISSION_CHANNEL, MISSION_PLAN_CHANNEL, MissionPlan, mission_goals,
};
use hng_modules::msgs::{MAX_MISSION_GOALS, Mission, MissionGoal, MissionOp};
use serde::Deserialize;

use hng_supervisor::doc::{DocReader, ensure_channel_exists};

/// How long a command waits for the Manager (it answers as soon as it has applied a change).
const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);

/// `hng mission ...`.
#[derive(Debug, Subcommand)]
pub enum MissionCommand {
    /// The mission: every goal with its state (reached, refused, active, pending).
    Show {
        /// One JSON document.
        #[arg(long)]
        json: bool,
    },
    /// Replace the goals not yet dealt with (the current goal is abandoned).
    Set(GoalArgs),
    /// Append goals to the mission (a finished mission starts again with them).
    Add(GoalArgs),
    /// Drop every goal not yet dealt with: the robot holds.
    Clear,
    /// Give up the current goal (counted as refused) and go on with the next.
    Skip,
}

/// Goals given on the command line or in a file.
#[derive(Debug, Args)]
pub struct GoalArgs {
    /// Goals as `X,Y` or `X,Y,THETA` (metres, radians, map frame); put goals with a negative
    /// x after `--` (`hng mission add -- -1,2`).
    goals: Vec<String>,
    /// A TOML file of goals: `[[goals]]` tables with `x`, `y` and optional `theta`, `tolerance`.
    #[arg(long)]
    file: Option<PathBuf>,
    /// Position tolerance of the command-line goals, m.
    #[arg(long, default_value_t = 0.2, allow_negative_numbers = true)]
    tolerance: f64,
}

/// Runs `hng mission`.
pub fn run(prefix: &str, cmd: MissionCommand) -> Result<()> {
    ensure_channel_exists(
        prefix,
        MISSION_PLAN_CHANNEL,
        "Manager",
        "start a system with `hng run` or pass --prefix",
    )?;
    let mut reader = DocReader::<MissionPlan>::open(
        prefix,
        MISSION_PLAN_CHANNEL,
        "hng-mission",
        "the Manager's mission",
    )?;
    let current = reader.current(ANSWER_TIMEOUT)?;
    let (op, goals) = match cmd {
        MissionCommand::Show { json } => {
            print_plan(&current, json)?;
            return Ok(());
        }
        MissionCommand::Set(args) => (MissionOp::Replace, args.goals()?),
        MissionCommand::Add(args) => (MissionOp::Append, args.goals()?),
        MissionCommand::Clear => (MissionOp::Clear, Vec::new()),
        MissionCommand::Skip => (MissionOp::Skip, Vec::new()),
    };
    let messages = messages(op, &goals);
    let publisher = reader
        .node()
        .publisher::<Mission>(MISSION_CHANNEL)
        .context("opening the mission channel")?;
    publisher.update_connections();
    for m in &messages {
        publisher
            .publish(*m)
            .context("sending the mission change")?;
    }
    let want = current.revision + messages.len() as u64;
    let plan = reader
        .next_where(ANSWER_TIMEOUT, |p| p.revision >= want)
        .context("the Manager did not acknowledge the mission change")?;
    print_plan(&plan, false)
}

impl GoalArgs {
    fn goals(&self) -> Result<Vec<MissionGoal>> {
        let mut configs = Vec::new();
        if let Some(path) = &self.file {
            configs.extend(read_goal_file(path)?);
        }
        for g in &self.goals {
            configs.push(parse_goal(g, self.tolerance)?);
        }
        if configs.is_empty() {
            bail!("give at least one goal (X,Y[,THETA] or --file FILE)");
        }
        mission_goals(&configs).map_err(|e| anyhow::anyhow!("{e}"))
    }
}

/// `X,Y` or `X,Y,THETA`.
fn parse_goal(s: &str, tolerance: f64) -> Result<GoalConfig> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let num = |i: usize, what: &str| -> Result<f64> {
        parts[i]
            .parse::<f64>()
            .with_context(|| format!("goal {s:?}: {what} {:?} is not a number", parts[i]))
    };
    if !(2..=3).contains(&parts.len()) {
        bail!("goal {s:?}: expected X,Y or X,Y,THETA (metres, radians)");
    }
    let goal = GoalConfig {
        x: num(0, "x")?,
        y: num(1, "y")?,
        theta: if parts.len() == 3 {
            Some(num(2, "theta")?)
        } else {
            None
        },
        tolerance: Some(tolerance),
    };
    if let Err(e) = mission_goals(&[goal]) {
        bail!("goal {s:?}: {e}");
    }
    Ok(goal)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GoalFile {
    goals: Vec<GoalConfig>,
}

/// A TOML goal file; errors name the file and the line.
fn read_goal_file(path: &Path) -> Result<Vec<GoalConfig>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading mission file {}", path.display()))?;
    let file: GoalFile =
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    mission_goals(&file.goals).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(file.goals)
}

/// The messages for one change: `op` with the first goals, appends for the rest.
fn messages(op: MissionOp, goals: &[MissionGoal]) -> Vec<Mission> {
    if goals.is_empty() {
        return vec![Mission::new(op, &[])];
    }
    goals
        .chunks(MAX_MISSION_GOALS)
        .enumerate()
        .map(|(i, chunk)| Mission::new(if i == 0 { op } else { MissionOp::Append }, chunk))
        .collect()
}

fn print_plan(p: &MissionPlan, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(p)?);
        return Ok(());
    }
    println!(
        "mission: {} goals, {} reached, {} refused, {}",
        p.goals_total,
        p.goals_reached,
        p.goals_refused,
        if p.done {
            "done (holding)".to_owned()
        } else {
            format!("current goal {}", p.current_goal_id)
        }
    );
    if p.goals.is_empty() {
        return Ok(());
    }
    println!(
        "{:>4}  {:<8} {:>8} {:>8} {:>7} {:>6}  REASON",
        "ID", "STATE", "X", "Y", "THETA", "TOL"
    );
    for g in &p.goals {
        println!(
            "{:>4}  {:<8} {:>8.2} {:>8.2} {:>7} {:>6.2}  {}",
            g.id,
            g.state,
            g.x,
            g.y,
            g.theta
                .map_or_else(|| "-".to_owned(), |t| format!("{t:.2}")),
            g.tolerance_m,
            g.reason.as_deref().unwrap_or("")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goals_parse_with_clear_errors() {
        let g = parse_goal("1.5, -2,0.5", 0.3).ok();
        assert_eq!(g.map(|g| (g.x, g.y, g.theta)), Some((1.5, -2.0, Some(0.5))));
        let e = parse_goal("1,x", 0.2).err().map(|e| format!("{e:#}"));
        assert!(e.is_some_and(|e| e.contains("y \"x\" is not a number")));
        assert!(parse_goal("1", 0.2).is_err());
        assert!(parse_goal("1,2,3,4", 0.2).is_err());
        // Beyond any map: refused with the reason, before anything is sent.
        let e = parse_goal("1e300,1e300", 0.2)
            .err()
            .map(|e| format!("{e:#}"));
        assert!(
            e.as_deref()
                .is_some_and(|e| e.contains("1e300,1e300") && e.contains("within")),
            "{e:?}"
        );
    }

    #[test]
    fn long_lists_become_one_op_then_appends() {
        let goals = vec![MissionGoal::default(); MAX_MISSION_GOALS + 5];
        let m = messages(MissionOp::Replace, &goals);
        assert_eq!(m.len(), 2);
        assert_eq!(
            (m[0].op, m[0].goals().len()),
            (MissionOp::Replace as u8, 32)
        );
        assert_eq!((m[1].op, m[1].goals().len()), (MissionOp::Append as u8, 5));
        assert_eq!(messages(MissionOp::Skip, &[]).len(), 1);
    }

    #[test]
    fn goal_file_errors_name_file_and_line() {
        let dir = std::env::temp_dir().join(format!("hng-mission-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).ok();
        let path = dir.join("goals.toml");
        std::fs::write(
            &path,
            "[[goals]]\nx = 1.0\ny = 2.0\n\n[[goals]]\nx = 3.0\nz = 1\n",
        )
        .ok();
        let e = read_goal_file(&path).err().map(|e| format!("{e:#}"));
        std::fs::remove_dir_all(&dir).ok();
        let e = e.unwrap_or_default();
        assert!(e.contains("goals.toml") && e.contains("line 7"), "{e}");
    }
}
