//! Wall detection module (`hng module walls`; Table 1's Wall follower split in two: this is
//! "Detect wall", needing "LIDAR data").
//!
//! At every scan it extracts the straight walls ([`crate::walls::WallDetector`],
//! split-and-merge) and publishes them as [`Walls`] (`walls_out`, `walls/walls`: distance,
//! angle, length, side, end points in `base_link`, longest first, and the free distance
//! ahead). The scan comes from its "LIDAR data" provider while it is selected, and from
//! `scan` (`laser/scan`) while it is not: it detects all the time, so attention can offer
//! "follow wall" before anyone follows one.
//!
//! Aptitude 1 only while a wall is detected (a wall of at least `min_wall_length_m` within
//! `max_wall_distance_m`); Q = 1 − mean fit residual / 5 cm of those walls (in [0, 1]); −1
//! without scans. Checkpoint: counters.

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::ProviderInput;
use hng_runtime::msg::{LaserScan, MAX_WALLS, WallSegment, Walls};
use hng_runtime::{Context, Module, ModuleResult, Publisher};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{check_fields, positive, seconds};
use crate::walls::{Side, Wall, WallDetector, WallDetectorConfig};

/// The service this module provides.
pub const DETECT_WALL: &str = "Detect wall";
/// Rank of its "LIDAR data" need.
pub const LIDAR_NEED: u16 = 1;
/// Half-width of the sector ahead whose closest return is [`Walls::front`], rad (25 degrees).
pub const FRONT_HALF_ANGLE: f64 = 25.0 * std::f64::consts::PI / 180.0;

/// Configuration of `hng module walls`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct WallsConfig {
    /// Scans read while no LIDAR provider is selected (default `laser/scan`).
    #[default("laser/scan".into())]
    pub scan: String,
    /// Where the walls go (default `walls/walls`).
    #[default("walls/walls".into())]
    pub walls_out: String,
    /// A wall counts for the aptitude only if at least this long, m (default 0.5).
    #[default(0.5)]
    pub min_wall_length_m: f64,
    /// ... and at most this far, m (default 3).
    #[default(3.0)]
    pub max_wall_distance_m: f64,
    /// No scan for this long: aptitude 0, Q −1, s (default 1).
    #[default(1.0)]
    pub scan_timeout_s: f64,
    /// The extractor's parameters.
    #[default(WallDetectorConfig::default())]
    pub detector: WallDetectorConfig,
}

/// The side as a number on the wire: 1 left, -1 right, 2 front, -2 back.
pub fn side_number(s: Side) -> i32 {
    match s {
        Side::Left => 1,
        Side::Right => -1,
        Side::Front => 2,
        Side::Back => -2,
    }
}

/// The side from the wire (`None`: not a side).
pub fn side_of_number(n: i32) -> Option<Side> {
    Some(match n {
        1 => Side::Left,
        -1 => Side::Right,
        2 => Side::Front,
        -2 => Side::Back,
        _ => return None,
    })
}

/// A wire wall back as the library's.
pub fn wall_of_segment(w: &WallSegment) -> Option<Wall> {
    Some(Wall {
        distance: w.distance,
        normal_bearing: w.normal_bearing,
        angle: w.angle,
        length: w.length,
        side: side_of_number(w.side)?,
        beside: w.beside != 0,
        start: w.start,
        end: w.end,
        points: 0,
        rmse: f64::from(w.rmse),
    })
}

/// The message of one scan's walls: the longest [`MAX_WALLS`], and the free distance ahead.
pub fn walls_message(walls: &[Wall], scan: &LaserScan) -> Walls {
    let mut msg = Walls {
        front: front_distance(scan),
        ..Default::default()
    };
    msg.header.frame_id = scan.header.frame_id;
    let mut order: Vec<&Wall> = walls.iter().collect();
    order.sort_by(|a, b| b.length.total_cmp(&a.length));
    for (i, w) in order.into_iter().take(MAX_WALLS).enumerate() {
        msg.walls[i] = WallSegment {
            distance: w.distance,
            normal_bearing: w.normal_bearing,
            angle: w.angle,
            length: w.length,
            side: side_number(w.side),
            beside: u8::from(w.beside),
            start: w.start,
            end: w.end,
            rmse: w.rmse as f32,
        };
        msg.count += 1;
    }
    msg
}

