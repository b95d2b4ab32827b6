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
    pub dt: f64,
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
    pub cmd_timeout: f64,
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
            cmd_timeout: Self::default_cmd_timeout(),
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LidarConfig {
    /// Simulate this sensor (default true).
    pub enabled: bool,
    /// Number of beams (default 360).
    pub beams: u32,
    /// Field of view, radians (default 2π).
    pub fov: f64,
    /// Scans per second (default 10).
    pub rate: f64,
    /// Maximum range, metres (default 10). No return gives +inf.
    pub max_range: f64,
    /// Minimum range, metres (default 0.05). Closer returns give -inf (REP-117).
    pub min_range: f64,
    /// Standard deviation of the Gaussian range noise, metres (default 0.01).
    pub range_sigma: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            beams: 360,
            fov: TAU,
            rate: 10.0,
            max_range: 10.0,
            min_range: 0.05,
            range_sigma: 0.01,
        }
    }
}

/// Wheel odometry: the true motion of each physics step, in the robot frame, is distorted and
/// integrated into a pose in the odom frame (which starts at the identity at the start pose).
///
/// Per physics step with true travel `d` (metres) and rotation `dθ` (radians):
/// `d' = d (1 + linear_scale_error) + N(0, (linear_noise·|d|)²)` and
/// `dθ' = dθ (1 + angular_scale_error) + heading_drift·d + N(0, (angular_noise·|dθ| + angular_noise_per_metre·|d|)²)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OdometryConfig {
    /// Simulate this sensor (default true).
    pub enabled: bool,
    /// Messages per second (default 50).
    pub rate: f64,
    /// Systematic distance scale error, fraction (default 0.01).
    pub linear_scale_error: f64,
    /// Systematic rotation scale error, fraction (default 0.02).
    pub angular_scale_error: f64,
    /// Systematic heading drift per metre driven, rad/m (default 0.005; unequal wheels).
    pub heading_drift: f64,
    /// Random distance error, fraction of the distance (default 0.02).
    pub linear_noise: f64,
    /// Random rotation error, fraction of the rotation (default 0.02).
    pub angular_noise: f64,
    /// Random rotation error per metre driven, rad/m (default 0.002).
    pub angular_noise_per_metre: f64,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate: 50.0,
            linear_scale_error: 0.01,
            angular_scale_error: 0.02,
            heading_drift: 0.005,
            linear_noise: 0.02,
            angular_noise: 0.02,
            angular_noise_per_metre: 0.002,
        }
    }
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpsConfig {
    /// Simulate this sensor (default true).
    pub enabled: bool,
    /// Fixes per second (default 5).
    pub rate: f64,
    /// Standard deviation of x and y, metres (default 0.3).
    pub position_sigma: f64,
    /// Standard deviation of the heading, radians (default 0.03).
    pub yaw_sigma: f64,
    /// Outage and degraded zones; where zones overlap an outage wins, else the largest multiplier.
    pub zones: Vec<GpsZone>,
}

impl Default for GpsConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate: 5.0,
            position_sigma: 0.3,
            yaw_sigma: 0.03,
            zones: Vec::new(),
        }
    }
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Simulate this sensor (default true).
    pub enabled: bool,
    /// Frames per second (default 5).
    pub rate: f64,
    /// Horizontal field of view, radians (default 1.2, about 69°).
    pub fov: f64,
    /// Maximum detection distance, metres (default 8).
    pub max_range: f64,
    /// Standard deviation of the bearing, radians (default 0.01).
    pub bearing_sigma: f64,
    /// Standard deviation of the distance, metres (default 0.05).
    pub range_sigma: f64,
    /// Render RGB8 images (`sim/camera/image`, `ImageInfo` + bytes) with the same `fov`
    /// (default true); the beacon list above stays as ground truth.
    pub image: bool,
    /// Images per second (default 15).
    pub image_rate: f64,
    /// Image width, pixels (default 320).
    pub width: u32,
    /// Image height, pixels (default 240).
    pub height: u32,
    /// Standard deviation of the pixel noise, 8-bit steps (default 2).
    pub noise_sigma: f64,
    /// Lighting factor of the images at the start (1 normal, lower is darker; default 1).
    pub lighting: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate: 5.0,
            fov: 1.2,
            max_range: 8.0,
            bearing_sigma: 0.01,
            range_sigma: 0.05,
            image: true,
            image_rate: 15.0,
            width: 320,
            height: 240,
            noise_sigma: 2.0,
            lighting: 1.0,
        }
    }
}

