//! The planner's logic, apart from the module's I/O: [`PlanningCore`] keeps the inflated map,
//! plans with A* and publishes the pure-pursuit carrot (see `planning_module.rs`), with its
//! parameters [`PlanningParams`] and each update's result [`PlanStep`].

use hng_runtime::msg::{FrameId, Goal, Header, Pose2D, Waypoint};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::msgs::{GoalState, GoalStatus, RefusalReason};
use crate::planning::carrot::{ClearanceField, carrot_distance};
use crate::planning::path::{PathState, nearest_cell};
use crate::planning::progress::{
    Action, Event, NavProgress, ProgressMonitor, ProgressParams, progress_message,
    recovery_waypoint,
};
use crate::planning::{
    Costmap, CostmapConfig, GridPlanner, OccupancyGrid, PlannerConfig, simplify_with_cost,
};

/// Parameters of the planner.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct PlanningParams {
    /// Robot radius, m (default [`crate::footprint::ROBOT_RADIUS_M`], 0.2).
    #[default(crate::footprint::ROBOT_RADIUS_M)]
    pub robot_radius: f64,
    /// Margin on top of the radius: cells closer than `robot_radius + clearance` to an
    /// obstacle are lethal, m (default [`crate::footprint::FOOTPRINT_MARGIN_M`], 0.05, the
    /// margin of Security's swept disc).
    #[default(crate::footprint::FOOTPRINT_MARGIN_M)]
    pub clearance: f64,
    /// Distance from obstacles at which the inflation cost has fallen to 0, m (default 1.0):
    /// paths keep this far from walls where there is room.
    #[default(1.0)]
    pub inflation_m: f64,
    /// Inflation cost at the lethal band: a step there costs `1 + cost_weight` times its
    /// length (default 10; 0 plans the plain shortest path).
    #[default(10.0)]
    pub cost_weight: f64,
    /// Decay of the inflation cost with the distance beyond the lethal band, 1/m (default 8:
    /// the cost halves every 9 cm, so paths round convex corners at about 0.5 m from them
    /// rather than grazing the lethal band).
    #[default(8.0)]
    pub cost_decay: f64,
    /// Distance of the carrot ahead of the robot on the path, m (default 0.6): the longest,
    /// in the open ([`crate::planning::carrot`]).
    #[default(0.6)]
    pub lookahead_m: f64,
    /// Shortest distance of the carrot, where the path passes near obstacles, m (default
    /// 0.25): the carrot is shortened so that the line to it keeps the path's clearance.
    #[default(0.25)]
    pub min_lookahead_m: f64,
    /// Distance from obstacles beyond which the line to the carrot may leave the path's
    /// clearance, m (default 0.7: a 0.5 m gap for the 0.2 m robot).
    #[default(0.7)]
    pub comfort_m: f64,
    /// Replan when the robot is farther than this from the path, m (default 0.5).
    #[default(0.5)]
    pub deviation_m: f64,
    /// Speed suggested in waypoints, m/s (default 0.5).
    #[default(0.5)]
    pub speed: f64,
    /// Plan through unknown cells (default true, as Nav2's `allow_unknown`): a SLAM map is
    /// mostly unknown at first, and a goal in its unexplored part is not a reason to refuse
    /// (the "Mapping" provider may also be SLAM only until Maps' better offer arrives); the
    /// robot explores, Security keeps it off what the lidar sees, and every new map replans.
    /// A surveyed map (Maps) has no unknown cells inside the area it covers.
    #[default(true)]
    pub unknown_is_free: bool,
    /// Progress checker and recovery behaviours ([`crate::planning::progress`]).
    #[default(ProgressParams::default())]
    pub progress: ProgressParams,
}

/// What one update of the planner produced.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanStep {
    /// The waypoint to publish.
    pub waypoint: Option<Waypoint>,
    /// The goal's status to publish.
    pub status: Option<GoalStatus>,
    /// Why the goal was just refused (once per goal; final: the map is complete).
    pub refused: Option<String>,
    /// Why the goal cannot be planned in the map as it is, when the map may still grow (a
    /// partial map, or the Mapping provider changing): not a refusal; planned again with the
    /// next map or provider.
    pub pending: Option<String>,
    /// True if a new path was computed.
    pub replanned: bool,
    /// Stalls and recoveries to report.
    pub progress: Vec<NavProgress>,
}

