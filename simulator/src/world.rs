//! The world description: walls, boxes, beacons, robot and sensor settings.
//!
//! A world is read from a TOML file ([`World::load`]), built from a ROS map_server occupancy map
//! ([`World::from_occupancy_map`]), taken from the built-in default ([`World::default_world`]) or
//! assembled in code. All units are SI (metres, radians, seconds); angles are counter-clockwise,
//! x forward, y left (ROS REP-103). Every field except `robot` has a default, and unknown fields
//! are errors.

use std::f64::consts::{PI, TAU};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::error::{Result, SimError, line_col};
use crate::map::{OccupancyGrid, grid_boxes, grid_from_world};
use crate::script::{LightingZone, WorldEvent};

pub use hng_runtime::msg::Pose2D;

/// The whole simulated world. See the crate documentation for a complete TOML example.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct World {
    /// A name for logs.
    #[serde(default = "default_name")]
    pub name: String,
    /// Seed of every noise source. Same seed and same commands give bit-identical sensor streams.
    #[serde(default)]
    pub seed: u64,
    /// Physics time step in seconds (default 0.01).
    #[serde(default = "default_dt")]
    pub dt_s: f64,
    /// The robot.
    pub robot: RobotConfig,
    /// Straight walls.
    #[serde(default)]
    pub walls: Vec<Wall>,
    /// Rectangular obstacles.
    #[serde(default)]
    pub boxes: Vec<BoxObstacle>,
    /// Beacons the camera can see.
    #[serde(default)]
    pub beacons: Vec<Beacon>,
    /// Occupancy maps (ROS map_server YAML) whose occupied cells become walls.
    #[serde(default)]
    pub maps: Vec<MapRef>,
    /// Sensor settings.
    #[serde(default)]
    pub sensors: SensorsConfig,
    /// Timed changes of the world (see [`crate::script`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<WorldEvent>,
    /// Places where the camera sees darker or brighter (see [`crate::script`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub lighting_zones: Vec<LightingZone>,
    /// Boxes read from `maps` when the world was loaded (not part of the file format).
    #[serde(skip)]
    pub map_boxes: Vec<BoxObstacle>,
}

fn default_name() -> String {
    "unnamed".to_owned()
}
fn default_dt() -> f64 {
    0.01
}

/// A reference to a ROS map_server map (YAML + image) used as a source of walls.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapRef {
    /// Path of the map YAML, relative to the world file.
    pub yaml: PathBuf,
}

/// Robot shape, start pose and motion limits (a differential-drive disc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Start pose in the map frame.
    pub start: Pose2D,
    /// Radius of the robot disc, metres (default 0.2).
    #[serde(default = "RobotConfig::default_radius")]
    pub radius: f64,
    /// Maximum forward/backward speed, m/s (default 1.0).
    #[serde(default = "RobotConfig::default_max_linear_speed")]
    pub max_linear_speed: f64,
    /// Maximum turn rate, rad/s (default 2.0).
    #[serde(default = "RobotConfig::default_max_angular_speed")]
    pub max_angular_speed: f64,
    /// Maximum linear acceleration, m/s² (default 2.0).
    #[serde(default = "RobotConfig::default_max_linear_accel")]
    pub max_linear_accel: f64,
    /// Maximum angular acceleration, rad/s² (default 6.0).
    #[serde(default = "RobotConfig::default_max_angular_accel")]
    pub max_angular_accel: f64,
    /// The robot stops when no command arrived for this long, seconds (default 0.5).
    #[serde(default = "RobotConfig::default_cmd_timeout")]
    pub cmd_timeout_s: f64,
}

impl RobotConfig {
    fn default_radius() -> f64 {
        0.2
    }
    fn default_max_linear_speed() -> f64 {
        1.0
    }
    fn default_max_angular_speed() -> f64 {
        2.0
    }
    fn default_max_linear_accel() -> f64 {
        2.0
    }
    fn default_max_angular_accel() -> f64 {
        6.0
    }
    fn default_cmd_timeout() -> f64 {
        0.5
    }

    /// Default limits with the given start pose.
    #[must_use]
    pub fn at(start: Pose2D) -> Self {
        Self {
            start,
            radius: Self::default_radius(),
            max_linear_speed: Self::default_max_linear_speed(),
            max_angular_speed: Self::default_max_angular_speed(),
            max_linear_accel: Self::default_max_linear_accel(),
            max_angular_accel: Self::default_max_angular_accel(),
            cmd_timeout_s: Self::default_cmd_timeout(),
        }
    }
}

