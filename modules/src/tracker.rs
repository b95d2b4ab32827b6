//! Beacon tracking in camera images (Table 1: the Visual tracker, "Track beacon").
//!
//! Beacons wear two colour bands, top and bottom, picked from their id
//! ([`hng_runtime::msg::beacon_colors`]). [`ColourTracker`] segments an RGB8 image by
//! chromaticity (each colour divided by its brightness, so a uniformly darker scene keeps its
//! hues), keeps the columns where the designated beacon's top band lies above its bottom band,
//! and reports the blob's bearing (from its centre column) and range (from its height in pixels,
//! since the marker's height is known). Pixels darker than `min_brightness` carry no usable hue
//! and are ignored, so in poor light the blob thins out and the quality falls: the honest
//! self-evaluation attention needs to switch trackers.
//!
//! [`BeaconTrack`] turns detections into a track: through a short occlusion it keeps
//! predicting the last bearing and range with a quality that falls to 0 over `hold`; after that
//! the beacon is lost.

use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

/// The camera as a tracker needs it: image size and horizontal field of view (a pinhole with
/// the optical axis at the image centre), and the known height of the beacon markers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct CameraModel {
    /// Image width, pixels.
    #[default(320)]
    pub width: u32,
    /// Image height, pixels.
    #[default(240)]
    pub height: u32,
    /// Horizontal field of view, rad.
    #[default(1.2)]
    pub fov: f64,
    /// Height of a beacon marker, m.
    #[default(0.6)]
    pub beacon_height: f64,
    /// Radius of a beacon marker, m (its width gives the range when the marker is taller than
    /// the image, close up).
    #[default(0.1)]
    pub beacon_radius: f64,
}

impl CameraModel {
    /// Focal length, pixels.
    #[must_use]
    pub fn focal_px(&self) -> f64 {
        f64::from(self.width) / 2.0 / (self.fov / 2.0).tan()
    }

    /// Width and height of `image` (RGB8, `width * height * 3` bytes) if it is one of this
    /// camera's images.
    #[must_use]
    pub fn image_size(&self, image: &[u8]) -> Option<(usize, usize)> {
        let (w, h) = (self.width as usize, self.height as usize);
        (image.len() == w * h * 3).then_some((w, h))
    }
}

/// A beacon found in one image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// Beacon id.
    pub id: u32,
    /// Bearing, rad, counter-clockwise from the optical axis (positive: left).
    pub bearing: f64,
    /// Estimated range, m.
    pub range: f64,
    /// Self-evaluated quality in [0, 1].
    pub quality: f64,
    /// Bounding box: columns `u0..u1`, rows `v0..v1`.
    pub bbox: [u32; 4],
}

/// Parameters of the colour-segmentation tracker.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct ColourTrackerConfig {
    /// Largest chromaticity distance of a band pixel from its band colour (default 0.06).
    #[default(0.06)]
    pub tolerance: f64,
    /// Pixels whose r + g + b is below this carry no usable colour (default 90).
    #[default(90)]
    pub min_brightness: u32,
    /// Fewest band pixels of each band for a detection (default 6).
    #[default(6)]
    pub min_pixels: u32,
    /// Mean r + g + b of the band pixels at which their colour is fully trusted; quality falls
    /// linearly from there to `min_brightness` (default 200).
    #[default(200)]
    pub good_brightness: u32,
}

/// Colour-segmentation tracker: see the module documentation.
#[derive(Debug, Clone)]
pub struct ColourTracker {
    cfg: ColourTrackerConfig,
    camera: CameraModel,
    /// Per column: top-band pixel count, bottom-band count, top band's first row, bottom
    /// band's last row.
    columns: Vec<(u32, u32, u32, u32)>,
    /// Per column: summed brightness (r + g + b) of its band pixels.
    brightness: Vec<u64>,
}

fn chroma(c: [u8; 3]) -> Option<[f64; 2]> {
    let s = u32::from(c[0]) + u32::from(c[1]) + u32::from(c[2]);
    (s > 0).then(|| {
        let s = f64::from(s);
        [f64::from(c[0]) / s, f64::from(c[1]) / s]
    })
}

impl ColourTracker {
    /// A tracker for images of `camera`.
    #[must_use]
    pub fn new(cfg: ColourTrackerConfig, camera: CameraModel) -> Self {
        ColourTracker {
            cfg,
            camera,
            columns: Vec::new(),
            brightness: Vec::new(),
        }
    }

