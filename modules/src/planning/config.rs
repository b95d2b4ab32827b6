//! The configuration of `hng module planning`.

use hng_runtime::msg::PLANNED_PATH_CHANNEL;
use serde::Deserialize;

use crate::planning_module::PlanningParams;

/// Configuration of `hng module planning`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlanningModuleConfig {
    /// Map input until a "Mapping" provider is known (default `maps/map`).
    pub map: String,
    /// Position input (default `slam/pose`).
    pub pose: String,
    /// Goal input (default `manager/goal`).
    pub goal: String,
    /// Waypoints out (default `planning/waypoint`).
    pub waypoint_out: String,
    /// Goal status out (default `planning/status`).
    pub status_out: String,
    /// Stalls and recoveries out (default `planning/progress`).
    pub progress_out: String,
    /// The whole planned path out (default `planning/path`, [`PLANNED_PATH_CHANNEL`]; an
    /// empty path when there is none).
    pub path_out: String,
    /// Planner parameters.
    pub params: PlanningParams,
    /// Scans, to rate the "Mapping" provider by agreement with them (client feedback,
    /// [`crate::feedback::ScanMapAgreement`]; default `laser/scan`, empty: no rating).
    pub scan: String,
    /// The rating's parameters.
    pub map_feedback: crate::feedback::MapFeedbackParams,
    /// Longest computation (map inflation, a search) during which heartbeats go on, s
    /// (default 120); a longer one is a hang for the watchdog. See [`crate::heartbeat`].
    pub max_compute_s: f64,
}

impl Default for PlanningModuleConfig {
    fn default() -> Self {
        PlanningModuleConfig {
            map: "maps/map".into(),
            pose: "slam/pose".into(),
            goal: "manager/goal".into(),
            waypoint_out: "planning/waypoint".into(),
            status_out: "planning/status".into(),
            progress_out: crate::planning::progress::PROGRESS_CHANNEL.into(),
            path_out: PLANNED_PATH_CHANNEL.into(),
            params: PlanningParams::default(),
            scan: "laser/scan".into(),
            map_feedback: crate::feedback::MapFeedbackParams::default(),
            max_compute_s: 120.0,
        }
    }
}
