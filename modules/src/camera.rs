//! Camera: the camera driver (Table 1: provides "Video"). Backed here by the simulator's
//! rendered camera (`sim/camera/image`, RGB8 `ImageInfo` + bytes), relayed on `image_out`
//! (`camera/image`), the data channel of its "Video" offer (type `hng/ImageInfo/v2`). The
//! relay is one copy of each frame from the device's sample into the Camera's own loaned
//! sample; its clients read that sample in place.
//!
//! A frame whose payload does not match its header (`width * height * 3` bytes of `rgb8`) is
//! dropped and counted (`dropped` in the checkpoint, `msgs_dropped` in the report).
//!
//! Frames only when read: the Camera takes the device's frames only while someone reads
//! its own images (a tracker, the operator page, a recorder: a subscriber of `image_out`).
//! With no reader it drops its subscription to `image_in`, and the simulator, whose image
//! channel then has no subscriber, renders nothing. It looks for readers every
//! `demand_check_s` (and after each frame). At start (and after a restart) it takes frames
//! until the first one, to know the device works.
//!
//! Quality Q: 1 while frames arrive, -1 (aptitude 0) after `frame_timeout_s` without one
//! (while it takes frames). While nobody reads, Q stays what the last frames said.

use hng_runtime::channel::InputId;
use hng_runtime::contract::ServiceOffer;
use hng_runtime::msg::ImageInfo;
use hng_runtime::{Context, Module, ModuleResult, SlicePublisher, SliceSubscriber, TimerId};
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
    /// How often, with no frames taken, the Camera looks for readers of `image_out`, s
    /// (default 0.2).
    #[default(0.2)]
    pub demand_check_s: f64,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct CameraState {
    frames: u64,
    dropped: u64,
}

/// The Camera driver module.
#[derive(Debug)]
pub struct CameraModule {
    image_in: String,
    frame_timeout: std::time::Duration,
    /// The device's frames, taken only while someone reads `output` (and until the first).
    input: Option<SliceSubscriber<ImageInfo>>,
    /// A frame came since this process started (the device works).
    probed: bool,
    output: SlicePublisher<ImageInfo>,
    state: CameraState,
}

impl CameraModule {
    /// Takes the device's frames when `output` has readers (or no frame came yet), and stops
    /// taking them when it has none.
    fn follow_demand(&mut self, ctx: &mut Context) -> ModuleResult {
        let wanted = self.output.subscribers() > 0 || !self.probed;
        match (&self.input, wanted) {
            (None, true) => {
                self.input = Some(ctx.subscribe_slice(&self.image_in, Some(self.frame_timeout))?);
                tracing::debug!(module = ctx.name(), "images read: taking frames");
            }
            (Some(input), false) => {
                ctx.unsubscribe(input.id())?;
                self.input = None;
                tracing::debug!(
                    module = ctx.name(),
                    "nobody reads the images: no frames taken"
                );
            }
            _ => {}
        }
        Ok(())
    }
}

impl Module for CameraModule {
    type Config = CameraModuleConfig;

    fn configure(ctx: &mut Context, cfg: CameraModuleConfig) -> ModuleResult<Self> {
        let timeout = seconds("frame_timeout_s", cfg.frame_timeout_s)?;
        let check = seconds("demand_check_s", cfg.demand_check_s)?;
        let mut offer = ServiceOffer::new("Video", VIDEO_TYPE);
        offer.channel = cfg.image_out.clone();
        ctx.provide(offer);
        ctx.set_quality(false, -1.0);
        ctx.add_timer(check);
        Ok(CameraModule {
            input: Some(ctx.subscribe_slice(&cfg.image_in, Some(timeout))?),
            probed: false,
            image_in: cfg.image_in,
            frame_timeout: timeout,
            output: ctx.slice_publisher(&cfg.image_out, 320 * 240 * 3)?,
            state: CameraState::default(),
        })
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        self.follow_demand(ctx)
    }

    fn on_input(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        let Some(input) = &self.input else {
            return Ok(());
        };
        while let Some(f) = input.receive()? {
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
            self.probed = true;
            ctx.set_quality(true, 1.0);
        }
        self.follow_demand(ctx)
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