    /// Finds beacon `id` in `image` (RGB8, row-major, top row first, `width * height * 3`
    /// bytes); `None` if it is not seen or the image has the wrong size.
    pub fn detect(&mut self, image: &[u8], id: u32) -> Option<Detection> {
        let (w, _) = self.camera.image_size(image)?;
        let (top_rgb, bottom_rgb) = hng_runtime::msg::beacon_colors(id);
        let (top, bottom) = (chroma(top_rgb)?, chroma(bottom_rgb)?);
        let tol2 = self.cfg.tolerance * self.cfg.tolerance;
        self.columns.clear();
        self.columns.resize(w, (0, 0, u32::MAX, 0));
        self.brightness.clear();
        self.brightness.resize(w, 0);
        for (v, row) in image.chunks_exact(w * 3).enumerate() {
            for (u, px) in row.chunks_exact(3).enumerate() {
                let s = u32::from(px[0]) + u32::from(px[1]) + u32::from(px[2]);
                if s < self.cfg.min_brightness {
                    continue;
                }
                let sf = f64::from(s);
                let c = [f64::from(px[0]) / sf, f64::from(px[1]) / sf];
                let d = |t: [f64; 2]| (c[0] - t[0]).powi(2) + (c[1] - t[1]).powi(2);
                let col = &mut self.columns[u];
                if d(top) < tol2 {
                    col.0 += 1;
                    col.2 = col.2.min(v as u32);
                    self.brightness[u] += u64::from(s);
                } else if d(bottom) < tol2 {
                    col.1 += 1;
                    col.3 = col.3.max(v as u32);
                    self.brightness[u] += u64::from(s);
                }
            }
        }
        let brightness = &self.brightness;
        marker(
            &self.camera,
            &self.columns,
            brightness,
            id,
            self.cfg.min_pixels,
            |mean_s| {
                let (lo, hi) = (
                    f64::from(self.cfg.min_brightness),
                    f64::from(self.cfg.good_brightness.max(self.cfg.min_brightness + 1)),
                );
                ((mean_s - lo) / (hi - lo)).clamp(0.0, 1.0)
            },
        )
    }
}

/// Per column of an image: top-band pixel count, bottom-band count, top band's first row,
/// bottom band's last row (the trackers' common intermediate result).
pub(crate) type Column = (u32, u32, u32, u32);

/// The marker in per-column band counts: the widest run of columns with the top band above
/// the bottom band, with at least `min_pixels` of each; bearing from its centre column, range
/// from its height (from its width when it is cut by the image's top or bottom edge), and
/// quality = band fill x blob size x `light(mean band brightness)`.
pub(crate) fn marker(
    camera: &CameraModel,
    columns: &[Column],
    brightness: &[u64],
    id: u32,
    min_pixels: u32,
    light: impl Fn(f64) -> f64,
) -> Option<Detection> {
    let w = columns.len();
    let good = |c: &Column| c.0 > 0 && c.1 > 0 && c.2 < c.3;
    let mut best: Option<(usize, usize)> = None;
    let mut start = None;
    for u in 0..=w {
        let ok = columns.get(u).is_some_and(good);
        match (ok, start) {
            (true, None) => start = Some(u),
            (false, Some(s)) => {
                if best.is_none_or(|(a, b)| u - s > b - a) {
                    best = Some((s, u));
                }
                start = None;
            }
            _ => {}
        }
    }
    let (u0, u1) = best?;
    let cols = &columns[u0..u1];
    let n_top: u32 = cols.iter().map(|c| c.0).sum();
    let n_bottom: u32 = cols.iter().map(|c| c.1).sum();
    if n_top < min_pixels || n_bottom < min_pixels {
        return None;
    }
    let v0 = cols.iter().map(|c| c.2).min()?;
    let v1 = cols.iter().map(|c| c.3).max()? + 1;
    let f = camera.focal_px();
    let uc = (u0 + u1) as f64 / 2.0;
    let bearing = ((f64::from(camera.width) / 2.0 - uc) / f).atan();
    let height_px = f64::from(v1 - v0);
    let width_px = (u1 - u0) as f64;
    let clipped = v0 == 0 || v1 >= camera.height;
    let range = if clipped && u0 > 0 && u1 < w {
        f * 2.0 * camera.beacon_radius / width_px / bearing.cos()
    } else {
        f * camera.beacon_height / height_px / bearing.cos()
    };
    // Quality: how much of the box is band-coloured, how big the blob is (a few pixels say
    // little about range), and how bright its pixels are (dim colours are noisy hues).
    let area = width_px * height_px;
    let n = n_top + n_bottom;
    let fill = (f64::from(n) / area).min(1.0);
    let size = (height_px / 12.0).min(1.0);
    let mean_s = brightness[u0..u1].iter().sum::<u64>() as f64 / f64::from(n);
    Some(Detection {
        id,
        bearing,
        range,
        quality: fill * size * light(mean_s),
        bbox: [u0 as u32, u1 as u32, v0, v1],
    })
}

