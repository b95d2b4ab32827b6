//! The occupancy grid shared by planning and SLAM, laid out like ROS `nav_msgs/OccupancyGrid`.

use serde::{Deserialize, Serialize};

/// Cell value of an unknown cell.
pub const UNKNOWN: i8 = -1;
/// Cell value of a certainly free cell.
pub const FREE: i8 = 0;
/// Cell value of a certainly occupied cell.
pub const OCCUPIED: i8 = 100;

/// A 2D occupancy grid in the map frame.
///
/// Layout follows ROS `nav_msgs/OccupancyGrid`: `data` is row-major, row 0 is
/// the row with the smallest y, cell `(x, y)` is `data[y * width + x]`, and
/// `origin` is the map-frame position of the lower-left corner of cell
/// `(0, 0)`. Values: `-1` unknown, `0..=100` occupancy probability in percent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGrid {
    width: u32,
    height: u32,
    resolution: f64,
    origin: [f64; 2],
    data: Vec<i8>,
}

/// Why an [`OccupancyGrid`] could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    /// Width or height is zero, or `width * height` overflows.
    #[error(
        "grid size {width}x{height} is invalid: both must be > 0 and the product must fit in memory"
    )]
    BadSize {
        /// Requested width in cells.
        width: u32,
        /// Requested height in cells.
        height: u32,
    },
    /// Resolution is not a finite positive number.
    #[error("grid resolution {0} m/cell is invalid: it must be finite and > 0")]
    BadResolution(f64),
    /// Data length does not match `width * height`.
    #[error("grid data has {got} cells but width*height is {expected}")]
    BadDataLength {
        /// `width * height`.
        expected: usize,
        /// Length of the given data.
        got: usize,
    },
    /// A cell value is outside `-1..=100`.
    #[error("grid cell {index} has value {value}, expected -1 (unknown) or 0..=100")]
    BadCellValue {
        /// Linear index of the offending cell.
        index: usize,
        /// Its value.
        value: i8,
    },
}

impl OccupancyGrid {
    /// A grid filled with `fill`.
    pub fn new(
        width: u32,
        height: u32,
        resolution: f64,
        origin: [f64; 2],
        fill: i8,
    ) -> Result<Self, GridError> {
        let n = Self::check_dims(width, height, resolution)?;
        if !(UNKNOWN..=OCCUPIED).contains(&fill) {
            return Err(GridError::BadCellValue {
                index: 0,
                value: fill,
            });
        }
        Ok(Self {
            width,
            height,
            resolution,
            origin,
            data: vec![fill; n],
        })
    }

    /// A grid from existing row-major data (row 0 = lowest y).
    pub fn from_data(
        width: u32,
        height: u32,
        resolution: f64,
        origin: [f64; 2],
        data: Vec<i8>,
    ) -> Result<Self, GridError> {
        let n = Self::check_dims(width, height, resolution)?;
        if data.len() != n {
            return Err(GridError::BadDataLength {
                expected: n,
                got: data.len(),
            });
        }
        if let Some((index, &value)) = data
            .iter()
            .enumerate()
            .find(|(_, v)| !(UNKNOWN..=OCCUPIED).contains(*v))
        {
            return Err(GridError::BadCellValue { index, value });
        }
        Ok(Self {
            width,
            height,
            resolution,
            origin,
            data,
        })
    }

    fn check_dims(width: u32, height: u32, resolution: f64) -> Result<usize, GridError> {
        if !(resolution.is_finite() && resolution > 0.0) {
            return Err(GridError::BadResolution(resolution));
        }
        let n = (width as usize).checked_mul(height as usize);
        match n {
            Some(n) if width > 0 && height > 0 && n <= u32::MAX as usize => Ok(n),
            _ => Err(GridError::BadSize { width, height }),
        }
    }

    /// Width in cells.
    pub fn width(&self) -> u32 {
        self.width
    }
    /// Height in cells.
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Cell edge length in metres.
    pub fn resolution(&self) -> f64 {
        self.resolution
    }
    /// Map-frame position (m) of the lower-left corner of cell (0, 0).
    pub fn origin(&self) -> [f64; 2] {
        self.origin
    }
    /// Row-major cells, row 0 = lowest y.
    pub fn data(&self) -> &[i8] {
        &self.data
    }

    /// Linear index of cell `(x, y)`, if inside.
    #[inline]
    pub fn index(&self, x: i64, y: i64) -> Option<usize> {
        if x >= 0 && y >= 0 && x < self.width as i64 && y < self.height as i64 {
            Some(y as usize * self.width as usize + x as usize)
        } else {
            None
        }
    }

    /// Value of cell `(x, y)`, if inside.
    #[inline]
    pub fn get(&self, x: i64, y: i64) -> Option<i8> {
        self.index(x, y).map(|i| self.data[i])
    }

    /// Sets cell `(x, y)`; values are clamped to `-1..=100`. Returns false if outside.
    pub fn set(&mut self, x: i64, y: i64, value: i8) -> bool {
        match self.index(x, y) {
            Some(i) => {
                self.data[i] = value.clamp(UNKNOWN, OCCUPIED);
                true
            }
            None => false,
        }
    }

    /// Cell containing the map-frame point `(wx, wy)` (may be outside the grid).
    #[inline]
    pub fn world_to_cell(&self, wx: f64, wy: f64) -> (i64, i64) {
        (
            ((wx - self.origin[0]) / self.resolution).floor() as i64,
            ((wy - self.origin[1]) / self.resolution).floor() as i64,
        )
    }

    /// Map-frame centre of cell `(x, y)`.
    #[inline]
    pub fn cell_to_world(&self, x: i64, y: i64) -> [f64; 2] {
        [
            self.origin[0] + (x as f64 + 0.5) * self.resolution,
            self.origin[1] + (y as f64 + 0.5) * self.resolution,
        ]
    }
}
