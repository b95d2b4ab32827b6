//! Camera: the camera driver (Table 1: provides "Video"). Backed here by the simulator's
//! rendered camera (`sim/camera/image`, RGB8 `ImageInfo` + bytes), relayed on `image_out`
//! (`camera/image`), the data channel of its "Video" offer (type `hng/ImageInfo/v2`). The
//! relay is one copy of each frame from the device's sample into the Camera's own loaned
//! sample; its clients read that sample in place.
//!
//! A frame whose payload does not match its header (`width * height * 3` bytes of `rgb8`) is
//! dropped and counted (`dropped` in the checkpoint, `msgs_dropped` in the report).
//!
//! Quality Q: 1 while frames arrive, -1 (aptitude 0) after `frame_timeout_s` without one.

use hng_runtime::channel::InputId;
use hng_runtime::contract::ServiceOffer;
use hng_runtime::msg::ImageInfo;
use hng_runtime::{Context, Module, ModuleResult, SlicePublisher, SliceSubscriber};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::seconds;
use crate::video::{VIDEO_TYPE, check_rgb8};

/// Configuration of `hng module camera`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct CameraModuleConfig {
    /// The device's images (default `sim/camera/image`).
    #[default("sim/camera/image".into())]
    pub image_in: String,
    /// Relayed images, the "Video" data channel (default `camera/image`).
    #[default("camera/image".into())]
    pub image_out: String,
    /// No frame for this long means the camera is gone, s (default 1.0).
    #[default(1.0)]
    pub frame_timeout_s: f64,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct CameraState {
    frames: u64,
    dropped: u64,
}

/// The Camera driver module.
#[derive(Debug)]
pub struct CameraModule {
    input: SliceSubscriber<ImageInfo>,
    output: SlicePublisher<ImageInfo>,
    state: CameraState,
}

impl Module for CameraModule {
    type Config = CameraModuleConfig;

    fn configure(ctx: &mut Context, cfg: CameraModuleConfig) -> ModuleResult<Self> {
        let timeout = seconds("frame_timeout_s", cfg.frame_timeout_s)?;
        let mut offer = ServiceOffer::new("Video", VIDEO_TYPE);
        offer.channel = cfg.image_out.clone();
        ctx.provide(offer);
        ctx.set_quality(false, -1.0);
        Ok(CameraModule {
            input: ctx.subscribe_slice(&cfg.image_in, Some(timeout))?,
            output: ctx.slice_publisher(&cfg.image_out, 320 * 240 * 3)?,
            state: CameraState::default(),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        while let Some(f) = self.input.receive()? {
            if let Some(why) = check_rgb8(f.header(), f.data().len()) {
                self.state.dropped += 1;
                let c = &ctx.node().counters().msgs_dropped;
                c.set(c.get() + 1);
                tracing::warn!(
                    module = ctx.name(),
                    dropped = self.state.dropped,
                    "malformed image dropped: {why}"
                );
                continue;
            }
            let mut loan = self
                .output
                .loan_uninit(f.data().len())?
                .write_from_slice(f.data());
            let info = f.header();
            *loan.header_mut() = ImageInfo {
                header: hng_runtime::msg::Header {
                    frame_id: info.header.frame_id,
                    ..Default::default()
                },
                ..*info
            };
            loan.publish()?; // restamped, frame kept
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

    // A checkpoint of format 1 (the frame count alone) does not decode: the runtime starts
    // the counters afresh, with a warning.
    hng_runtime::checkpoint_field!(state);
}