/// A beacon track over time: the last detection, predicted through short occlusions.
#[derive(Debug, Clone, Default)]
pub struct BeaconTrack {
    last: Option<(Detection, f64)>,
}

/// The state of a [`BeaconTrack`] at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrackState {
    /// Seen in the latest image.
    Seen(Detection),
    /// Not seen for the given seconds; the last detection with its quality lowered.
    Predicted(Detection, f64),
    /// Not seen for longer than `hold`, or never.
    Lost,
}

impl BeaconTrack {
    /// A track that starts from a sighting `d` taken before the designation, counted as seen
    /// at `t` (s): it is predicted from there for `hold`, so a client turns toward where the
    /// beacon was seen until the tracker sees it again.
    #[must_use]
    pub fn seeded(d: Detection, t: f64) -> Self {
        BeaconTrack { last: Some((d, t)) }
    }

    /// Feeds the result of one image at time `t` (s); `hold` is how long (s) a beacon is
    /// predicted after it was last seen.
    pub fn update(&mut self, detection: Option<Detection>, t: f64, hold: f64) -> TrackState {
        if let Some(d) = detection {
            self.last = Some((d, t));
            return TrackState::Seen(d);
        }
        match self.last {
            Some((d, seen)) if t - seen <= hold && hold > 0.0 => {
                let age = (t - seen).max(0.0);
                let q = d.quality * (1.0 - age / hold);
                TrackState::Predicted(Detection { quality: q, ..d }, age)
            }
            _ => {
                self.last = None;
                TrackState::Lost
            }
        }
    }
}

