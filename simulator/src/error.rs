//! Errors of the simulator crate.

use std::path::PathBuf;

use hng_runtime::map::MapFileError;

/// Everything that can go wrong when loading a world or map, or building a simulator.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A velocity command was NaN or infinite; the robot was told to stop instead.
    #[error(
        "rejected velocity command linear_x={linear_x}, angular_z={angular_z}: not finite; stopping"
    )]
    RejectedCommand {
        /// Commanded forward speed.
        linear_x: f64,
        /// Commanded turn rate.
        angular_z: f64,
    },
    /// A file could not be read or written, or a world file, map YAML or PGM image is
    /// malformed (`Parse`: 1-based line and column, the dotted path of the offending field,
    /// e.g. `sensors.lidar.beams` or `walls[2].thickness`). One error type for every file.
    #[error(transparent)]
    Map(#[from] hng_runtime::map::MapFileError),
    /// A world built in code (not parsed from a file) has an invalid value.
    #[error("invalid world: field `{field}`: {message}")]
    Invalid {
        /// Dotted path of the offending field.
        field: String,
        /// What is wrong.
        message: String,
    },
}

impl SimError {
    pub(crate) fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        SimError::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    pub(crate) fn io(
        path: impl Into<PathBuf>,
        action: &'static str,
        source: std::io::Error,
    ) -> Self {
        SimError::Map(MapFileError::Io {
            path: path.into(),
            action,
            source,
        })
    }

    pub(crate) fn parse(
        path: impl Into<PathBuf>,
        (line, column): (usize, usize),
        field: String,
        message: String,
    ) -> Self {
        SimError::Map(MapFileError::Parse {
            path: path.into(),
            line,
            column,
            field,
            message,
        })
    }
}

/// Result alias of this crate.
pub type Result<T, E = SimError> = std::result::Result<T, E>;

/// 1-based (line, column) of a byte offset in `src`.
pub(crate) fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(src.len());
    let before = src.get(..offset).unwrap_or(src);
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before.get(line_start..).map_or(0, |s| s.chars().count()) + 1;
    (line, column)
}