/// The planner's logic, without I/O.
#[derive(Debug)]
pub struct PlanningCore {
    params: PlanningParams,
    planner: GridPlanner,
    /// The costmap's grid (lethal cells occupied).
    grid: Option<OccupancyGrid>,
    /// Its inflation cost per cell.
    costs: Vec<f32>,
    /// Each cell's distance to the nearest obstacle, m.
    clearances: Vec<f32>,
    /// The map it was built from (rebuilt by the "clear" recovery).
    raw: Option<OccupancyGrid>,
    /// Progress of the current goal (from its first update), its stalls and recoveries, and
    /// whether the distance left must be measured afresh (a new map).
    monitor: Option<ProgressMonitor>,
    stalls: u32,
    recoveries: u32,
    rebase: bool,
    goal: Option<Goal>,
    refused: Option<u32>,
    /// The refusal of `refused` is provisional: the map may still grow.
    provisional: bool,
    /// The map may still grow (it has unknown cells, or no Mapping provider is settled).
    map_may_grow: bool,
    /// Provider switch in flight (set by the module).
    provider_settled: bool,
    path: Option<PathState>,
    replan: bool,
}

impl PlanningCore {
    /// A planner with `params`.
    pub fn new(params: PlanningParams) -> PlanningCore {
        PlanningCore {
            params,
            planner: GridPlanner::new(PlannerConfig {
                occupied_threshold: 50,
                unknown_is_free: params.unknown_is_free,
            }),
            grid: None,
            costs: Vec::new(),
            clearances: Vec::new(),
            raw: None,
            monitor: None,
            stalls: 0,
            recoveries: 0,
            rebase: false,
            goal: None,
            refused: None,
            provisional: false,
            map_may_grow: false,
            provider_settled: true,
            path: None,
            replan: false,
        }
    }

    /// Whether the Mapping provider is settled (false while a switch is in flight: no
    /// refusal is final then). Unsettling or settling again retries a provisional refusal.
    pub fn set_provider_settled(&mut self, settled: bool) {
        if settled != self.provider_settled {
            self.provider_settled = settled;
            self.retry_provisional();
        }
    }

    fn retry_provisional(&mut self) {
        if self.provisional {
            self.refused = None;
            self.provisional = false;
            self.replan = true;
        }
    }

    /// The current goal.
    pub fn goal(&self) -> Option<&Goal> {
        self.goal.as_ref()
    }

    /// True if the current goal was refused for good.
    pub fn is_refused(&self) -> bool {
        self.goal.is_some_and(|g| self.refused == Some(g.id)) && !self.provisional
    }

    /// The path being followed, in the map frame, start first (empty when none).
    pub fn path_points(&self) -> &[[f64; 2]] {
        self.path.as_ref().map_or(&[], |p| &p.points)
    }

    /// Length of the path being followed, m (0 when none).
    pub fn path_length(&self) -> f64 {
        self.path.as_ref().map_or(0.0, PathState::total)
    }

    /// True while a path is being followed.
    pub fn has_path(&self) -> bool {
        self.path.is_some()
    }

    /// A new map: it is inflated, and the path replanned at the next pose.
    pub fn set_map(&mut self, grid: &OccupancyGrid) {
        let p = &self.params;
        let costmap = Costmap::build(
            grid,
            &CostmapConfig {
                lethal_m: p.robot_radius + p.clearance,
                inflation_m: p.inflation_m,
                weight: p.cost_weight,
                decay: p.cost_decay,
                ..CostmapConfig::default()
            },
        );
        self.map_may_grow = grid.data().contains(&crate::planning::UNKNOWN);
        self.grid = Some(costmap.grid().clone());
        self.costs = costmap.costs().to_vec();
        self.clearances = costmap.clearances().to_vec();
        self.raw = Some(grid.clone());
        self.rebase = true;
        self.replan = true;
        if self.goal.is_some() {
            self.refused = None; // the new map may make it reachable
            self.provisional = false;
        }
    }

    /// A goal (id 0 clears it). The same goal again changes nothing.
    pub fn set_goal(&mut self, goal: Goal) {
        if goal.id == 0 {
            self.goal = None;
            self.path = None;
            return;
        }
        if self
            .goal
            .is_some_and(|g| g.id == goal.id && g.pose == goal.pose)
        {
            return;
        }
        self.goal = Some(goal);
        self.path = None;
        self.monitor = None;
        (self.stalls, self.recoveries) = (0, 0);
        self.refused = None;
        self.provisional = false;
        self.replan = true;
    }

    fn status(&self, goal_id: u32, state: GoalState, distance_m: f64) -> GoalStatus {
        GoalStatus {
            header: Header {
                frame_id: FrameId::MAP,
                ..Header::default()
            },
            goal_id,
            state: state as u8,
            distance_m,
            reason: 0,
        }
    }

