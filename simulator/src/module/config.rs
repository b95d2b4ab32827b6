//! Configuration of `hng module simulator` (the `config` table of its launch-file entry).

use std::path::PathBuf;

use hng_runtime::ModuleResult;
use hng_runtime::clock::lockstep::DEFAULT_OUTSIDE;
use hng_runtime::msg::MAX_BEAMS;
use hng_runtime::wait::WaitMode;
use serde::{Deserialize, Deserializer};
use smart_default::SmartDefault;

use crate::pacing::Speed;
use crate::world::{Pose2D, World};

/// Per-sensor switches; `None` keeps the world file's setting. A sensor switched off publishes
/// nothing and does not even open its channel, so a real driver or a log replay can provide it
/// (hybrid simulation).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorSwitches {
    /// Lidar on `channels.scan`.
    pub lidar: Option<bool>,
    /// Odometry on `channels.odom`.
    pub odometry: Option<bool>,
    /// GPS on `channels.gps`.
    pub gps: Option<bool>,
    /// Beacon camera on `channels.camera`.
    pub camera: Option<bool>,
    /// Ground truth on `channels.ground_truth`.
    pub ground_truth: Option<bool>,
    /// Rendered camera images on `channels.camera_image` (with the camera on).
    pub camera_image: Option<bool>,
}

/// Channel names.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct Channels {
    /// Lidar, `LaserScan` in `laser` (default `sim/scan`).
    #[default("sim/scan".into())]
    pub scan: String,
    /// Odometry, `Odometry` odom → base_link (default `sim/odom`).
    #[default("sim/odom".into())]
    pub odom: String,
    /// GPS/IMU pose, `PoseWithCovariance` in `map` (default `sim/gps`).
    #[default("sim/gps".into())]
    pub gps: String,
    /// Beacon camera, `BeaconObservation` in `camera` (default `sim/camera`).
    #[default("sim/camera".into())]
    pub camera: String,
    /// Rendered camera images, `ImageInfo` + RGB8 bytes (default `sim/camera/image`).
    #[default("sim/camera/image".into())]
    pub camera_image: String,
    /// Lighting factor of the images in, `SimLighting` (default `sim/lighting`).
    #[default("sim/lighting".into())]
    pub lighting: String,
    /// True pose, `PoseWithCovariance` in `map`, evaluation only (default `sim/ground_truth`).
    #[default("sim/ground_truth".into())]
    pub ground_truth: String,
    /// Collision events, [`SimCollision`] (default `sim/collisions`).
    #[default("sim/collisions".into())]
    pub collisions: String,
    /// Counters, [`SimStatus`] (default `sim/status`).
    #[default("sim/status".into())]
    pub status: String,
    /// Teleport commands in, [`super::SimTeleport`] (default `sim/teleport`; empty: none).
    #[default("sim/teleport".into())]
    pub teleport: String,
    /// Velocity commands in, `Twist` (default `sim/cmd_vel`).
    #[default("sim/cmd_vel".into())]
    pub cmd_vel: String,
    /// Ground-truth occupancy grid, `GridInfo` + `[i8]`, published once (default `sim/map`;
    /// empty: not published).
    #[default("sim/map".into())]
    pub map: String,
}

/// Configuration of `hng module simulator` (the `config` table of its launch-file entry).
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct SimModuleConfig {
    /// World file: a TOML world, or a map_server YAML (`.yaml`/`.yml`, then `start` is needed).
    /// Default: the built-in world.
    pub world: Option<PathBuf>,
    /// Robot start pose, overriding the world's.
    pub start: Option<Pose2D>,
    /// `"realtime"` (default), a factor such as `10`, or `"max"`.
    #[serde(deserialize_with = "de_speed")]
    #[default(Speed::RealTime)]
    pub speed: Speed,
    /// Noise seed, overriding the world's.
    pub seed: Option<u64>,
    /// Stop cleanly after this many simulated seconds.
    pub duration_s: Option<f64>,
    /// Sensor switches (hybrid simulation).
    #[default(SensorSwitches::default())]
    pub sensors: SensorSwitches,
    /// Channel names.
    #[default(Channels::default())]
    pub channels: Channels,
    /// Cell size of the published ground-truth map, m (default 0.05).
    #[default(0.05)]
    pub map_resolution: f64,
    /// Most physics steps per tick before commands and signals are looked at (default 10).
    #[default(10)]
    pub max_steps_per_tick: u32,
    /// Publish the clock every this many steps (default 1), and always with sensor data.
    #[default(1)]
    pub clock_every_steps: u32,
    /// Modules whose first report simulated time waits for (default none: it starts at once).
    pub wait_for: Vec<String>,
    /// Longest wait for them, s of wall time (default 10).
    #[default(10.0)]
    pub wait_timeout_s: f64,
    /// Lockstep: modules whose acknowledgement of each step simulated time waits for
    /// (default none: the simulator only keeps its pace); see
    /// [`hng_runtime::clock::lockstep`].
    pub lockstep: Vec<String>,
    /// A lockstep participant silent this long (s of wall time) is not waited for until it
    /// answers again (default 10).
    #[default(10.0)]
    pub lockstep_timeout_s: f64,
    /// A lockstep participant is called to a round at least every this many seconds of
    /// simulated time, even with nothing written to it and no deadline; default 1. What
    /// processes outside the barrier send it comes through `lockstep_outside` sooner.
    #[default(1.0)]
    pub lockstep_idle_s: f64,
    /// Channels written from outside the barrier (the supervisor, the RM, an operator):
    /// when one is published to, its readers are called at the next step. Default
    /// [`hng_runtime::clock::lockstep::DEFAULT_OUTSIDE`].
    #[default(DEFAULT_OUTSIDE.iter().map(|c| (*c).to_owned()).collect())]
    pub lockstep_outside: Vec<String>,
}