/// Ground-truth pose for evaluation (never feed it to the robot's modules).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GroundTruthConfig {
    /// Publish ground truth (default true).
    pub enabled: bool,
    /// Messages per second (default 100).
    pub rate: f64,
}

impl Default for GroundTruthConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate: 100.0,
        }
    }
}

impl World {
    /// An empty world (no walls) with default settings and the robot at `start`.
    #[must_use]
    pub fn empty(start: Pose2D) -> Self {
        Self {
            name: default_name(),
            seed: 0,
            dt: default_dt(),
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
            let message = e.message().trim().to_owned();
            let mut field = toml_field_at(src, offset);
            if let Some(missing) = backticked(&message, "missing field `") {
                field = join_field(&field, missing);
            }
            SimError::Parse {
                path: path.to_path_buf(),
                line,
                column,
                field: if field.is_empty() {
                    "(top level)".to_owned()
                } else {
                    field
                },
                message,
            }
        })?;
        world.validate().map_err(|e| match e {
            SimError::Invalid { field, message } => {
                let (line, column) = locate_toml_field(src, &field);
                SimError::Parse {
                    path: path.to_path_buf(),
                    line,
                    column,
                    field,
                    message,
                }
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

    /// Checks every value; errors name the field.
    pub fn validate(&self) -> Result<()> {
        check(
            self.dt.is_finite() && self.dt > 0.0 && self.dt <= 1.0,
            "dt",
            "must be in (0, 1] seconds",
        )?;
        check(self.dt * 1e9 >= 1.0, "dt", "must be at least 1 ns")?;
        let r = &self.robot;
        check_finite(&[r.start.x, r.start.y, r.start.theta], "robot.start")?;
        check_pos(r.radius, "robot.radius")?;
        check_pos(r.max_linear_speed, "robot.max_linear_speed")?;
        check_pos(r.max_angular_speed, "robot.max_angular_speed")?;
        check_pos(r.max_linear_accel, "robot.max_linear_accel")?;
        check_pos(r.max_angular_accel, "robot.max_angular_accel")?;
        check_pos(r.cmd_timeout, "robot.cmd_timeout")?;
        for (i, w) in self.walls.iter().enumerate() {
            check_finite(&[w.from[0], w.from[1]], &format!("walls[{i}].from"))?;
            check_finite(&[w.to[0], w.to[1]], &format!("walls[{i}].to"))?;
            check_pos(w.thickness, &format!("walls[{i}].thickness"))?;
        }
        for (i, b) in self.boxes.iter().enumerate() {
            check_finite(&[b.center[0], b.center[1]], &format!("boxes[{i}].center"))?;
            check(
                b.size.iter().all(|s| s.is_finite() && *s > 0.0),
                &format!("boxes[{i}].size"),
                "both sizes must be finite and > 0",
            )?;
            check_finite(&[b.angle], &format!("boxes[{i}].angle"))?;
        }
        for (i, b) in self.beacons.iter().enumerate() {
            check_finite(
                &[b.position[0], b.position[1]],
                &format!("beacons[{i}].position"),
            )?;
            check(
                b.radius.is_finite() && b.radius >= 0.0,
                &format!("beacons[{i}].radius"),
                "must be finite and >= 0",
            )?;
            check(
                !self.beacons[..i].iter().any(|o| o.id == b.id),
                &format!("beacons[{i}].id"),
                &format!("id {} is used twice", b.id),
            )?;
        }
        let s = &self.sensors;
        let l = &s.lidar;
        check(
            l.beams >= 1 && l.beams <= 100_000,
            "sensors.lidar.beams",
            "must be in 1..=100000",
        )?;
        check_fov(l.fov, "sensors.lidar.fov")?;
        check_rate(l.rate, "sensors.lidar.rate")?;
        check_pos(l.max_range, "sensors.lidar.max_range")?;
        check(
            l.min_range.is_finite() && l.min_range >= 0.0 && l.min_range < l.max_range,
            "sensors.lidar.min_range",
            "must be >= 0 and less than max_range",
        )?;
        check_nonneg(l.range_sigma, "sensors.lidar.range_sigma")?;
        let o = &s.odometry;
        check_rate(o.rate, "sensors.odometry.rate")?;
        check(
            o.linear_scale_error.is_finite() && o.linear_scale_error > -1.0,
            "sensors.odometry.linear_scale_error",
            "must be finite and > -1",
        )?;
        check(
            o.angular_scale_error.is_finite() && o.angular_scale_error > -1.0,
            "sensors.odometry.angular_scale_error",
            "must be finite and > -1",
        )?;
        check_finite(&[o.heading_drift], "sensors.odometry.heading_drift")?;
        check_nonneg(o.linear_noise, "sensors.odometry.linear_noise")?;
        check_nonneg(o.angular_noise, "sensors.odometry.angular_noise")?;
        check_nonneg(
            o.angular_noise_per_metre,
            "sensors.odometry.angular_noise_per_metre",
        )?;
        let g = &s.gps;
        check_rate(g.rate, "sensors.gps.rate")?;
        check_nonneg(g.position_sigma, "sensors.gps.position_sigma")?;
        check_nonneg(g.yaw_sigma, "sensors.gps.yaw_sigma")?;
        for (i, z) in g.zones.iter().enumerate() {
            let f = format!("sensors.gps.zones[{i}]");
            match (&z.rect, &z.circle) {
                (Some(r), None) => check(
                    r.min.iter().chain(&r.max).all(|v| v.is_finite())
                        && r.min[0] < r.max[0]
                        && r.min[1] < r.max[1],
                    &format!("{f}.rect"),
                    "needs finite min < max in x and y",
                )?,
                (None, Some(c)) => {
                    check_finite(&c.center, &format!("{f}.circle.center"))?;
                    check_pos(c.radius, &format!("{f}.circle.radius"))?;
                }
                _ => {
                    return Err(SimError::invalid(
                        f,
                        "give exactly one of `rect` and `circle`",
                    ));
                }
            }
            check(
                z.noise_multiplier.is_finite() && z.noise_multiplier >= 1.0,
                &format!("{f}.noise_multiplier"),
                "must be finite and >= 1",
            )?;
        }
        let c = &s.camera;
        check_rate(c.rate, "sensors.camera.rate")?;
        check_fov(c.fov, "sensors.camera.fov")?;
        check_pos(c.max_range, "sensors.camera.max_range")?;
        check_nonneg(c.bearing_sigma, "sensors.camera.bearing_sigma")?;
        check_nonneg(c.range_sigma, "sensors.camera.range_sigma")?;
        check_rate(c.image_rate, "sensors.camera.image_rate")?;
        for (v, f) in [
            (c.width, "sensors.camera.width"),
            (c.height, "sensors.camera.height"),
        ] {
            check(
                (8..=4096).contains(&v),
                f,
                &format!("must be in 8..=4096 pixels, got {v}"),
            )?;
        }
        check_nonneg(c.noise_sigma, "sensors.camera.noise_sigma")?;
        check_nonneg(c.lighting, "sensors.camera.lighting")?;
        if c.image {
            check(
                c.fov < 3.0,
                "sensors.camera.fov",
                "must be below 3.0 rad for images",
            )?;
        }
        check_rate(s.ground_truth.rate, "sensors.ground_truth.rate")?;
        crate::script::validate(&self.events, &self.lighting_zones)
    }

    /// The built-in world: a 20 x 15 m area. The western part (x < 8) is an open yard with
    /// pillars and good GPS; the eastern part is a building with three rooms joined by doorways,
    /// where GPS is degraded (south rooms) or lost (north room). Six beacons.
    #[must_use]
    pub fn default_world() -> Self {
        let mut w = Self::empty(Pose2D::new(2.0, 2.0, 0.0));
        w.name = "default".to_owned();
        w.seed = 1;
        let wall = |a: [f64; 2], b: [f64; 2]| Wall::new(a, b);
        w.walls = vec![
            // Outer boundary.
            wall([0.0, 0.0], [20.0, 0.0]),
            wall([20.0, 0.0], [20.0, 15.0]),
            wall([20.0, 15.0], [0.0, 15.0]),
            wall([0.0, 15.0], [0.0, 0.0]),
            // Building west wall x = 8 with doorways at y 2..3.2 and 11..12.2.
            wall([8.0, 0.0], [8.0, 2.0]),
            wall([8.0, 3.2], [8.0, 11.0]),
            wall([8.0, 12.2], [8.0, 15.0]),
            // Wall y = 8 between north room and south rooms, doorway at x 12..13.2.
            wall([8.0, 8.0], [12.0, 8.0]),
            wall([13.2, 8.0], [20.0, 8.0]),
            // Wall x = 14 splitting the south part, doorway at y 4..5.2.
            wall([14.0, 0.0], [14.0, 4.0]),
            wall([14.0, 5.2], [14.0, 8.0]),
        ];
        w.boxes = vec![
            // Pillars in the yard.
            BoxObstacle {
                center: [4.0, 5.0],
                size: [0.6, 0.6],
                angle: 0.0,
                color: None,
            },
            BoxObstacle {
                center: [5.5, 10.0],
                size: [1.0, 0.5],
                angle: 0.5,
                color: None,
            },
            BoxObstacle {
                center: [2.5, 12.5],
                size: [0.8, 0.8],
                angle: PI / 4.0,
                color: None,
            },
            // A table in the north room and a shelf in the south-east room.
            BoxObstacle {
                center: [15.0, 11.5],
                size: [2.0, 1.0],
                angle: 0.0,
                color: None,
            },
            BoxObstacle {
                center: [17.5, 2.0],
                size: [0.4, 2.0],
                angle: 0.0,
                color: None,
            },
        ];
        w.beacons = vec![
            Beacon {
                id: 1,
                position: [7.9, 6.0],
                radius: 0.1,
            },
            Beacon {
                id: 2,
                position: [0.1, 7.5],
                radius: 0.1,
            },
            Beacon {
                id: 3,
                position: [4.0, 14.9],
                radius: 0.1,
            },
            Beacon {
                id: 4,
                position: [19.9, 12.0],
                radius: 0.1,
            },
            Beacon {
                id: 5,
                position: [11.0, 0.1],
                radius: 0.1,
            },
            Beacon {
                id: 6,
                position: [19.9, 4.0],
                radius: 0.1,
            },
        ];
        w.sensors.gps.zones = vec![
            GpsZone {
                name: "building south".to_owned(),
                kind: GpsZoneKind::Degraded,
                rect: Some(Rect {
                    min: [8.0, 0.0],
                    max: [20.0, 8.0],
                }),
                circle: None,
                noise_multiplier: 5.0,
            },
            GpsZone {
                name: "building north".to_owned(),
                kind: GpsZoneKind::Outage,
                rect: Some(Rect {
                    min: [8.0, 8.0],
                    max: [20.0, 15.0],
                }),
                circle: None,
                noise_multiplier: 1.0,
            },
            GpsZone {
                name: "tree".to_owned(),
                kind: GpsZoneKind::Degraded,
                rect: None,
                circle: Some(Circle {
                    center: [3.0, 9.0],
                    radius: 1.5,
                }),
                noise_multiplier: 3.0,
            },
        ];
        w
    }
}

pub(crate) fn check(ok: bool, field: &str, message: &str) -> Result<()> {
    if ok {
        Ok(())
    } else {
        Err(SimError::invalid(field, message))
    }
}
pub(crate) fn check_pos(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v > 0.0,
        field,
        &format!("must be finite and > 0, got {v}"),
    )
}
pub(crate) fn check_nonneg(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v >= 0.0,
        field,
        &format!("must be finite and >= 0, got {v}"),
    )
}
pub(crate) fn check_finite(v: &[f64], field: &str) -> Result<()> {
    check(v.iter().all(|x| x.is_finite()), field, "must be finite")
}
fn check_rate(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v > 0.0 && v <= 1e9,
        field,
        &format!("must be in (0, 1e9] Hz, got {v}"),
    )
}
fn check_fov(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v > 0.0 && v <= TAU + 1e-9,
        field,
        &format!("must be in (0, 2π] radians, got {v}"),
    )
}