/// A straight wall from `from` to `to`. It is built as a box `thickness` wide, centred on the
/// segment, with square caps that extend `thickness / 2` past both ends so that corners close.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wall {
    /// Start point [x, y], metres.
    pub from: [f64; 2],
    /// End point [x, y], metres.
    pub to: [f64; 2],
    /// Thickness, metres (default 0.05).
    #[serde(default = "Wall::default_thickness")]
    pub thickness: f64,
    /// Colour [r, g, b] in camera images (default: a shade picked from the wall's position).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<[u8; 3]>,
}

impl Wall {
    fn default_thickness() -> f64 {
        0.05
    }

    /// A wall of the default thickness (5 cm).
    #[must_use]
    pub fn new(from: [f64; 2], to: [f64; 2]) -> Self {
        Self {
            from,
            to,
            thickness: Self::default_thickness(),
            color: None,
        }
    }

    /// The box this wall is built as.
    #[must_use]
    pub fn to_box(&self) -> BoxObstacle {
        let dx = self.to[0] - self.from[0];
        let dy = self.to[1] - self.from[1];
        let len = dx.hypot(dy);
        BoxObstacle {
            center: [
                (self.from[0] + self.to[0]) / 2.0,
                (self.from[1] + self.to[1]) / 2.0,
            ],
            size: [len + self.thickness, self.thickness],
            angle: if len > 0.0 { dy.atan2(dx) } else { 0.0 },
            color: self.color,
        }
    }
}

/// A rectangular obstacle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxObstacle {
    /// Centre [x, y], metres.
    pub center: [f64; 2],
    /// Full size [along its x axis, along its y axis], metres.
    pub size: [f64; 2],
    /// Rotation, radians (default 0).
    #[serde(default)]
    pub angle: f64,
    /// Colour [r, g, b] in camera images (default: a shade picked from the box's position).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<[u8; 3]>,
}

impl BoxObstacle {
    /// The four corners, counter-clockwise.
    #[must_use]
    pub fn corners(&self) -> [[f64; 2]; 4] {
        let (s, c) = self.angle.sin_cos();
        let hx = self.size[0] / 2.0;
        let hy = self.size[1] / 2.0;
        [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)].map(|(u, v)| {
            [
                self.center[0] + c * u - s * v,
                self.center[1] + s * u + c * v,
            ]
        })
    }
}

/// A beacon the camera reports by id.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Beacon {
    /// Identifier reported by the camera (unique).
    pub id: u32,
    /// Position [x, y], metres.
    pub position: [f64; 2],
    /// Radius, metres (default 0.1). Beacons are markers, not obstacles: the robot drives through
    /// them; a beacon is occluded when a wall lies on the line of sight closer than
    /// `distance - radius`.
    #[serde(default = "Beacon::default_radius")]
    pub radius: f64,
}

impl Beacon {
    fn default_radius() -> f64 {
        0.1
    }
}

/// Settings of all simulated sensors. A disabled sensor publishes nothing, so a real driver or a
/// replayed log can provide that channel instead (hybrid simulation).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorsConfig {
    /// 2D lidar.
    #[serde(default)]
    pub lidar: LidarConfig,
    /// Wheel odometry.
    #[serde(default)]
    pub odometry: OdometryConfig,
    /// GPS/IMU-like absolute pose.
    #[serde(default)]
    pub gps: GpsConfig,
    /// Beacon camera.
    #[serde(default)]
    pub camera: CameraConfig,
    /// Ground-truth pose (for evaluation only).
    #[serde(default)]
    pub ground_truth: GroundTruthConfig,
}

/// 2D lidar at the robot centre. Beams are spread evenly over `fov`, centred on the heading; a
/// full circle (`fov` = 2π) has no duplicate beam.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct LidarConfig {
    /// Simulate this sensor (default true).
    #[default(true)]
    pub enabled: bool,
    /// Number of beams (default 360).
    #[default(360)]
    pub beams: u32,
    /// Field of view, radians (default 2π).
    #[default(TAU)]
    pub fov: f64,
    /// Scans per second (default 10).
    #[default(10.0)]
    pub rate: f64,
    /// Maximum range, metres (default 10). No return gives +inf.
    #[default(10.0)]
    pub max_range: f64,
    /// Minimum range, metres (default 0.05). Closer returns give -inf (REP-117).
    #[default(0.05)]
    pub min_range: f64,
    /// Standard deviation of the Gaussian range noise, metres (default 0.01).
    #[default(0.01)]
    pub range_sigma: f64,
}

