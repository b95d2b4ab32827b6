//! Algorithm cores of hng's modules, as pure libraries without I/O to the
//! runtime: [`planning`] (occupancy grids, A*, MovingAI validation) and
//! [`slam`] (CARMEN logs, scan matching, occupancy mapping, a SLAM front end).

pub mod planning;
pub mod slam;

/// Re-exported so users of the SLAM API (poses are `nalgebra` types) need not
/// depend on a matching version themselves.
pub use nalgebra;