/// The text between `prefix` and the next backtick in `message`.
fn backticked<'a>(message: &'a str, prefix: &str) -> Option<&'a str> {
    let start = message.find(prefix)? + prefix.len();
    let rest = message.get(start..)?;
    rest.find('`').and_then(|end| rest.get(..end))
}

fn join_field(table: &str, key: &str) -> String {
    match (table.is_empty(), key.is_empty()) {
        (true, _) => key.to_owned(),
        (_, true) => table.to_owned(),
        _ => format!("{table}.{key}"),
    }
}

/// Tracks `[table]` and `[[array]]` headers line by line, giving paths like `walls[2]`.
#[derive(Default)]
struct HeaderTracker {
    current: String,
    counts: std::collections::HashMap<String, usize>,
}

impl HeaderTracker {
    /// Updates the current table if `line` is a header; returns whether it was one.
    fn feed(&mut self, line: &str) -> bool {
        let t = line.trim();
        if let Some(inner) = t.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = inner.trim().to_owned();
            // A nested array like [[sensors.gps.zones]] counts within its parent.
            let n = self.counts.entry(name.clone()).or_insert(0);
            self.current = format!("{name}[{}]", *n);
            *n += 1;
            true
        } else if let Some(inner) = t.strip_prefix('[').and_then(|r| r.split(']').next()) {
            self.current = inner.trim().to_owned();
            true
        } else {
            false
        }
    }
}

