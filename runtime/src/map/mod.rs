//! Occupancy grids: the one definition shared by the simulator, the map server, planning and
//! SLAM, and the ROS map_server file format (PGM + YAML) they are read from and written to.

mod grid;
mod map_server;

pub use grid::{FREE, GridError, OCCUPIED, OccupancyGrid, UNKNOWN};
pub use map_server::MapFileError;
