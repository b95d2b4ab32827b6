//! The configuration of `hng module planning`.

use hng_runtime::msg::PLANNED_PATH_CHANNEL;
use serde::Deserialize;
use smart_default::SmartDefault;

use crate::planning_module::PlanningParams;

/// Configuration of `hng module planning`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct PlanningModuleConfig {
    /// Map input until a "Mapping" provider is known (default `maps/map`).
    #[default("maps/map".into())]
    pub map: String,
    /// Position input (default `slam/pose`).
    #[default("slam/pose".into())]
    pub pose: String,
    /// Goal input (default `manager/goal`).
    #[default("manager/goal".into())]
    pub goal: String,
    /// Waypoints out (default `planning/waypoint`).
    #[default("planning/waypoint".into())]
    pub waypoint_out: String,
    /// Goal status out (default `planning/status`).
    #[default("planning/status".into())]
    pub status_out: String,
    /// An `Active` status goes out again only when the distance left has changed by this
    /// much since the last one sent, m (default 0.25; 0: at every pose); any other change
    /// (goal, state, reason) goes out at once. See [`crate::planning_module::StatusFilter`].
    #[default(0.25)]
    pub status_step_m: f64,
    /// Stalls and recoveries out (default `planning/progress`).
    #[default(crate::planning::progress::PROGRESS_CHANNEL.into())]
    pub progress_out: String,
    /// The whole planned path out (default `planning/path`, [`PLANNED_PATH_CHANNEL`]; an
    /// empty path when there is none).
    #[default(PLANNED_PATH_CHANNEL.into())]
    pub path_out: String,
    /// Planner parameters.
    #[default(PlanningParams::default())]
    pub params: PlanningParams,
    /// Scans, to rate the "Mapping" provider by agreement with them (client feedback,
    /// [`crate::feedback::ScanMapAgreement`]; default `laser/scan`, empty: no rating).
    #[default("laser/scan".into())]
    pub scan: String,
    /// The rating's parameters.
    pub map_feedback: crate::feedback::MapFeedbackParams,
    /// Odometry, to check the "Localization" provider's poses: while they disagree with it
    /// the map is not rated ([`crate::feedback::PoseCheck`]; default `robot/odom`, empty: no
    /// check).
    #[default("robot/odom".into())]
    pub odom: String,
    /// The operator's pose estimates (default `operator/initial_pose`, empty: none): the
    /// Localization provider jumps to one, and the map is not rated for a window.
    #[default(crate::initial_pose::INITIAL_POSE_CHANNEL.into())]
    pub initial_pose: String,
    /// Longest computation (map inflation, a search) during which heartbeats go on, s
    /// (default 120); a longer one is a hang for the watchdog. See [`crate::heartbeat`].
    #[default(120.0)]
    pub max_compute_s: f64,
}