/// Wheel odometry: the true motion of each physics step, in the robot frame, is distorted and
/// integrated into a pose in the odom frame (which starts at the identity at the start pose).
///
/// Per physics step with true travel `d` (metres) and rotation `dθ` (radians):
/// `d' = d (1 + linear_scale_error) + N(0, (linear_noise·|d|)²)` and
/// `dθ' = dθ (1 + angular_scale_error) + heading_drift·d + N(0, (angular_noise·|dθ| + angular_noise_per_metre·|d|)²)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct OdometryConfig {
    /// Simulate this sensor (default true).
    #[default(true)]
    pub enabled: bool,
    /// Messages per second (default 50).
    #[default(50.0)]
    pub rate: f64,
    /// Systematic distance scale error, fraction (default 0.01).
    #[default(0.01)]
    pub linear_scale_error: f64,
    /// Systematic rotation scale error, fraction (default 0.02).
    #[default(0.02)]
    pub angular_scale_error: f64,
    /// Systematic heading drift per metre driven, rad/m (default 0.005; unequal wheels).
    #[default(0.005)]
    pub heading_drift: f64,
    /// Random distance error, fraction of the distance (default 0.02).
    #[default(0.02)]
    pub linear_noise: f64,
    /// Random rotation error, fraction of the rotation (default 0.02).
    #[default(0.02)]
    pub angular_noise: f64,
    /// Random rotation error per metre driven, rad/m (default 0.002).
    #[default(0.002)]
    pub angular_noise_per_metre: f64,
}

impl OdometryConfig {
    /// Odometry without any error.
    #[must_use]
    pub fn noise_free() -> Self {
        Self {
            linear_scale_error: 0.0,
            angular_scale_error: 0.0,
            heading_drift: 0.0,
            linear_noise: 0.0,
            angular_noise: 0.0,
            angular_noise_per_metre: 0.0,
            ..Self::default()
        }
    }
}

/// GPS/IMU-like absolute pose in the map frame with Gaussian noise, and zones where the fix is
/// degraded (noise multiplied) or lost.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct GpsConfig {
    /// Simulate this sensor (default true).
    #[default(true)]
    pub enabled: bool,
    /// Fixes per second (default 5).
    #[default(5.0)]
    pub rate: f64,
    /// Standard deviation of x and y, metres (default 0.3).
    #[default(0.3)]
    pub position_sigma: f64,
    /// Standard deviation of the heading, radians (default 0.03).
    #[default(0.03)]
    pub yaw_sigma: f64,
    /// Outage and degraded zones; where zones overlap an outage wins, else the largest multiplier.
    pub zones: Vec<GpsZone>,
}

/// What a GPS zone does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GpsZoneKind {
    /// No fix inside.
    Outage,
    /// Noise multiplied by `noise_multiplier` inside.
    Degraded,
}

/// An axis-aligned rectangle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rect {
    /// Lower-left corner [x, y].
    pub min: [f64; 2],
    /// Upper-right corner [x, y].
    pub max: [f64; 2],
}

/// A circle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Circle {
    /// Centre [x, y].
    pub center: [f64; 2],
    /// Radius, metres.
    pub radius: f64,
}

/// A GPS outage or degraded zone: exactly one of `rect` and `circle`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpsZone {
    /// Optional name for logs.
    #[serde(default)]
    pub name: String,
    /// `outage` or `degraded`.
    pub kind: GpsZoneKind,
    /// Rectangle shape.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rect: Option<Rect>,
    /// Circle shape.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub circle: Option<Circle>,
    /// Noise multiplier inside a degraded zone (default 5, at least 1).
    #[serde(default = "GpsZone::default_multiplier")]
    pub noise_multiplier: f64,
}

impl GpsZone {
    fn default_multiplier() -> f64 {
        5.0
    }

    /// Whether the point lies inside the zone.
    #[must_use]
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let in_rect = self
            .rect
            .is_some_and(|r| x >= r.min[0] && x <= r.max[0] && y >= r.min[1] && y <= r.max[1]);
        let in_circle = self
            .circle
            .is_some_and(|c| (x - c.center[0]).hypot(y - c.center[1]) <= c.radius);
        in_rect || in_circle
    }
}

/// Camera that reports beacons (id, bearing, distance) inside its field of view and range and
/// not occluded by walls. Mounted at the robot centre, looking forward.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Simulate this sensor (default true).
    #[default(true)]
    pub enabled: bool,
    /// Frames per second (default 5).
    #[default(5.0)]
    pub rate: f64,
    /// Horizontal field of view, radians (default 1.2, about 69°).
    #[default(1.2)]
    pub fov: f64,
    /// Maximum detection distance, metres (default 8).
    #[default(8.0)]
    pub max_range: f64,
    /// Standard deviation of the bearing, radians (default 0.01).
    #[default(0.01)]
    pub bearing_sigma: f64,
    /// Standard deviation of the distance, metres (default 0.05).
    #[default(0.05)]
    pub range_sigma: f64,
    /// Render RGB8 images (`sim/camera/image`, `ImageInfo` + bytes) with the same `fov`
    /// (default true); the beacon list above stays as ground truth.
    #[default(true)]
    pub image: bool,
    /// Images per second (default 15).
    #[default(15.0)]
    pub image_rate: f64,
    /// Image width, pixels (default 320).
    #[default(320)]
    pub width: u32,
    /// Image height, pixels (default 240).
    #[default(240)]
    pub height: u32,
    /// Standard deviation of the pixel noise, 8-bit steps (default 2).
    #[default(2.0)]
    pub noise_sigma: f64,
    /// Lighting factor of the images at the start (1 normal, lower is darker; default 1).
    #[default(1.0)]
    pub lighting: f64,
}

