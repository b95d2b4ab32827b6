//! `hng bench vision`: the camera images and the trackers.
//!
//! Cases (one sample per frame unless said):
//! - `render_320x240`: the simulator renders one 320 x 240 RGB8 image of the default world
//!   (ray casting, pixel noise on), from poses around the yard;
//! - `tracker_colour_320x240`, `tracker_histogram_320x240`: one detection of a beacon in
//!   view, on those rendered images;
//! - `image_hop_230400/<mode>`: one 230 400-byte frame (320 x 240 RGB8) from one process to
//!   another through the data plane (hng slice channel, loaned sample, the ping-pong of
//!   `hng bench ipc`: one way = half a round trip).

use anyhow::{Context as _, Result};
use clap::Args;
use hng_modules::tracker::{CameraModel, ColourTracker, ColourTrackerConfig};
use hng_modules::tracker_hist::{HistogramTracker, HistogramTrackerConfig};
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_simulator::render::{ImageParams, Renderer};
use hng_simulator::{Pose2D, World};
use std::time::{Duration, Instant};

use super::ipc::{Mode, Transport, run_mode};

/// What a tracker knows of the simulator's camera rendering with `params`.
pub fn camera_model(params: &ImageParams) -> CameraModel {
    CameraModel {
        width: params.width,
        height: params.height,
        fov: params.fov,
        beacon_height: params.beacon_height,
        ..CameraModel::default()
    }
}

/// Arguments of `hng bench vision`.
#[derive(Debug, Clone, Args)]
pub struct VisionArgs {
    /// Frames timed per in-process case.
    #[arg(long, default_value_t = 2000)]
    pub frames: usize,
    /// Frames sent in the image hop case.
    #[arg(long, default_value_t = 3000)]
    pub hop_samples: usize,
    /// Time limit of the image hop case, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub max_seconds: f64,
    /// One JSON object per case instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn time_each(n: usize, mut f: impl FnMut(usize)) -> Vec<u64> {
    (0..n)
        .map(|i| {
            let t = Instant::now();
            f(i);
            t.elapsed().as_nanos() as u64
        })
        .collect()
}

/// Runs every case and prints the rows.
pub fn run(a: &VisionArgs) -> Result<()> {
    let world = World::default_world();
    let params = ImageParams {
        noise_sigma: 2.0,
        ..ImageParams::default()
    };
    let renderer = Renderer::new(&world, params).context("renderer of the default world")?;
    // Poses around the yard, each with a beacon in view.
    let mut views: Vec<(Pose2D, u32)> = Vec::new();
    'grid: for i in 0..40 {
        for j in 0..30 {
            for k in 0..8 {
                let pose = Pose2D::new(
                    0.5 + f64::from(i) * 0.5,
                    0.5 + f64::from(j) * 0.5,
                    f64::from(k) * std::f64::consts::FRAC_PI_4,
                );
                if let Some(b) = world
                    .beacons
                    .iter()
                    .find(|b| renderer.beacon_box(pose, b.id).is_some())
                {
                    views.push((pose, b.id));
                }
                if views.len() >= 32 {
                    break 'grid;
                }
            }
        }
    }
    anyhow::ensure!(
        !views.is_empty(),
        "no beacon in view anywhere in the default world"
    );
    let mut img = vec![0u8; params.image_bytes()];
    let n = a.frames.max(1);
    let mut render = time_each(n, |i| {
        renderer.render_seeded(views[i % views.len()].0, 1.0, i as u64, &mut img);
    });
    let images: Vec<Vec<u8>> = views
        .iter()
        .enumerate()
        .map(|(k, (pose, _))| {
            let mut im = vec![0u8; params.image_bytes()];
            renderer.render_seeded(*pose, 1.0, k as u64, &mut im);
            im
        })
        .collect();
    let camera = camera_model(&params);
    let mut colour = ColourTracker::new(ColourTrackerConfig::default(), camera);
    let mut hist = HistogramTracker::new(HistogramTrackerConfig::default(), camera);
    let (mut found_c, mut found_h) = (0u64, 0u64);
    let mut t_colour = time_each(n, |i| {
        let k = i % views.len();
        found_c += u64::from(colour.detect(&images[k], views[k].1).is_some());
    });
    let mut t_hist = time_each(n, |i| {
        let k = i % views.len();
        found_h += u64::from(hist.detect(&images[k], views[k].1).is_some());
    });
    let mut rows = vec![
        BenchRow::new("vision", "render_320x240", Percentiles::of(&mut render))
            .with("bytes", params.image_bytes() as u64)
            .with("walls", world.walls.len() as u64),
        BenchRow::new(
            "vision",
            "tracker_colour_320x240",
            Percentiles::of(&mut t_colour),
        )
        .with("detected_share", found_c as f64 / n as f64),
        BenchRow::new(
            "vision",
            "tracker_histogram_320x240",
            Percentiles::of(&mut t_hist),
        )
        .with("detected_share", found_h as f64 / n as f64),
    ];
    let exe = std::env::current_exe().context("locating the hng executable")?;
    let max = Duration::from_secs_f64(a.max_seconds.max(0.1));
    for row in run_mode(
        &exe,
        &[Transport::Hng],
        &[params.image_bytes()],
        Mode::Blocking,
        a.hop_samples.max(10),
        3,
        max,
    )? {
        let mut hop = BenchRow::new(
            "vision",
            &format!("image_hop_{}/blocking", params.image_bytes()),
            Percentiles {
                p50_ns: json_u64(&row, "p50_ns"),
                p99_ns: json_u64(&row, "p99_ns"),
                p999_ns: json_u64(&row, "p999_ns"),
                max_ns: json_u64(&row, "max_ns"),
                samples: json_u64(&row, "samples"),
            },
        )
        .with("bytes", params.image_bytes() as u64)
        .with("transport", "hng");
        hop = hop.with("unit", "one way = round trip / 2");
        rows.push(hop);
    }
    super::print_rows(&rows, a.json);
    Ok(())
}

fn json_u64(row: &BenchRow, key: &str) -> u64 {
    row.get(key)
        .and_then(serde_json::Value::as_u64)
        .unwrap_or(0)
}
