//! Camera: the camera driver (Table 1: provides "Video"). Backed here by the simulator's beacon
//! camera (`sim/camera`, beacons detected in each frame), relayed on `beacons_out`, the data
//! channel of its "Video" offer.
//!
//! Quality Q: 1 while frames arrive, -1 (aptitude 0) after `frame_timeout_s` without one.

use hng_runtime::channel::InputId;
use hng_runtime::contract::ServiceOffer;
use hng_runtime::msg::BeaconObservation;
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{decode_state, encode_state, seconds};

/// Configuration of `hng module camera`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraModuleConfig {
    /// The device's frames (default `sim/camera`).
    pub beacons_in: String,
    /// Relayed frames (default `camera/beacons`).
    pub beacons_out: String,
    /// No frame for this long means the camera is gone, s (default 1.0).
    pub frame_timeout_s: f64,
}

impl Default for CameraModuleConfig {
    fn default() -> Self {
        CameraModuleConfig {
            beacons_in: "sim/camera".into(),
            beacons_out: "camera/beacons".into(),
            frame_timeout_s: 1.0,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct CameraState {
    frames: u64,
}

/// The Camera driver module.
#[derive(Debug)]
pub struct CameraModule {
    input: Subscriber<BeaconObservation>,
    output: Publisher<BeaconObservation>,
    state: CameraState,
}

impl Module for CameraModule {
    type Config = CameraModuleConfig;

    fn configure(ctx: &mut Context, cfg: CameraModuleConfig) -> ModuleResult<Self> {
        let timeout = seconds("frame_timeout_s", cfg.frame_timeout_s)?;
        let mut offer = ServiceOffer::new("Video", "hng/BeaconObservation/v1");
        offer.channel = cfg.beacons_out.clone();
        ctx.provide(offer);
        ctx.set_quality(false, -1.0);
        Ok(CameraModule {
            input: ctx.subscribe(&cfg.beacons_in, Some(timeout))?,
            output: ctx.publisher(&cfg.beacons_out)?,
            state: CameraState::default(),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        while let Some(f) = self.input.receive()? {
            self.output.publish(*f)?; // restamped, frame kept
            self.state.frames += 1;
            ctx.set_quality(true, 1.0);
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no frame from the camera");
        ctx.set_quality(false, -1.0);
        Ok(())
    }

    fn checkpoint(&self) -> Option<Vec<u8>> {
        encode_state(&self.state)
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        self.state = decode_state(state)?;
        Ok(())
    }
}