/// Dotted path of the key being defined at byte `offset` of a TOML document.
fn toml_field_at(src: &str, offset: usize) -> String {
    let mut tracker = HeaderTracker::default();
    let mut pos = 0;
    for line in src.split_inclusive('\n') {
        let end = pos + line.len();
        if offset < end || end == src.len() {
            if tracker.feed(line) {
                return tracker.current;
            }
            let col = offset.saturating_sub(pos).min(line.len());
            let prefix = line.get(..col).unwrap_or(line);
            let keys = inline_keys(prefix);
            let key = if keys.is_empty() {
                // The offset is on the key itself, e.g. an unknown field.
                line.split('=')
                    .next()
                    .unwrap_or("")
                    .trim()
                    .trim_matches('"')
                    .to_owned()
            } else {
                keys.join(".")
            };
            return join_field(&tracker.current, &key);
        }
        tracker.feed(line);
        pos = end;
    }
    tracker.current
}

/// Keys open at the end of a TOML line prefix: `a = { b = [1, { c = ` gives [a, b, c].
fn inline_keys(prefix: &str) -> Vec<String> {
    let mut stack: Vec<String> = Vec::new();
    let mut pending: Option<String> = None;
    let mut word = String::new();
    let mut last_word = String::new();
    let mut in_str = false;
    for ch in prefix.chars() {
        if in_str {
            if ch == '"' || ch == '\'' {
                in_str = false;
            }
            continue;
        }
        match ch {
            '"' | '\'' => in_str = true,
            '#' => break,
            '=' => {
                if let Some(p) = pending.take() {
                    stack.push(p);
                }
                pending = Some(std::mem::take(&mut last_word));
            }
            '{' | '[' => {
                if let Some(p) = pending.take() {
                    stack.push(p);
                }
                stack.push(String::new());
            }
            '}' | ']' => {
                pending = None;
                while let Some(top) = stack.pop() {
                    if top.is_empty() {
                        break;
                    }
                }
                // The key owning the closed value is complete too.
                stack.pop();
            }
            ',' => pending = None,
            c if c.is_alphanumeric() || c == '_' || c == '-' => word.push(c),
            _ => {}
        }
        let in_word = ch.is_alphanumeric() || ch == '_' || ch == '-';
        if !in_word && !word.is_empty() {
            last_word = std::mem::take(&mut word);
        }
    }
    stack
        .into_iter()
        .chain(pending)
        .filter(|k| !k.is_empty())
        .collect()
}