/// The closest valid return within [`FRONT_HALF_ANGLE`] of straight ahead (infinite: none).
pub fn front_distance(scan: &LaserScan) -> f64 {
    let a0 = f64::from(scan.angle_min);
    let inc = f64::from(scan.angle_increment);
    let rmin = f64::from(scan.range_min);
    scan.ranges()
        .iter()
        .enumerate()
        .filter(|(i, _)| {
            let a = crate::common::wrap_angle(a0 + inc * *i as f64);
            a.abs() <= FRONT_HALF_ANGLE
        })
        .map(|(_, &r)| f64::from(r))
        .filter(|r| r.is_finite() && *r >= rmin)
        .fold(f64::INFINITY, f64::min)
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct WallsState {
    scans: u64,
    with_walls: u64,
}

/// The wall detection module.
#[derive(Debug)]
pub struct WallsModule {
    cfg: WallsConfig,
    detector: WallDetector,
    scan: ProviderInput<LaserScan>,
    out: Publisher<Walls>,
    walls: Vec<Wall>,
    state: WallsState,
}

impl WallsModule {
    fn on_scan(&mut self, ctx: &mut Context, scan: &LaserScan) -> ModuleResult {
        self.state.scans += 1;
        self.detector.detect_scan(scan, &mut self.walls);
        let msg = walls_message(&self.walls, scan);
        self.out.publish(msg)?;
        let counted: Vec<&Wall> = self
            .walls
            .iter()
            .filter(|w| {
                w.length >= self.cfg.min_wall_length_m && w.distance <= self.cfg.max_wall_distance_m
            })
            .collect();
        if counted.is_empty() {
            ctx.set_quality(false, 0.0);
        } else {
            self.state.with_walls += 1;
            let mean = counted.iter().map(|w| w.rmse).sum::<f64>() / counted.len() as f64;
            ctx.set_quality(true, (1.0 - mean / 0.05).clamp(0.0, 1.0) as f32);
        }
        Ok(())
    }
}

impl Module for WallsModule {
    type Config = WallsConfig;

    fn configure(ctx: &mut Context, cfg: WallsConfig) -> ModuleResult<Self> {
        check_fields!(positive, cfg; min_wall_length_m, max_wall_distance_m)?;
        let timeout = seconds("scan_timeout_s", cfg.scan_timeout_s)?;
        check_fields!(positive, cfg.detector, "detector"; split_tolerance, range_sigma,
            min_length, max_range)?;
        if cfg.walls_out.is_empty() || cfg.scan.is_empty() {
            return Err(crate::common::field_error("walls_out", "is empty").into());
        }
        let mut offer = ServiceOffer::new(DETECT_WALL, "hng/Walls/v1");
        offer.channel = cfg.walls_out.clone();
        ctx.provide(offer)
            .need(NeedSpec::required("LIDAR data", LIDAR_NEED));
        ctx.set_quality(false, -1.0);
        Ok(WallsModule {
            detector: WallDetector::new(cfg.detector),
            scan: ProviderInput::new()
                .with_deadline(Some(timeout))
                .with_fallback(ctx, &cfg.scan)?,
            out: ctx.publisher(&cfg.walls_out)?,
            walls: Vec::new(),
            state: WallsState::default(),
            cfg,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if self.scan.is(input) {
            while let Some(s) = self.scan.receive()? {
                let s = *s;
                self.on_scan(ctx, &s)?;
            }
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no scan: no walls");
        ctx.set_quality(false, -1.0);
        Ok(())
    }

    hng_runtime::follow_needs!(LIDAR_NEED => scan);

    hng_runtime::checkpoint_field!(state);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan_of(ranges: &[f32]) -> LaserScan {
        LaserScan::full_circle(ranges, 0.05, 10.0)
    }

    #[test]
    fn a_corridor_gives_a_wall_on_each_side_and_the_front_distance() {
        // A corridor 1.2 m wide along x, closed 2 m ahead: 360 beams from -pi.
        let n = 360;
        let ranges: Vec<f32> = (0..n)
            .map(|i| {
                let a = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * i as f64 / n as f64;
                let (c, s) = (a.cos(), a.sin());
                let mut r = f64::INFINITY;
                if s.abs() > 1e-9 {
                    r = r.min(0.6 / s.abs());
                }
                if c > 1e-9 {
                    r = r.min(2.0 / c);
                }
                r.min(9.0) as f32
            })
            .collect();
        let scan = scan_of(&ranges);
        let mut det = WallDetector::new(WallDetectorConfig::default());
        let mut walls = Vec::new();
        det.detect_scan(&scan, &mut walls);
        let msg = walls_message(&walls, &scan);
        assert!(
            msg.beside(1, 0.7) && msg.beside(-1, 0.7),
            "{:?}",
            msg.walls()
        );
        // The side walls enter the +-25 degree sector at 0.6 / sin 25 deg, before the end wall.
        let want = (0.6 / FRONT_HALF_ANGLE.sin()).min(2.0);
        assert!(
            (msg.front - want).abs() < 0.05,
            "front {} want {want}",
            msg.front
        );
        for w in msg.walls() {
            let back = wall_of_segment(w).expect("side");
            assert_eq!(side_number(back.side), w.side);
        }
        assert!(side_of_number(7).is_none());
    }
}