/// Ground-truth pose for evaluation (never feed it to the robot's modules).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct GroundTruthConfig {
    /// Publish ground truth (default true).
    #[default(true)]
    pub enabled: bool,
    /// Messages per second (default 100).
    #[default(100.0)]
    pub rate: f64,
}

impl World {
    /// An empty world (no walls) with default settings and the robot at `start`.
    #[must_use]
    pub fn empty(start: Pose2D) -> Self {
        Self {
            name: default_name(),
            seed: 0,
            dt_s: default_dt(),
            robot: RobotConfig::at(start),
            walls: Vec::new(),
            boxes: Vec::new(),
            beacons: Vec::new(),
            maps: Vec::new(),
            sensors: SensorsConfig::default(),
            events: Vec::new(),
            lighting_zones: Vec::new(),
            map_boxes: Vec::new(),
        }
    }

    /// Reads a world TOML file; maps it references are loaded relative to its folder.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let src =
            std::fs::read_to_string(path).map_err(|e| SimError::io(path, "cannot read", e))?;
        Self::from_toml_str(&src, path)
    }

    /// Parses a world from TOML text. `path` names the file in errors; maps are loaded relative
    /// to its folder.
    pub fn from_toml_str(src: &str, path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let mut world: World = toml::from_str(src).map_err(|e| {
            let offset = e.span().map_or(0, |s| s.start);
            let (line, column) = line_col(src, offset);
            let message = hng_runtime::module::renamed_to_seconds(e.message())
                .unwrap_or_else(|| e.message().trim().to_owned());
            let mut field = toml_field_at(src, offset);
            if let Some(missing) = backticked(&message, "missing field `") {
                field = join_field(&field, missing);
            }
            if field.is_empty() {
                field = "(top level)".to_owned();
            }
            SimError::parse(path, (line, column), field, message)
        })?;
        world.validate().map_err(|e| match e {
            SimError::Invalid { field, message } => {
                SimError::parse(path, locate_toml_field(src, &field), field, message)
            }
            other => other,
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        for map in &world.maps {
            let grid = OccupancyGrid::load(base.join(&map.yaml))?;
            world.map_boxes.extend(grid_boxes(&grid));
        }
        Ok(world)
    }

    /// A world whose walls are the occupied cells of a ROS map_server map, with default settings
    /// and the robot at `start`.
    pub fn from_occupancy_map(yaml: impl AsRef<Path>, start: Pose2D) -> Result<Self> {
        let yaml = yaml.as_ref();
        let grid = OccupancyGrid::load(yaml)?;
        let mut world = Self::empty(start);
        world.name = yaml.display().to_string();
        world.maps.push(MapRef {
            yaml: yaml.to_path_buf(),
        });
        world.map_boxes = grid_boxes(&grid);
        Ok(world)
    }

    /// The world as TOML text (maps stay references; `map_boxes` are not written).
    pub fn to_toml_string(&self) -> Result<String> {
        toml::to_string(self).map_err(|e| SimError::invalid("(world)", e.to_string()))
    }

    /// Every obstacle as a box: walls, boxes and map cells.
    #[must_use]
    pub fn obstacle_boxes(&self) -> Vec<BoxObstacle> {
        self.walls
            .iter()
            .map(Wall::to_box)
            .chain(self.boxes.iter().copied())
            .chain(self.map_boxes.iter().copied())
            .collect()
    }

    /// Writes the ground-truth occupancy map of this world (map_server PGM + YAML) at
    /// `resolution` metres per pixel. The image goes next to `yaml` with the extension `pgm`.
    pub fn write_occupancy_map(&self, yaml: impl AsRef<Path>, resolution: f64) -> Result<()> {
        Ok(grid_from_world(self, resolution)?.save(yaml)?)
    }
}

mod default;
mod toml_locate;
mod validate;

use toml_locate::{backticked, join_field, locate_toml_field, toml_field_at};
pub(crate) use validate::{check, check_finite, check_nonneg, check_pos};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_world_is_valid_and_round_trips_through_toml() -> Result<()> {
        let w = World::default_world();
        w.validate()?;
        let text = w.to_toml_string()?;
        let back = World::from_toml_str(&text, "default.toml")?;
        assert_eq!(back, w);
        Ok(())
    }
}
