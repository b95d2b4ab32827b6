//! The Visual tracker modules (Table 1: "Track beacon"): `hng module tracker_colour`
//! ([`ColourTrackerModule`], [`crate::tracker::ColourTracker`]) and `hng module
//! tracker_histogram` ([`HistogramTrackerModule`], [`crate::tracker_hist::HistogramTracker`]),
//! two providers of one service with different cost and robustness, so attention has a real
//! choice.
//!
//! Each needs "Video" (rank 1, required) and reads the operator's [`Designation`] on
//! [`DESIGNATION_CHANNEL`] (a state channel: the latest designation counts). It tracks all
//! the time, selected or not (its images come from the configured `image` channel until a
//! "Video" provider is contracted), so its self-evaluation is current when a client compares
//! it with the other tracker. For every image it publishes a [`BeaconTrack`] (state, bearing,
//! range, quality) on its offer's data channel (`track_out`, default `<module>/track`); through
//! an occlusion the track is predicted for `hold_s` with a quality falling to 0, then lost.
//!
//! While no beacon is designated it looks, in one image of `discover_every`, for each beacon
//! id of `discover` and publishes a seen track for each one found (on the same channel; the
//! reacher ignores tracks of beacons it was not told to reach), so that attention can offer
//! "reach beacon N" for a beacon in view before anyone designated it. When beacon N is then
//! designated, a sighting of it at most `seed_s` old starts the track: predicted from the
//! designation for `hold_s`, so the reacher turns toward where the beacon was seen even if it
//! has left the image since (the operator's order comes after the offer).
//!
//! Quality Q (`ctx.set_quality`): the track's quality (the detector's fill x size x
//! brightness; the histogram tracker's at most 0.75), half of it, falling to 0 over `hold_s`,
//! while the beacon is only predicted; 0 when the beacon is lost, not
//! designated or unknown (an unknown id has no colours in view: lost); aptitude 0 and Q = -1
//! without images for `frame_timeout_s`. Malformed images (payload not `width * height * 3`
//! bytes of rgb8) are dropped and counted.
//!
//! The camera model comes from each image: its size and its horizontal field of view
//! (`ImageInfo` v2 `hfov`, filled by the simulator from the world's camera). An image without
//! a usable `hfov` (a camera that does not give it) is dropped and counted, said once in the
//! log: the tracker cannot turn columns into bearings, and without usable images it is not apt
//! (Q = -1 after `frame_timeout_s`).
//!
//! `lie = true` (tests of client feedback): the tracker claims Q = 1 and state "seen" for
//! every image, reporting the bearing off by `lie_bearing_rad` and, once it loses the beacon,
//! the last values it had; its clients' feedback is what exposes it.

use std::marker::PhantomData;
use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::SliceProviderInput;
use hng_runtime::msg::ImageInfo;
use hng_runtime::msg::{
    BeaconTrack, DESIGNATION_CHANNEL, Designation, FrameId, Header, TRACK_LOST, TRACK_PREDICTED,
    TRACK_SEEN,
};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::{Deserialize, Serialize};

use crate::common::{field_error, seconds};
use crate::tracker::{
    BeaconTrack as Track, CameraModel, ColourTracker, ColourTrackerConfig, Detection, TrackState,
};
use crate::tracker_hist::{HistogramTracker, HistogramTrackerConfig};
use crate::video::{check_rgb8, image_hfov};

/// The service the trackers provide.
pub const TRACK_BEACON: &str = "Track beacon";
/// Rank of the trackers' "Video" need.
pub const VIDEO_NEED: u16 = 1;

/// A tracking algorithm the module can run.
pub trait Detector: Sized + 'static {
    /// Its parameters (the `algorithm` table of the module's config).
    type Params: Default + Clone + for<'de> Deserialize<'de> + std::fmt::Debug;
    /// A detector for images of `camera`.
    fn build(params: Self::Params, camera: CameraModel) -> Self;
    /// Beacon `id` in one RGB8 image.
    fn detect(&mut self, image: &[u8], id: u32) -> Option<Detection>;
}