fn de_speed<'de, D: Deserializer<'de>>(d: D) -> Result<Speed, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Raw {
        Number(f64),
        Text(String),
    }
    let text = match Raw::deserialize(d)? {
        Raw::Number(f) => f.to_string(),
        Raw::Text(s) => s,
    };
    text.parse().map_err(serde::de::Error::custom)
}

/// How the simulator waits for its inputs (lockstep acknowledgements, commands), given its
/// configuration `toml` and `HNG_WAIT` (`env_wait`): as `HNG_WAIT` says when set; otherwise,
/// at a paced speed (real time or a factor) it sleeps at once instead of spinning
/// (`blocking:0`): its next step waits for the pace anyway, so catching an acknowledgement a
/// few tens of microseconds sooner gains nothing, and the spin cost about a fifth of its CPU
/// at 1x. At `max` speed it keeps the runtime's adaptive spin. `None`: keep the default (an
/// unreadable configuration is reported when the module configures).
pub(super) fn wait_mode(toml: &str, env_wait: Option<&str>) -> Option<WaitMode> {
    if env_wait.is_some_and(|w| !w.is_empty()) {
        return None;
    }
    let cfg: SimModuleConfig = toml::from_str(toml).ok()?;
    (!matches!(cfg.speed, Speed::Unlimited)).then_some(WaitMode::SLEEP)
}

pub(super) fn config_error(
    field: &str,
    message: impl std::fmt::Display,
) -> Box<dyn std::error::Error + Send + Sync> {
    format!("simulator config: field `{field}`: {message}").into()
}

impl SimModuleConfig {
    /// The world this configuration describes: loaded, with the overrides applied.
    pub fn build_world(&self) -> ModuleResult<World> {
        let mut world = match &self.world {
            None => World::default_world(),
            Some(path) => {
                let is_yaml = path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                    e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml")
                });
                if is_yaml {
                    let start = self.start.ok_or_else(|| {
                        config_error(
                            "start",
                            format!(
                                "a map_server world ({}) has no robot pose: give `start = {{ x = .., y = .. }}`",
                                path.display()
                            ),
                        )
                    })?;
                    World::from_occupancy_map(path, start)?
                } else {
                    World::load(path)?
                }
            }
        };
        if let Some(start) = self.start {
            world.robot.start = start;
        }
        if let Some(seed) = self.seed {
            world.seed = seed;
        }
        let s = &self.sensors;
        let sw = &mut world.sensors;
        for (switch, enabled) in [
            (s.lidar, &mut sw.lidar.enabled),
            (s.odometry, &mut sw.odometry.enabled),
            (s.gps, &mut sw.gps.enabled),
            (s.camera, &mut sw.camera.enabled),
            (s.ground_truth, &mut sw.ground_truth.enabled),
            (s.camera_image, &mut sw.camera.image),
        ] {
            if let Some(on) = switch {
                *enabled = on;
            }
        }
        if world.sensors.lidar.beams as usize > MAX_BEAMS {
            return Err(config_error(
                "sensors.lidar.beams",
                format!(
                    "{} beams do not fit a LaserScan message (at most {MAX_BEAMS})",
                    world.sensors.lidar.beams
                ),
            ));
        }
        if let Some(d) = self.duration_s
            && !(d.is_finite() && d > 0.0)
        {
            return Err(config_error(
                "duration_s",
                format!("must be > 0 seconds, got {d}"),
            ));
        }
        if self.max_steps_per_tick == 0 {
            return Err(config_error("max_steps_per_tick", "must be at least 1"));
        }
        if !(self.lockstep_idle_s.is_finite() && self.lockstep_idle_s > 0.0) {
            return Err(config_error(
                "lockstep_idle_s",
                format!("must be > 0 seconds, got {}", self.lockstep_idle_s),
            ));
        }
        if !(self.lockstep_timeout_s.is_finite() && self.lockstep_timeout_s > 0.0) {
            return Err(config_error(
                "lockstep_timeout_s",
                format!("must be > 0 seconds, got {}", self.lockstep_timeout_s),
            ));
        }
        if self.clock_every_steps == 0 {
            return Err(config_error("clock_every_steps", "must be at least 1"));
        }
        Ok(world)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_simulator_sleeps_at_once_when_paced_and_spins_at_max_unless_told() {
        let sleep = Some(WaitMode::SLEEP);
        assert_eq!(wait_mode("speed = \"realtime\"", None), sleep);
        assert_eq!(wait_mode("speed = 6", None), sleep);
        assert_eq!(wait_mode("speed = \"max\"", None), None);
        assert_eq!(wait_mode("speed = 6", Some("spin")), None);
        assert_eq!(wait_mode("speed = 6", Some("")), sleep);
        assert_eq!(wait_mode("no_such_field = 1", None), None);
    }
}
