//! What the mission monitor concludes: the summary of a mission, its JSON file and the
//! terminal text `hng run` ends with.

use serde::Serialize;

use crate::error::{Context as _, Result};

/// One goal of the mission, as the summary reports it.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct GoalSummary {
    /// The Manager's id of the goal.
    pub id: u32,
    /// x, m (map frame).
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// Position tolerance, m.
    pub tolerance_m: f64,
    /// `reached` (true pose within tolerance), `missed` (reported reached, true pose
    /// outside the tolerance), `refused`, `active` or `pending` (never dealt with).
    pub state: String,
    /// Why it was not reached (refusal reason, true error, ...).
    pub reason: Option<String>,
    /// Distance from the true pose to the goal when it was dealt with (reached or refused),
    /// or at the end of the mission, m (`null` without ground truth).
    pub true_error_m: Option<f64>,
}

/// The summary of a mission (`--summary FILE` writes it as JSON, with exactly these fields).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Summary {
    /// Every goal truly reached, no collision, within the duration.
    pub success: bool,
    /// Goals reached (true pose within tolerance).
    pub goals_reached: u32,
    /// Goals the mission ever held (added ones and refused ones included).
    pub goals_total: u32,
    /// Every goal, in mission order.
    pub goals: Vec<GoalSummary>,
    /// Simulated time at the end, s: the stamp of the Manager's document that said the
    /// mission done, or when the run ended otherwise.
    pub sim_time_s: f64,
    /// Wall time from start to the end of the mission, s.
    pub wall_time_s: f64,
    /// Length of the true path until the end (`sim_time_s`), m.
    pub path_length_m: f64,
    /// Smallest gap between the robot and an obstacle, m (`null` if never measured).
    pub min_obstacle_distance_m: Option<f64>,
    /// Contacts begun with obstacles.
    pub collisions: u64,
    /// Times a need changed from one provider to another.
    pub contract_switches: u64,
    /// Module processes that died and were restarted.
    pub restarts: u64,
    /// Simulated time the true pose moved less than 5 cm in a second while a goal was
    /// pursued, s.
    pub stuck_time_s: f64,
    /// Stalls Planning reported (no progress toward a goal).
    pub stalls: u64,
    /// Recovery behaviours Planning started.
    pub recoveries: u64,
    /// True poses the monitor lost before reading them (its buffer overflowed: the machine
    /// starved it). A goal is judged against the true pose at the time it was reported
    /// reached; with poses lost around that time the judgement may be off.
    pub true_poses_lost: u64,
    /// Why the mission failed (`null` on success).
    pub failure: Option<String>,
}

/// How the mission ended, with the summary.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The figures.
    pub summary: Summary,
    /// Why it failed (empty on success).
    pub failure: Option<String>,
}

/// Writes `summary` as JSON to `path` through a temporary file and a rename.
pub fn write_summary(path: &std::path::Path, summary: &Summary) -> Result<()> {
    let text = serde_json::to_string_pretty(summary).context("encoding the summary")?;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    std::fs::write(&tmp, text + "\n")
        .with_context(|| format!("writing the summary to {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("writing the summary to {}", path.display()))
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "mission {}: {} of {} goals reached",
            if self.success { "SUCCEEDED" } else { "FAILED" },
            self.goals_reached,
            self.goals_total
        )?;
        writeln!(
            f,
            "  time              {:.1} s simulated, {:.1} s wall",
            self.sim_time_s, self.wall_time_s
        )?;
        writeln!(f, "  path length       {:.2} m", self.path_length_m)?;
        match self.min_obstacle_distance_m {
            Some(d) => writeln!(f, "  min obstacle dist {d:.3} m")?,
            None => writeln!(f, "  min obstacle dist -")?,
        }
        writeln!(f, "  collisions        {}", self.collisions)?;
        for g in &self.goals {
            let err = g
                .true_error_m
                .map_or_else(|| "-".to_owned(), |e| format!("{e:.3} m"));
            let why = g
                .reason
                .as_deref()
                .map(|r| format!(" ({r})"))
                .unwrap_or_default();
            writeln!(
                f,
                "  goal {:<3} ({:6.2}, {:6.2})  {:<8} true error {err}{why}",
                g.id, g.x, g.y, g.state
            )?;
        }
        writeln!(
            f,
            "  stalls            {} ({} recovery behaviours, {:.1} s standing still)",
            self.stalls, self.recoveries, self.stuck_time_s
        )?;
        writeln!(f, "  contract switches {}", self.contract_switches)?;
        write!(f, "  restarts          {}", self.restarts)
    }
}