impl Detector for ColourTracker {
    type Params = ColourTrackerConfig;
    fn build(params: ColourTrackerConfig, camera: CameraModel) -> Self {
        ColourTracker::new(params, camera)
    }
    fn detect(&mut self, image: &[u8], id: u32) -> Option<Detection> {
        ColourTracker::detect(self, image, id)
    }
}

impl Detector for HistogramTracker {
    type Params = HistogramTrackerConfig;
    fn build(params: HistogramTrackerConfig, camera: CameraModel) -> Self {
        HistogramTracker::new(params, camera)
    }
    fn detect(&mut self, image: &[u8], id: u32) -> Option<Detection> {
        HistogramTracker::detect(self, image, id)
    }
}

/// Configuration of the tracker modules.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerConfig<P> {
    /// Images read until a "Video" provider is contracted (default `camera/image`).
    pub image: String,
    /// Where tracks go, the offer's data channel (default `<module name>/track`).
    pub track_out: String,
    /// Designations (default `operator/designation`).
    pub designation: String,
    /// Height of the beacon markers, m (default 0.6).
    pub beacon_height: f64,
    /// Radius of the beacon markers, m (default 0.1).
    pub beacon_radius: f64,
    /// How long a hidden beacon is predicted, s (default 1.5).
    pub hold_s: f64,
    /// No image for this long: aptitude 0, s (default 1.0).
    pub frame_timeout_s: f64,
    /// Claim Q = 1 while reporting a wrong bearing (tests of client feedback; default false).
    pub lie: bool,
    /// The liar's bearing error, rad (default 0.5).
    pub lie_bearing_rad: f64,
    /// Beacon ids looked for while none is designated, so attention can offer "reach beacon
    /// N" for a beacon in view (default 1 to 9; empty: no discovery).
    pub discover: Vec<u32>,
    /// Look for them in one image of this many, while none is designated (default 5: 3 Hz
    /// at 15 Hz; attention forgets a beacon after 1 s).
    pub discover_every: u32,
    /// A designated beacon discovered at most this long before its designation starts its
    /// track from that sighting, s (default 3.0; 0: never).
    pub seed_s: f64,
    /// The algorithm's parameters.
    pub algorithm: P,
}