    /// True when a path can start from `pose`: it is in the map and a free cell is within
    /// the inflation band (the same test as in [`PlanningCore::plan`]).
    fn can_start_from(&self, pose: &Pose2D) -> bool {
        let Some(grid) = &self.grid else {
            return false;
        };
        let cfg = *self.planner.config();
        let free = |x: i64, y: i64| grid.get(x, y).is_some_and(|v| cfg.passable(v));
        let reach = ((self.params.robot_radius + self.params.clearance) / grid.resolution()).ceil()
            as i64
            + 2;
        pose.x.is_finite()
            && pose.y.is_finite()
            && nearest_cell(grid.world_to_cell(pose.x, pose.y), reach, free).is_some()
    }

    fn plan(&mut self, pose: &Pose2D, goal: &Goal) -> Result<PathState, (RefusalReason, String)> {
        let Some(grid) = &self.grid else {
            return Err((RefusalReason::OutsideMap, "no map".into()));
        };
        let cfg = *self.planner.config();
        let (gx, gy) = (goal.pose.x, goal.pose.y);
        let o = grid.origin();
        let (w, h, res) = (grid.width(), grid.height(), grid.resolution());
        if !(gx.is_finite() && gy.is_finite()) {
            return Err((
                RefusalReason::Invalid,
                format!("goal {} has a non-finite position", goal.id),
            ));
        }
        let gcell = grid.world_to_cell(gx, gy);
        if grid.index(gcell.0, gcell.1).is_none() {
            return Err((
                RefusalReason::OutsideMap,
                format!(
                    "goal {} at ({gx:.2}, {gy:.2}) is outside the map (x {:.2}..{:.2}, y {:.2}..{:.2})",
                    goal.id,
                    o[0],
                    o[0] + f64::from(w) * res,
                    o[1],
                    o[1] + f64::from(h) * res
                ),
            ));
        }
        let free = |x: i64, y: i64| grid.get(x, y).is_some_and(|v| cfg.passable(v));
        let tol_cells = (goal.tolerance_m.max(0.0) / res).floor() as i64;
        let goal_cell = nearest_cell(gcell, tol_cells, free).ok_or_else(|| {
            (RefusalReason::InObstacle, format!(
                "goal {} at ({gx:.2}, {gy:.2}) is inside an obstacle or closer than {:.2} m to one",
                goal.id,
                self.params.robot_radius + self.params.clearance
            ))
        })?;
        let scell = grid.world_to_cell(pose.x, pose.y);
        // The robot may stand inside the inflation band (it is allowed closer than the
        // clearance): start from the nearest free cell.
        let reach = ((self.params.robot_radius + self.params.clearance) / res).ceil() as i64 + 2;
        let start_cell = nearest_cell(scell, reach, free).ok_or_else(|| {
            (
                RefusalReason::Unreachable,
                format!(
                    "the robot at ({:.2}, {:.2}) is inside an obstacle or outside the map",
                    pose.x, pose.y
                ),
            )
        })?;
        let gp = self
            .planner
            .plan_cells_weighted(grid, &self.costs, start_cell, goal_cell)
            .map_err(|e| {
                (
                    RefusalReason::Unreachable,
                    format!("goal {} at ({gx:.2}, {gy:.2}) is unreachable: {e}", goal.id),
                )
            })?;
        let mut points = simplify_with_cost(
            grid,
            &cfg,
            &self.costs,
            &self.clearances,
            self.params.inflation_m,
            &gp,
        );
        if let Some(first) = points.first_mut() {
            *first = [pose.x, pose.y];
        }
        if let Some(last) = points.last_mut()
            && goal_cell == gcell
        {
            *last = [gx, gy];
        }
        if points.len() == 1 {
            points.push(points[0]);
        }
        Ok(PathState::new(points))
    }

    /// The robot is at `pose`: (re)plan if needed and give the waypoint to follow (no
    /// progress checking: see [`Self::update_at`]).
    pub fn update(&mut self, pose: &Pose2D) -> PlanStep {
        self.update_at(None, pose)
    }