/// The trackers' test scene: a grey 320 x 240 image with the marker of beacon `id` painted at
/// columns `u0..u1`, rows `v0..v1`, all at brightness `light`; `noisy` adds a sky above row
/// 100 and a little deterministic noise (+-2).
#[cfg(test)]
pub(crate) fn test_scene(
    id: u32,
    (u0, u1): (usize, usize),
    (v0, v1): (usize, usize),
    light: f64,
    noisy: bool,
) -> Vec<u8> {
    let (w, h) = (320, 240);
    let mut img = vec![0u8; w * h * 3];
    let (top, bottom) = hng_runtime::msg::beacon_colors(id);
    let mut state = 12345u32;
    for v in 0..h {
        for u in 0..w {
            let c = if (u0..u1).contains(&u) && (v0..v1).contains(&v) {
                if v < (v0 + v1) / 2 { top } else { bottom }
            } else if noisy && v < 100 {
                [190, 215, 245]
            } else {
                [120, 120, 115]
            };
            let i = (v * w + u) * 3;
            for k in 0..3 {
                let n = if noisy {
                    state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
                    f64::from((state >> 16) % 5) - 2.0
                } else {
                    0.0
                };
                img[i + k] = (f64::from(c[k]) * light + n).clamp(0.0, 255.0) as u8;
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`test_scene`] without noise.
    fn painted(id: u32, u0: usize, u1: usize, v0: usize, v1: usize, light: f64) -> Vec<u8> {
        test_scene(id, (u0, u1), (v0, v1), light, false)
    }

    #[test]
    fn finds_the_designated_beacon_with_bearing_and_range() {
        let cam = CameraModel::default();
        let f = cam.focal_px();
        // A marker 2 m away straight ahead: f * 0.6 / 2 pixels tall, 2 * f * 0.1 / 2 wide.
        let hpx = (f * 0.6 / 2.0).round() as usize;
        let wpx = (f * 0.2 / 2.0).round() as usize;
        let img = painted(3, 160 - wpx / 2, 160 + wpx / 2, 100, 100 + hpx, 1.0);
        let mut t = ColourTracker::new(ColourTrackerConfig::default(), cam);
        let d = t.detect(&img, 3).expect("beacon 3 seen");
        assert!(d.bearing.abs() < 0.01, "{d:?}");
        assert!((d.range - 2.0).abs() < 0.05, "{d:?}");
        assert!(d.quality > 0.9, "{d:?}");
        // Another id (other colours) is not there.
        assert_eq!(t.detect(&img, 4), None);
    }

    #[test]
    fn the_bearing_follows_the_column_and_darkness_lowers_quality_then_loses_it() {
        let cam = CameraModel::default();
        let mut t = ColourTracker::new(ColourTrackerConfig::default(), cam);
        // Left of centre: positive bearing.
        let img = painted(1, 60, 70, 90, 150, 1.0);
        let d = t.detect(&img, 1).expect("seen");
        let want = ((160.0 - 65.0) / cam.focal_px()).atan();
        assert!((d.bearing - want).abs() < 0.005, "{d:?} vs {want}");
        // Dark: the hues survive (chromaticity) with a lower quality, until the pixels are too
        // dark to carry any.
        let dim = t
            .detect(&painted(1, 60, 70, 90, 150, 0.5), 1)
            .expect("dim but seen");
        assert!(dim.quality > 0.2 && dim.quality < d.quality, "{dim:?}");
        assert_eq!(t.detect(&painted(1, 60, 70, 90, 150, 0.1), 1), None);
    }

    #[test]
    fn bands_in_the_wrong_order_or_a_wrong_sized_image_give_nothing() {
        let cam = CameraModel::default();
        let mut t = ColourTracker::new(ColourTrackerConfig::default(), cam);
        let (top, bottom) = hng_runtime::msg::beacon_colors(2);
        // Upside down: bottom colour on top.
        let mut img = painted(2, 100, 110, 50, 110, 1.0);
        for v in 50..110 {
            for u in 100..110 {
                let c = if v < 80 { bottom } else { top };
                let i = (v * 320 + u) * 3;
                img[i..i + 3].copy_from_slice(&c);
            }
        }
        assert_eq!(t.detect(&img, 2), None);
        assert_eq!(t.detect(&img[..100], 2), None);
    }

    #[test]
    fn a_track_predicts_through_a_short_occlusion_then_loses_the_beacon() {
        let d = Detection {
            id: 1,
            bearing: 0.2,
            range: 3.0,
            quality: 0.9,
            bbox: [0, 1, 0, 1],
        };
        let mut track = BeaconTrack::default();
        assert_eq!(track.update(Some(d), 0.0, 1.5), TrackState::Seen(d));
        let TrackState::Predicted(p, age) = track.update(None, 1.0, 1.5) else {
            panic!("predicted through 1 s");
        };
        assert!(
            (age - 1.0).abs() < 1e-9 && (p.quality - 0.3).abs() < 1e-9,
            "{p:?}"
        );
        assert_eq!(p.bearing, 0.2);
        assert_eq!(track.update(None, 1.6, 1.5), TrackState::Lost);
        assert_eq!(track.update(None, 1.7, 1.5), TrackState::Lost);
    }

    #[test]
    fn a_seeded_track_is_predicted_from_its_sighting_until_seen_or_lost() {
        let d = Detection {
            id: 3,
            bearing: 0.6,
            range: 3.5,
            quality: 0.8,
            bbox: [0, 1, 0, 1],
        };
        // Designated at 10 s from a sighting: predicted with its bearing, quality falling.
        let mut track = BeaconTrack::seeded(d, 10.0);
        let TrackState::Predicted(p, age) = track.update(None, 10.5, 1.5) else {
            panic!("a seeded track is predicted");
        };
        assert!((age - 0.5).abs() < 1e-9 && p.bearing == 0.6 && p.quality < 0.8);
        let seen = Detection { bearing: 0.1, ..d };
        assert_eq!(track.update(Some(seen), 10.6, 1.5), TrackState::Seen(seen));
        // Never seen after its seed: lost once `hold` has passed.
        let mut track = BeaconTrack::seeded(d, 10.0);
        assert_eq!(track.update(None, 11.6, 1.5), TrackState::Lost);
    }
}