impl<P: Default> Default for TrackerConfig<P> {
    fn default() -> Self {
        TrackerConfig {
            image: "camera/image".into(),
            track_out: String::new(),
            designation: DESIGNATION_CHANNEL.into(),
            beacon_height: 0.6,
            beacon_radius: 0.1,
            hold_s: 1.5,
            frame_timeout_s: 1.0,
            lie: false,
            lie_bearing_rad: 0.5,
            discover: (1..=9).collect(),
            discover_every: 5,
            seed_s: 3.0,
            algorithm: P::default(),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct TrackerState {
    frames: u64,
    dropped: u64,
    seen: u64,
}

/// A tracker module running detector `D`; see the module documentation.
pub struct TrackerModule<D: Detector> {
    cfg: TrackerConfig<D::Params>,
    video: SliceProviderInput<ImageInfo>,
    designation: Subscriber<Designation>,
    out: Publisher<BeaconTrack>,
    /// The designated beacon, if any.
    target: Option<u32>,
    detector: Option<(CameraModel, D)>,
    track: Track,
    /// The latest discovery of each beacon id while none was designated: (detection, s).
    sightings: Vec<(Detection, f64)>,
    /// The liar's last report.
    lied: Option<(f64, f64)>,
    last_frame: Option<Duration>,
    state: TrackerState,
    /// An image without a usable field of view was reported (said once).
    said_no_fov: bool,
    _d: PhantomData<D>,
}

/// `hng module tracker_colour`.
pub type ColourTrackerModule = TrackerModule<ColourTracker>;
/// `hng module tracker_histogram`.
pub type HistogramTrackerModule = TrackerModule<HistogramTracker>;

impl<D: Detector> std::fmt::Debug for TrackerModule<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrackerModule")
            .field("target", &self.target)
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

impl<D: Detector> Module for TrackerModule<D> {
    type Config = TrackerConfig<D::Params>;

    fn configure(ctx: &mut Context, mut cfg: Self::Config) -> ModuleResult<Self> {
        seconds("hold_s", cfg.hold_s)?;
        if !(cfg.seed_s.is_finite() && cfg.seed_s >= 0.0) {
            return Err(
                field_error("seed_s", "must be a finite number of seconds, 0 or more").into(),
            );
        }
        let timeout = seconds("frame_timeout_s", cfg.frame_timeout_s)?;
        for (f, v) in [
            ("beacon_height", cfg.beacon_height),
            ("beacon_radius", cfg.beacon_radius),
        ] {
            crate::common::positive(f, v)?;
        }
        if cfg.discover_every == 0 {
            return Err(field_error("discover_every", "must be at least 1").into());
        }
        if !cfg.lie_bearing_rad.is_finite() {
            return Err(field_error("lie_bearing_rad", "must be finite").into());
        }
        if cfg.track_out.is_empty() {
            cfg.track_out = format!("{}/track", ctx.name());
        }
        let mut offer = ServiceOffer::new(TRACK_BEACON, "hng/BeaconTrack/v1");
        offer.channel = cfg.track_out.clone();
        ctx.provide(offer)
            .need(NeedSpec::required("Video", VIDEO_NEED));
        ctx.set_quality(false, -1.0);
        // The frame timeout: a timer looks at the age of the last image.
        ctx.add_timer(timeout.min(Duration::from_millis(250)));
        // A left image channel is closed: the Camera works only while its images have readers.
        let video = SliceProviderInput::new()
            .keep_left(0)
            .with_fallback(ctx, &cfg.image)?;
        if cfg.lie {
            tracing::warn!(
                module = ctx.name(),
                "lie = true: claiming Q = 1 with a wrong bearing (a test of client feedback)"
            );
        }
        Ok(TrackerModule {
            designation: ctx.subscribe(&cfg.designation, None)?,
            out: ctx.publisher(&cfg.track_out)?,
            video,
            target: None,
            detector: None,
            track: Track::default(),
            sightings: Vec::new(),
            lied: None,
            last_frame: None,
            state: TrackerState::default(),
            said_no_fov: false,
            cfg,
            _d: PhantomData,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if input == self.designation.id() {
            while let Some(d) = self.designation.receive()? {
                let next = (d.active != 0).then_some(d.beacon_id);
                if next != self.target {
                    let now = ctx.now().as_secs_f64();
                    let seed = next.and_then(|id| {
                        self.sightings
                            .iter()
                            .find(|(d, t)| d.id == id && now - t <= self.cfg.seed_s)
                    });
                    tracing::info!(
                        module = ctx.name(),
                        beacon = ?next,
                        seen_s_ago = seed.map(|(_, t)| now - t),
                        "designation"
                    );
                    self.track = seed.map_or_else(Track::default, |(d, _)| Track::seeded(*d, now));
                    self.lied = None;
                }
                self.target = next;
            }
            return Ok(());
        }
        if !self.video.is(input) {
            return Ok(());
        }
        while let Some(frame) = self.video.receive()? {
            let info = *frame.header();
            let fov = image_hfov(&info);
            if let Some(why) = check_rgb8(&info, frame.data().len()).or(fov.clone().err()) {
                self.state.dropped += 1;
                let c = &ctx.node().counters().msgs_dropped;
                c.set(c.get() + 1);
                let no_fov = fov.is_err();
                if !(no_fov && self.said_no_fov) {
                    tracing::warn!(
                        module = ctx.name(),
                        dropped = self.state.dropped,
                        "image dropped: {why}{}",
                        if no_fov { " (said once; counted)" } else { "" }
                    );
                }
                self.said_no_fov |= no_fov;
                continue;
            }
            self.state.frames += 1;
            self.last_frame = Some(ctx.now());
            let t = info.header.stamp_ns as f64 * 1e-9;
            let target = self.target;
            let discover = target.is_none()
                && !self.cfg.discover.is_empty()
                && self
                    .state
                    .frames
                    .is_multiple_of(u64::from(self.cfg.discover_every));
            let ids = if discover {
                self.cfg.discover.clone()
            } else {
                Vec::new()
            };
            let detector = self.detector_for(info.width, info.height, info.hfov);
            let mut found = Vec::new();
            let detection = match (target, detector) {
                (Some(id), Some(d)) => d.detect(frame.data(), id),
                (None, Some(d)) if discover => {
                    found.extend(ids.iter().filter_map(|id| d.detect(frame.data(), *id)));
                    None
                }
                _ => None,
            };
            drop(frame);
            let state = self.track.update(detection, t, self.cfg.hold_s);
            self.report(ctx, state)?;
            for d in found {
                self.out.publish(discovered(&info.header, &d))?;
                self.sightings.retain(|(s, _)| s.id != d.id);
                self.sightings.push((d, t));
            }
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        let silent = self
            .last_frame
            .is_none_or(|t| ctx.now().saturating_sub(t).as_secs_f64() > self.cfg.frame_timeout_s);
        if silent {
            ctx.set_quality(false, -1.0);
        }
        Ok(())
    }

    hng_runtime::follow_needs!(VIDEO_NEED => video);

    hng_runtime::checkpoint_field!(state);
}

/// The track of a beacon found while none is designated: seen, with the detection's bearing,
/// range and quality (the module's own Q stays 0: it tracks nothing for a client).
fn discovered(image: &Header, d: &Detection) -> BeaconTrack {
    BeaconTrack {
        header: Header {
            frame_id: FrameId::CAMERA,
            stamp_ns: image.stamp_ns,
            ..Header::default()
        },
        beacon_id: d.id,
        state: TRACK_SEEN,
        bearing: d.bearing,
        range: d.range,
        quality: d.quality as f32,
    }
}

impl<D: Detector> TrackerModule<D> {
    /// The detector for images of `width` x `height` seen with field of view `fov` (rebuilt
    /// when either changes).
    fn detector_for(&mut self, width: u32, height: u32, fov: f64) -> Option<&mut D> {
        let camera = CameraModel {
            width,
            height,
            fov,
            beacon_height: self.cfg.beacon_height,
            beacon_radius: self.cfg.beacon_radius,
        };
        if self.detector.as_ref().is_none_or(|(c, _)| *c != camera) {
            self.detector = Some((camera, D::build(self.cfg.algorithm.clone(), camera)));
        }
        self.detector.as_mut().map(|(_, d)| d)
    }

    /// Publishes the track of one image and sets Q from it.
    fn report(&mut self, ctx: &mut Context, state: TrackState) -> ModuleResult {
        let beacon_id = self.target.unwrap_or(0);
        let mut msg = BeaconTrack {
            header: Header {
                frame_id: FrameId::CAMERA,
                ..Header::default()
            },
            beacon_id,
            ..Default::default()
        };
        let q = match state {
            TrackState::Seen(d) => {
                self.state.seen += 1;
                (msg.state, msg.bearing, msg.range) = (TRACK_SEEN, d.bearing, d.range);
                d.quality
            }
            TrackState::Predicted(d, _) => {
                (msg.state, msg.bearing, msg.range) = (TRACK_PREDICTED, d.bearing, d.range);
                // A prediction is worth at most half a sighting: a tracker that sees the
                // beacon beats one that only remembers it.
                0.5 * d.quality
            }
            TrackState::Lost => {
                msg.state = TRACK_LOST;
                0.0
            }
        };
        msg.quality = q as f32;
        if self.cfg.lie && self.target.is_some() {
            if msg.state == TRACK_SEEN {
                self.lied = Some((msg.bearing + self.cfg.lie_bearing_rad, msg.range));
            }
            if let Some((b, r)) = self.lied {
                (msg.state, msg.bearing, msg.range, msg.quality) = (TRACK_SEEN, b, r, 1.0);
            }
        }
        ctx.set_quality(true, msg.quality);
        self.out.publish(msg)?;
        Ok(())
    }
}