    /// [`Self::update`] at time `now` (s): with a time, progress toward the goal is checked
    /// and the recovery behaviours run ([`crate::planning::progress`]).
    pub fn update_at(&mut self, now: Option<f64>, pose: &Pose2D) -> PlanStep {
        let mut out = PlanStep::default();
        let Some(goal) = self.goal else {
            return out;
        };
        if self.refused == Some(goal.id) || self.grid.is_none() {
            return out;
        }
        let p = [pose.x, pose.y];
        let deviated = self.path.as_mut().is_some_and(|path| {
            let (_, d) = path.project(p);
            d > self.params.deviation_m
        });
        if self.path.is_none() || self.replan || deviated {
            self.replan = false;
            match self.plan(pose, &goal) {
                Ok(path) => {
                    self.path = Some(path);
                    out.replanned = true;
                }
                Err((_, why)) if !self.can_start_from(pose) => {
                    // A position inside an obstacle or outside the map is a localization
                    // error (e.g. a degraded GPS fix before the switch to SLAM), not a reason
                    // to refuse the goal: hold and plan again from the next position.
                    tracing::debug!("not planning from ({:.2}, {:.2}): {why}", pose.x, pose.y);
                    self.path = None;
                    self.replan = true;
                    return out;
                }
                Err((_, why)) if self.map_may_grow || !self.provider_settled => {
                    // Not in the map as it is, but the map may still grow: hold, and plan
                    // again with the next map or Mapping provider.
                    self.path = None;
                    self.refused = Some(goal.id);
                    self.provisional = true;
                    out.pending = Some(why);
                    return out;
                }
                Err((reason, why)) => {
                    self.path = None;
                    self.refused = Some(goal.id);
                    let mut status = self.status(goal.id, GoalState::Refused, -1.0);
                    status.reason = reason as u8;
                    out.status = Some(status);
                    out.refused = Some(why);
                    return out;
                }
            }
        }
        let Some(path) = self.path.as_mut() else {
            return out;
        };
        let (s, _) = path.project(p);
        let total = path.total();
        let lookahead = match &self.grid {
            Some(grid) if self.clearances.len() == grid.data().len() => carrot_distance(
                &ClearanceField {
                    grid,
                    clearances: &self.clearances,
                },
                path,
                s,
                p,
                self.params.lookahead_m,
                self.params.min_lookahead_m,
                self.params.comfort_m,
                self.params.robot_radius + self.params.clearance,
            ),
            _ => self.params.lookahead_m,
        };
        let target = s + lookahead;
        let is_final = target >= total;
        let (point, heading) = path.at(target);
        let theta = if is_final && goal.use_theta != 0 {
            goal.pose.theta
        } else {
            heading
        };
        out.waypoint = Some(Waypoint {
            header: Header {
                frame_id: FrameId::MAP,
                ..Header::default()
            },
            goal_id: goal.id,
            index: path.seg as u32,
            pose: Pose2D {
                x: point[0],
                y: point[1],
                theta,
            },
            // Slower where the carrot is short (near obstacles), at most by half.
            speed: self.params.speed * (lookahead / self.params.lookahead_m).clamp(0.5, 1.0),
            is_final: u8::from(is_final),
        });
        out.status = Some(self.status(goal.id, GoalState::Active, (total - s).max(0.0)));
        if let Some(now) = now {
            self.check_progress(now, pose, goal.id, (total - s).max(0.0), &mut out);
        }
        out
    }

    /// Progress checking and recovery: may replace the waypoint or refuse the goal.
    fn check_progress(&mut self, now: f64, pose: &Pose2D, id: u32, left: f64, out: &mut PlanStep) {
        let params = self.params.progress;
        let m = self
            .monitor
            .get_or_insert_with(|| ProgressMonitor::new(params, now));
        if std::mem::take(&mut self.rebase) {
            m.rebase(left);
        }
        let (action, events) = m.update(now, (pose.x, pose.y, pose.theta), left);
        for e in &events {
            match e {
                Event::Stalled(_) => self.stalls += 1,
                Event::Started(..) => self.recoveries += 1,
                _ => {}
            }
            let msg = progress_message(e, id, left, self.stalls, self.recoveries);
            out.progress.push(msg);
        }
        match action {
            Action::Follow => {}
            Action::Clear => {
                if let Some(raw) = self.raw.take() {
                    self.set_map(&raw);
                }
                // The same map: its path is no detour to re-base progress on.
                self.rebase = false;
                self.replan = true;
            }
            Action::Replan => self.replan = true,
            Action::Rotate | Action::BackUp(_) => {
                out.waypoint = recovery_waypoint(action, pose, id);
            }
            Action::Fail => {
                self.path = None;
                self.refused = Some(id);
                let mut status = self.status(id, GoalState::Refused, left);
                status.reason = RefusalReason::Stuck as u8;
                out.status = Some(status);
                out.waypoint = None;
                out.refused = out.progress.last().map(NavProgress::describe);
            }
        }
    }
}
