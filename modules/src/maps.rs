//! Maps: mapping from a known map file (Table 1: provides "Mapping"; data out: map).
//!
//! Loads a ROS map_server map (YAML + PGM; the loader is the simulator crate's, which names
//! the file, line and field of any error) and publishes it once on `map_out`, a state channel
//! whose latest sample every late joiner receives. With `reload_s` set, the file is re-read
//! that often and republished when it changed (edit a map while the robot runs).
//!
//! Quality Q: `quality` (default 1: a surveyed map is as good as maps get here; lower for a
//! survey trusted less, e.g. an old one) when the map is loaded; a map that fails to load
//! stops the module at configure with the loader's message. Planning, its client, rates the
//! map by agreement with the scans (client feedback, `crate::feedback::ScanMapAgreement`).

use std::path::PathBuf;
use std::time::Duration;

use hng_runtime::msg::GridInfo;
use hng_runtime::{Context, Module, ModuleResult, SlicePublisher, TimerId};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{field_error, seconds};
use crate::planning::{GridError, OccupancyGrid};

/// Configuration of `hng module maps`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct MapsModuleConfig {
    /// The map_server YAML file (required).
    pub map: Option<PathBuf>,
    /// Channel of the map (default `maps/map`).
    #[default("maps/map".into())]
    pub map_out: String,
    /// Re-read the file this often, s (default: never).
    pub reload_s: Option<f64>,
    /// The self-evaluated quality Q of the map, in (0, 1] (default 1).
    #[default(1.0)]
    pub quality: f64,
}

/// A planning grid from a map message (the header's origin heading must be 0: rotated maps
/// are not supported).
pub fn grid_from_msg(info: &GridInfo, data: &[i8]) -> Result<OccupancyGrid, GridError> {
    OccupancyGrid::from_data(
        info.width,
        info.height,
        f64::from(info.resolution),
        [info.origin.x, info.origin.y],
        data.to_vec(),
    )
}

/// Loads a map_server map as a planning grid.
pub fn load_map(path: &std::path::Path) -> ModuleResult<OccupancyGrid> {
    let m = OccupancyGrid::load(path)?;
    if m.origin_yaw() != 0.0 {
        return Err(format!(
            "{}: field `origin`: a yaw of {} is not supported (rotated maps); use 0",
            path.display(),
            m.origin_yaw()
        )
        .into());
    }
    Ok(m)
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct MapsState {
    published: u64,
}

/// The Maps module.
#[derive(Debug)]
pub struct MapsModule {
    path: PathBuf,
    grid: OccupancyGrid,
    out: SlicePublisher<GridInfo>,
    state: MapsState,
}

impl MapsModule {
    fn publish(&mut self) -> ModuleResult {
        self.out.publish_copy(self.grid.info(), self.grid.data())?;
        self.state.published += 1;
        Ok(())
    }
}

impl Module for MapsModule {
    type Config = MapsModuleConfig;

    fn configure(ctx: &mut Context, cfg: MapsModuleConfig) -> ModuleResult<Self> {
        let path = cfg
            .map
            .ok_or_else(|| field_error("map", "missing: the map_server YAML file to publish"))?;
        if !(cfg.quality > 0.0 && cfg.quality <= 1.0) {
            return Err(
                field_error("quality", format!("must be in (0, 1], got {}", cfg.quality)).into(),
            );
        }
        let grid = load_map(&path)?;
        if let Some(r) = cfg.reload_s {
            ctx.add_timer(seconds("reload_s", r)?.max(Duration::from_millis(100)));
        }
        // Provides "Mapping" on `map_out`.
        let mut offer = hng_runtime::contract::ServiceOffer::new("Mapping", "hng/GridInfo/v1");
        offer.channel = cfg.map_out.clone();
        ctx.provide(offer);
        let out = ctx.slice_publisher::<GridInfo>(&cfg.map_out, grid.data().len())?;
        ctx.set_quality(true, cfg.quality as f32);
        tracing::info!(
            module = ctx.name(),
            map = %path.display(),
            width = grid.width(),
            height = grid.height(),
            resolution = grid.resolution(),
            "map loaded"
        );
        Ok(MapsModule {
            path,
            grid,
            out,
            state: MapsState::default(),
        })
    }

    fn start(&mut self, _ctx: &mut Context) -> ModuleResult {
        self.publish()
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        match load_map(&self.path) {
            Ok(g) if g != self.grid => {
                tracing::info!(module = ctx.name(), "map file changed: republishing");
                self.grid = g;
                self.publish()?;
            }
            Ok(_) => {}
            Err(e) => tracing::warn!(
                module = ctx.name(),
                "map reload failed, keeping the old map: {e}"
            ),
        }
        Ok(())
    }

    hng_runtime::checkpoint_field!(state);
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_example_map_loads_and_round_trips_through_a_message() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../simulator/worlds/example_map.yaml");
        let g = load_map(&path).unwrap();
        let info = g.info();
        let back = grid_from_msg(&info, g.data()).unwrap();
        assert_eq!(back, g);
        let err = load_map(std::path::Path::new("/nonexistent/map.yaml")).unwrap_err();
        assert!(err.to_string().contains("/nonexistent/map.yaml"), "{err}");
    }
}
