//! Camera images of the simulator module: the forward camera rendered by ray casting
//! ([`crate::render`]) at `sensors.camera.image_rate`, published as `ImageInfo` + RGB8 bytes
//! on `channels.camera_image` (`sim/camera/image`). The image is rendered straight into the
//! loaned shared-memory sample (no copy). Its stamp is the simulated time of the step it shows,
//! and in lockstep it goes out with the step's other data, before the clock sample.
//!
//! The images are rendered with the world script's lighting (its `lighting` events and
//! lighting zones, `Simulator::lighting`) times a factor that starts at
//! `sensors.camera.lighting` and follows `SimLighting` messages on `channels.lighting`
//! (`sim/lighting`, a state channel: the latest value counts; a value that is not finite or
//! outside [0, 4] is dropped and counted). Boxes the world script adds are drawn.
//!
//! Images only when read: a frame whose time comes while the image channel has no subscriber
//! (no Camera module relaying, no tracker, operator page, recorder or `hng topic`) is neither
//! rendered nor published, only counted (`skipped`): rendering and noising an image is most of
//! the simulator's work. The pixel noise of frame `k` (the `k`-th image period of simulated
//! time) is drawn from the ChaCha stream `k` of a generator seeded by the world's seed, so an
//! image depends only on the seed, the simulated time and the scene: the same whether or not
//! earlier frames were rendered, and after a restart from a checkpoint.

use hng_runtime::msg::{FrameId, Header, ImageInfo};
use hng_runtime::qos::ChannelKind;
use hng_runtime::{ModuleResult, Node, SlicePublisher};
use iceoryx2::prelude::ZeroCopySend;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::render::{ImageParams, Renderer};
use crate::world::{BoxObstacle, Pose2D, World};

/// The lighting of the camera images (published on `sim/lighting` to change it at run time).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-simulator/SimLighting/v1")]
pub struct SimLighting {
    /// Header.
    pub header: Header,
    /// Lighting factor: 1 normal, lower is darker (0 black), at most 4.
    pub lighting: f64,
}

hng_runtime::impl_message!(SimLighting, ChannelKind::State);

/// The image camera of the simulator module.
pub(super) struct ImageCamera {
    renderer: Renderer,
    publisher: SlicePublisher<ImageInfo>,
    period_ns: u64,
    next_ns: u64,
    lighting: f64,
    /// Seed of the pixel noise (frame `k` draws from stream `k`).
    seed: u64,
    /// Images published.
    pub published: u64,
    /// Frames due while nobody subscribed to the images: not rendered.
    pub skipped: u64,
    /// Lighting messages dropped (not finite, negative or above 4).
    pub bad_lighting: u64,
}

impl ImageCamera {
    /// The camera of `world`, publishing through `node` on `channel`; `None` when images are
    /// off (camera or its images disabled).
    pub(super) fn new(node: &Node, world: &World, channel: &str) -> ModuleResult<Option<Self>> {
        let c = &world.sensors.camera;
        if !(c.enabled && c.image) {
            return Ok(None);
        }
        let params = ImageParams {
            width: c.width,
            height: c.height,
            fov: c.fov,
            noise_sigma: c.noise_sigma,
            ..ImageParams::default()
        };
        let renderer = Renderer::new(world, params)?;
        let publisher = node.slice_publisher::<ImageInfo>(channel, params.image_bytes())?;
        Ok(Some(ImageCamera {
            renderer,
            publisher,
            period_ns: ((1e9 / c.image_rate) as u64).max(1),
            next_ns: 0,
            lighting: c.lighting,
            seed: world.seed ^ 0x1a6e_ca3e,
            published: 0,
            skipped: 0,
            bad_lighting: 0,
        }))
    }

    /// Sets the lighting factor; a bad value is dropped, counted and logged.
    pub(super) fn set_lighting(&mut self, lighting: f64) {
        if lighting.is_finite() && (0.0..=4.0).contains(&lighting) {
            if lighting != self.lighting {
                tracing::info!(lighting, "camera lighting changed");
            }
            self.lighting = lighting;
        } else {
            self.bad_lighting += 1;
            tracing::warn!(
                lighting,
                dropped = self.bad_lighting,
                "lighting must be in [0, 4]: dropped"
            );
        }
    }

    /// After a restore: the next image is due at `now_ns`.
    pub(super) fn resume_at(&mut self, now_ns: u64) {
        self.next_ns = now_ns;
    }

    /// Renders and publishes an image of `pose` if one is due at simulated time `now_ns` and
    /// someone subscribes to the images, with the world script's lighting (`script_lighting`,
    /// zones included) times the lighting set on the channel, and the boxes the script added.
    pub(super) fn step<'a>(
        &mut self,
        now_ns: u64,
        pose: Pose2D,
        script_lighting: f64,
        script_boxes: impl IntoIterator<Item = &'a BoxObstacle>,
    ) -> ModuleResult {
        if now_ns < self.next_ns {
            return Ok(());
        }
        let frame = self.next_ns / self.period_ns;
        while self.next_ns <= now_ns {
            self.next_ns = self.next_ns.saturating_add(self.period_ns);
        }
        if self.publisher.subscribers() == 0 {
            self.skipped += 1;
            return Ok(());
        }
        let p = *self.renderer.params();
        let mut loan = self
            .publisher
            .loan_uninit(p.image_bytes())?
            .write_from_fn(|_| 0);
        *loan.header_mut() = ImageInfo {
            header: Header {
                frame_id: FrameId::CAMERA,
                ..Header::default()
            },
            width: p.width,
            height: p.height,
            step: p.width * 3,
            encoding: FrameId::new("rgb8").unwrap_or_default(),
            hfov: p.fov,
        };
        self.renderer.set_script_boxes(script_boxes);
        let lighting = script_lighting * self.lighting;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        rng.set_stream(frame);
        self.renderer
            .render(pose, lighting, Some(&mut rng), loan.payload_mut());
        loan.publish()?;
        self.published += 1;
        Ok(())
    }
}
