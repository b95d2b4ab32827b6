//! The occupancy grid shared by the simulator, maps, planning and SLAM, laid out like ROS
//! `nav_msgs/OccupancyGrid`.

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
/// `(0, 0)`; the grid's x axis points along `origin_yaw` (0 for every grid hng builds; a
/// map_server map may be rotated). Values: `-1` unknown, `0..=100` occupancy probability in
/// percent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGrid {
    width: u32,
    height: u32,
    resolution: f64,
    origin: [f64; 2],
    #[serde(default)]
    origin_yaw: f64,
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
        Ok(Self::unchecked(
            width,
            height,
            resolution,
            origin,
            vec![fill; n],
        ))
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
        Ok(Self::unchecked(width, height, resolution, origin, data))
    }

    /// A grid of checked dimensions and cells, its x axis along the map's.
    fn unchecked(
        width: u32,
        height: u32,
        resolution: f64,
        origin: [f64; 2],
        data: Vec<i8>,
    ) -> Self {
        Self {
            width,
            height,
            resolution,
            origin,
            origin_yaw: 0.0,
            data,
        }
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
    /// Heading (rad) of the grid's x axis in the map frame; 0 unless the grid came from a
    /// rotated map_server map.
    pub fn origin_yaw(&self) -> f64 {
        self.origin_yaw
    }
    /// The header of this grid's message on a map channel (frame `map`, no stamp); the
    /// cells are [`OccupancyGrid::data`].
    pub fn info(&self) -> crate::msg::GridInfo {
        crate::msg::GridInfo {
            header: crate::msg::Header {
                frame_id: crate::msg::FrameId::MAP,
                ..crate::msg::Header::default()
            },
            resolution: self.resolution as f32,
            width: self.width,
            height: self.height,
            origin: crate::msg::Pose2D::new(self.origin[0], self.origin[1], self.origin_yaw),
        }
    }
    /// The same grid with its x axis turned by `yaw` radians about `origin`.
    #[must_use]
    pub fn with_origin_yaw(mut self, yaw: f64) -> Self {
        self.origin_yaw = if yaw.is_finite() { yaw } else { 0.0 };
        self
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
        let (mut dx, mut dy) = (wx - self.origin[0], wy - self.origin[1]);
        if self.origin_yaw != 0.0 {
            let (s, c) = self.origin_yaw.sin_cos();
            (dx, dy) = (c * dx + s * dy, -s * dx + c * dy);
        }
        (
            (dx / self.resolution).floor() as i64,
            (dy / self.resolution).floor() as i64,
        )
    }

    /// Map-frame centre of cell `(x, y)`.
    #[inline]
    pub fn cell_to_world(&self, x: i64, y: i64) -> [f64; 2] {
        let u = (x as f64 + 0.5) * self.resolution;
        let v = (y as f64 + 0.5) * self.resolution;
        if self.origin_yaw == 0.0 {
            return [self.origin[0] + u, self.origin[1] + v];
        }
        let (s, c) = self.origin_yaw.sin_cos();
        [
            self.origin[0] + c * u - s * v,
            self.origin[1] + s * u + c * v,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_and_points_round_trip_on_a_rotated_grid() -> Result<(), GridError> {
        let g = OccupancyGrid::new(10, 8, 0.5, [1.0, -2.0], FREE)?
            .with_origin_yaw(std::f64::consts::FRAC_PI_2);
        // Rotated by 90 degrees: the grid's x axis points along the map's y axis.
        let c = g.cell_to_world(0, 0);
        assert!(
            (c[0] - 0.75).abs() < 1e-12 && (c[1] - -1.75).abs() < 1e-12,
            "{c:?}"
        );
        for (x, y) in [(0, 0), (3, 5), (9, 7)] {
            let w = g.cell_to_world(x, y);
            assert_eq!(g.world_to_cell(w[0], w[1]), (x, y));
        }
        Ok(())
    }

    #[test]
    fn bad_grids_are_refused_with_the_reason() {
        assert!(matches!(
            OccupancyGrid::new(0, 3, 1.0, [0.0; 2], FREE),
            Err(GridError::BadSize { .. })
        ));
        assert!(matches!(
            OccupancyGrid::from_data(2, 1, 1.0, [0.0; 2], vec![0, 101]),
            Err(GridError::BadCellValue { index: 1, .. })
        ));
    }
}