/// 1-based line and column where `field` (as produced by `validate`) is written, or of its
/// nearest enclosing table; (1, 1) if nothing matches.
fn locate_toml_field(src: &str, field: &str) -> (usize, usize) {
    let mut tracker = HeaderTracker::default();
    let mut best: Option<(usize, usize, usize)> = None; // (score, line, column)
    for (i, line) in src.lines().enumerate() {
        let path = if tracker.feed(line) {
            tracker.current.clone()
        } else {
            let t = line.trim_start();
            if t.starts_with('#') || !t.contains('=') {
                continue;
            }
            let key = t.split('=').next().unwrap_or("").trim().trim_matches('"');
            join_field(&tracker.current, key)
        };
        let matches = field == path
            || field.starts_with(&format!("{path}."))
            || field.starts_with(&format!("{path}["));
        if matches && best.is_none_or(|(score, _, _)| path.len() > score) {
            let column = line.len() - line.trim_start().len() + 1;
            best = Some((path.len(), i + 1, column));
        }
    }
    best.map_or((1, 1), |(_, l, c)| (l, c))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inline_keys_follow_nesting() {
        assert_eq!(inline_keys("start = { x = 1.0, y = "), vec!["start", "y"]);
        assert_eq!(inline_keys("beams = "), vec!["beams"]);
        assert_eq!(inline_keys("a = { b = [1, 2], c = "), vec!["a", "c"]);
    }

    #[test]
    fn locate_finds_array_of_tables_entries() {
        let src = "[robot]\nstart = { x = 1, y = 2 }\n[[walls]]\nfrom = [0, 0]\n[[walls]]\nfrom = [1, 1]\nthickness = -1\n";
        assert_eq!(locate_toml_field(src, "walls[1].thickness"), (7, 1));
        assert_eq!(locate_toml_field(src, "walls[0].thickness"), (3, 1));
        assert_eq!(locate_toml_field(src, "robot.start.x"), (2, 1));
    }

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
