//! The second "Track beacon" algorithm: a chromaticity-histogram tracker, slower than
//! [`crate::tracker::ColourTracker`] and robust to poor light.
//!
//! Where the colour tracker compares each pixel's chromaticity with the band colours within a
//! fixed tolerance and ignores every pixel darker than a fixed brightness (so it goes blind at
//! dusk), this one looks at the whole image first:
//!
//! 1. a first pass builds the 2D chromaticity histogram (`bins` x `bins` over r/s, g/s) of
//!    every pixel brighter than the noise floor (`min_brightness`, far lower), and the
//!    brightness histogram;
//! 2. each histogram bin is labelled top band, bottom band or neither by back-projecting the
//!    band colours: a bin is a band's when its centre lies within the band's tolerance, widened
//!    by the chromaticity noise expected at the image's band brightness (pixel noise
//!    `noise_sigma` divided by brightness: dark pixels have noisy hues), and when it does not
//!    hold more than `max_bin_share` of the image (a large uniform surface of that hue, sky or
//!    wall, is not a marker);
//! 3. a second pass labels every pixel through its bin and counts band pixels per column,
//!    only in vertical runs of at least 3 pixels of one band (the hue of a dark, noisy floor
//!    strays into a band's tolerance pixel by pixel, not in runs); the marker is then found as
//!    by the colour tracker ([`crate::tracker::marker`]).
//!
//! Its quality: band fill x blob size x a brightness term that reaches 1 at `good_brightness`
//! (far below the colour tracker's, since the tolerance follows the noise), times
//! `max_quality` (0.75): the widened tolerance takes in more stray pixels at the blob's edges,
//! so in good light it rates itself below the colour tracker, which then keeps the contract.

use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::tracker::{CameraModel, Column, Detection, marker};

/// Parameters of the histogram tracker.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct HistogramTrackerConfig {
    /// Histogram bins per chromaticity axis (default 48).
    #[default(48)]
    pub bins: u32,
    /// Chromaticity tolerance of a band in good light (default 0.07).
    #[default(0.07)]
    pub tolerance: f64,
    /// Pixels whose r + g + b is below this are noise (default 18).
    #[default(18)]
    pub min_brightness: u32,
    /// Mean r + g + b of the band pixels at which the brightness term reaches 1 (default 70).
    #[default(70)]
    pub good_brightness: u32,
    /// Expected pixel noise, 8-bit steps per channel (default 2).
    #[default(2.0)]
    pub noise_sigma: f64,
    /// A bin holding more than this share of the valid pixels is background (default 0.25).
    #[default(0.25)]
    pub max_bin_share: f64,
    /// Fewest band pixels of each band for a detection (default 6).
    #[default(6)]
    pub min_pixels: u32,
    /// The best quality it claims (default 0.75).
    #[default(0.75)]
    pub max_quality: f64,
}

const NONE: u8 = 0;
const TOP: u8 = 1;
const BOTTOM: u8 = 2;
/// Shortest vertical run of one band's pixels that counts.
const MIN_RUN: usize = 3;

/// The histogram tracker: see the module documentation.
#[derive(Debug, Clone)]
pub struct HistogramTracker {
    cfg: HistogramTrackerConfig,
    camera: CameraModel,
    hist: Vec<u32>,
    label: Vec<u8>,
    /// Per pixel: its histogram bin (u16::MAX: too dark).
    pixel_bin: Vec<u16>,
    columns: Vec<Column>,
    brightness: Vec<u64>,
}

impl HistogramTracker {
    /// A tracker for images of `camera`.
    #[must_use]
    pub fn new(cfg: HistogramTrackerConfig, camera: CameraModel) -> Self {
        let bins = cfg.bins.clamp(4, 128) as usize;
        HistogramTracker {
            cfg: HistogramTrackerConfig {
                bins: bins as u32,
                ..cfg
            },
            camera,
            hist: vec![0; bins * bins],
            label: vec![NONE; bins * bins],
            pixel_bin: Vec::new(),
            columns: Vec::new(),
            brightness: Vec::new(),
        }
    }

