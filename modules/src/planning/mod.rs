//! Planning: occupancy grids, obstacle inflation, 8-connected A* and path
//! simplification, plus MovingAI benchmark I/O for validation.
//!
//! The planner is exact for the MovingAI "octile" rules: 8-connected moves,
//! cost 1 orthogonal and √2 diagonal, no corner cutting (a diagonal move is
//! allowed only if both orthogonally adjacent cells are passable). The
//! heuristic is the octile distance, which is consistent for these costs, so
//! every closed cell has its optimal cost and the returned path is optimal.
//! The open list is a binary heap ordered by f, ties broken towards larger g
//! (fewer expansions on open ground). Buffers are generation-stamped and kept
//! in [`GridPlanner`], so a query touches only the cells it expands.
//!
//! Typical use: inflate the SLAM map by the robot radius with [`inflate`],
//! then [`GridPlanner::plan`] in map coordinates, and [`simplify`] the exact
//! grid path into waypoints for the controller.

mod astar;
pub(crate) mod carrot;
mod clearance;
pub mod config;
pub mod core;
pub mod costmap;
mod inflate;
pub mod movingai;
pub(crate) mod path;
pub mod progress;
mod smooth;

pub use astar::{
    GridPath, GridPlanner, NEIGHBOURS, Path, PlanError, PlannerConfig, SQRT_2, octile,
    path_length_cells,
};
pub use clearance::path_clearance;
pub use costmap::{Costmap, CostmapConfig, inflation_cost, resample};
pub use hng_runtime::map::{FREE, GridError, OCCUPIED, OccupancyGrid, UNKNOWN};
pub use inflate::{InflationConfig, inflate, squared_distance_transform};
pub use movingai::{MovingAiError, PlannerEval, eval_movingai};
pub use smooth::{line_of_sight, line_of_sight_by, simplify, simplify_with_cost};