    /// Finds beacon `id` in `image` (RGB8, `width * height * 3` bytes); `None` if it is not
    /// seen or the image has the wrong size.
    pub fn detect(&mut self, image: &[u8], id: u32) -> Option<Detection> {
        let (w, h) = self.camera.image_size(image)?;
        let bins = self.cfg.bins as usize;
        let scale = bins as f64;
        self.hist.fill(0);
        self.pixel_bin.clear();
        self.pixel_bin.reserve(w * h);
        let mut valid = 0u32;
        let mut bright = [0u32; 766];
        // Pass 1: chromaticity and brightness histograms.
        for px in image.chunks_exact(3) {
            let s = u32::from(px[0]) + u32::from(px[1]) + u32::from(px[2]);
            bright[s as usize] += 1;
            if s < self.cfg.min_brightness {
                self.pixel_bin.push(u16::MAX);
                continue;
            }
            let sf = f64::from(s);
            let r = ((f64::from(px[0]) / sf * scale) as usize).min(bins - 1);
            let g = ((f64::from(px[1]) / sf * scale) as usize).min(bins - 1);
            let b = r * bins + g;
            self.hist[b] += 1;
            self.pixel_bin.push(b as u16);
            valid += 1;
        }
        if valid == 0 {
            return None;
        }
        // The image's exposure: the 99th percentile of brightness, which the band pixels of a
        // near marker reach; the band tolerance widens by the hue noise at that brightness (at most doubled).
        let mut seen = 0u32;
        let p99 = bright
            .iter()
            .position(|&n| {
                seen += n;
                f64::from(seen) >= 0.99 * (w * h) as f64
            })
            .unwrap_or(765)
            .max(1) as f64;
        let band_s = (0.5 * p99).max(f64::from(self.cfg.min_brightness));
        let tol = (self.cfg.tolerance + 1.5 * self.cfg.noise_sigma * 2f64.sqrt() / band_s)
            .min(2.0 * self.cfg.tolerance);
        // Back-projection: label the bins.
        let (top_rgb, bottom_rgb) = hng_runtime::msg::beacon_colors(id);
        let chroma = |c: [u8; 3]| {
            let s = f64::from(u32::from(c[0]) + u32::from(c[1]) + u32::from(c[2])).max(1.0);
            [f64::from(c[0]) / s, f64::from(c[1]) / s]
        };
        let (top, bottom) = (chroma(top_rgb), chroma(bottom_rgb));
        let max_count = (self.cfg.max_bin_share * f64::from(valid)) as u32;
        for r in 0..bins {
            for g in 0..bins {
                let c = [(r as f64 + 0.5) / scale, (g as f64 + 0.5) / scale];
                let d = |t: [f64; 2]| ((c[0] - t[0]).powi(2) + (c[1] - t[1]).powi(2)).sqrt();
                let (dt, db) = (d(top), d(bottom));
                let b = r * bins + g;
                self.label[b] = if self.hist[b] > max_count.max(1) {
                    NONE
                } else if dt < tol && dt <= db {
                    TOP
                } else if db < tol {
                    BOTTOM
                } else {
                    NONE
                };
            }
        }
        // Pass 2: band pixels per column, counted only in vertical runs of at least
        // `MIN_RUN` pixels of one band (isolated noisy pixels of a dark floor are not).
        self.columns.clear();
        self.columns.resize(w, (0, 0, u32::MAX, 0));
        self.brightness.clear();
        self.brightness.resize(w, 0);
        let label_of = |b: u16, labels: &[u8]| {
            if b == u16::MAX {
                NONE
            } else {
                labels[b as usize]
            }
        };
        let s_at = |i: usize| {
            u64::from(image[i * 3]) + u64::from(image[i * 3 + 1]) + u64::from(image[i * 3 + 2])
        };
        for u in 0..w {
            let (mut run_label, mut run_len, mut run_start) = (NONE, 0usize, 0usize);
            let col = &mut self.columns[u];
            let bright = &mut self.brightness[u];
            for v in 0..h {
                let l = label_of(self.pixel_bin[v * w + u], &self.label);
                if l == run_label {
                    run_len += 1;
                } else {
                    (run_label, run_len, run_start) = (l, 1, v);
                }
                if l == NONE || run_len < MIN_RUN {
                    continue;
                }
                let new_rows = if run_len == MIN_RUN {
                    run_start..v + 1
                } else {
                    v..v + 1
                };
                let n = new_rows.len() as u32;
                for r in new_rows {
                    *bright += s_at(r * w + u);
                }
                if l == TOP {
                    col.0 += n;
                    col.2 = col.2.min(run_start as u32);
                } else {
                    col.1 += n;
                    col.3 = col.3.max(v as u32);
                }
            }
        }
        let (lo, hi) = (
            f64::from(self.cfg.min_brightness),
            f64::from(self.cfg.good_brightness.max(self.cfg.min_brightness + 1)),
        );
        let max_q = self.cfg.max_quality.clamp(0.0, 1.0);
        marker(
            &self.camera,
            &self.columns,
            &self.brightness,
            id,
            self.cfg.min_pixels,
            |mean_s| max_q * ((mean_s - lo) / (hi - lo)).clamp(0.0, 1.0),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracker::{ColourTracker, ColourTrackerConfig};

    /// The trackers' test scene with a sky and noise.
    fn painted(id: u32, u0: usize, u1: usize, v0: usize, v1: usize, light: f64) -> Vec<u8> {
        crate::tracker::test_scene(id, (u0, u1), (v0, v1), light, true)
    }

    #[test]
    fn finds_the_beacon_where_the_colour_tracker_does_and_rates_itself_lower_in_good_light() {
        let cam = CameraModel::default();
        let img = painted(3, 150, 170, 80, 160, 1.0);
        let mut hist = HistogramTracker::new(HistogramTrackerConfig::default(), cam);
        let mut colour = ColourTracker::new(ColourTrackerConfig::default(), cam);
        let d = hist.detect(&img, 3).expect("seen by the histogram tracker");
        let c = colour.detect(&img, 3).expect("seen by the colour tracker");
        assert!((d.bearing - c.bearing).abs() < 0.01, "{d:?} {c:?}");
        assert!((d.range - c.range).abs() < 0.05 * c.range, "{d:?} {c:?}");
        assert!(d.quality < c.quality && d.quality > 0.6, "{d:?} {c:?}");
        assert_eq!(hist.detect(&img, 4), None, "another beacon's colours");
        assert_eq!(hist.detect(&img[..99], 3), None, "wrong size");
    }

    #[test]
    fn in_poor_light_it_keeps_the_beacon_the_colour_tracker_loses() {
        let cam = CameraModel::default();
        let mut hist = HistogramTracker::new(HistogramTrackerConfig::default(), cam);
        let mut colour = ColourTracker::new(ColourTrackerConfig::default(), cam);
        let dark = painted(1, 60, 75, 90, 150, 0.2);
        let c = colour.detect(&dark, 1).map_or(0.0, |d| d.quality);
        let d = hist.detect(&dark, 1).expect("seen in the dark");
        assert!(d.quality > c + 0.3, "histogram {d:?}, colour {c}");
        let want = ((160.0 - 67.5) / cam.focal_px()).atan();
        assert!((d.bearing - want).abs() < 0.01, "{d:?} vs {want}");
    }
}
