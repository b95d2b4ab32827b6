//! SLAM: localization and mapping from lidar and odometry (Table 1: provides "Localization"
//! and "Mapping", needs "Odometry" and "LIDAR data"; data out: position, map).
//!
//! [`SlamTracker`] (pure logic) runs the SLAM pipeline [`Slam`] (front end: correlative scan
//! matching with PL-ICP refinement against a sliding local map, a wide search for large steps;
//! back end: pose graph over submaps with loop closures, optimised on a background thread so
//! the scan loop never waits; see [`crate::slam`]) on every scan, with the odometry motion
//! since the previous scan as the prior. The pose and the map it publishes are the corrected
//! ones: an optimisation's correction moves the pose, and the map is re-rendered from the
//! optimised poses by the background thread. Between scans the pose is the last scan's pose
//! plus the odometry since, so the position is published at the odometry rate (50 Hz in the
//! simulator) rather than the scan rate. Each scan's beam geometry (`angle_min`,
//! `angle_increment`, `range_min`, `range_max`) is taken from that scan's message. The map
//! frame is fixed by `initial_pose` (the robot's start in the world, for the map to line up
//! with a known map).
//!
//! Contracts: provides "Localization" on `pose_out` and "Mapping" on `map_out`; needs
//! "Odometry" (rank 1, from the Robot) and "LIDAR data" (rank 2, from the Laser), followed on
//! their providers' channels. SLAM tracks whether selected or not (it must be ready when the
//! GPS degrades): while it has no provider (it is not selected, so it makes no contracts) it
//! reads the configured `odom` and `scan` channels.
//!
//! Quality Q: the front end's match quality (`2·score − 1`, see [`crate::slam::PoseEstimate`]),
//! smoothed over a few scans, times [`SLAM_Q_SCALE`]; -1 (aptitude 0) when scans or odometry stop.
//!
//! Idle rate: while no client is contracted to either offer, SLAM matches one scan in
//! `idle_scan_every` (default 5: 2 Hz at the simulator's 10 Hz lidar) and carries its pose on
//! the odometry between them: it keeps tracking, with its local map, graph and Q made from
//! the scans it matches, at a fraction of the CPU ([`IdleRate`]). From the first scan after
//! a contract is made it matches every scan again.
//!
//! The operator's pose estimate ([`crate::initial_pose`], `initial_pose_in`): a new map starts
//! there (the tracker is anchored at the estimate and the odometry of now, as after a restart).
//!
//! Checkpoint: the pose, the odometry reading it goes with, and the number of scans. After a
//! restart the tracker is anchored there: its first pose is the checkpointed pose plus the
//! odometry motion since the checkpoint, so the motion during the downtime (and since the last
//! periodic checkpoint) is not lost; the local map is rebuilt from the next scans.

use std::time::Duration;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::ProviderInput;
use hng_runtime::msg::{
    FrameId, GridInfo, Header, LaserScan, Odometry, Pose2D, PoseWithCovariance,
};
use hng_runtime::{Context, Module, ModuleResult, Publisher, SlicePublisher, TimerId};
use nalgebra::{Isometry2, Vector2};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{compose, relative, seconds};
use crate::initial_pose::{EstimateId, INITIAL_POSE_CHANNEL, InitialPoseInput};
use crate::slam::{BackendConfig, EstimateSource, LaserConfig, Slam, SlamConfig};

/// SLAM's contract Q is its smoothed match quality times this: at most 0.4, below the Q of a
/// nominal GPS fix (about 0.56 at σ 0.3 m) by more than the hysteresis (0.1), so the GPS
/// serves "Localization" where it is good and SLAM where it degrades (paper 5.8).
pub const SLAM_Q_SCALE: f64 = 0.4;

fn iso(p: &Pose2D) -> Isometry2<f64> {
    Isometry2::new(Vector2::new(p.x, p.y), p.theta)
}

fn pose(i: &Isometry2<f64>) -> Pose2D {
    Pose2D::new(i.translation.x, i.translation.y, i.rotation.angle())
}

/// The SLAM logic, without I/O.
#[derive(Debug)]
pub struct SlamTracker {
    cfg: SlamConfig,
    backend: BackendConfig,
    slam: Option<Slam>,
    /// Pose at the last scan, map frame.
    pose_at_scan: Pose2D,
    /// Odometry at the last scan.
    odom_at_scan: Option<Pose2D>,
    /// Latest odometry.
    odom: Option<Pose2D>,
    covariance: [f64; 9],
    quality: f64,
    scans: u64,
}

/// The result of one scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanResult {
    /// Pose, map frame.
    pub pose: Pose2D,
    /// Quality of this match in [-1, 1].
    pub quality: f64,
    /// Smoothed quality.
    pub smoothed_quality: f64,
    /// True if matched (not the odometry prior).
    pub matched: bool,
}

impl SlamTracker {
    /// A tracker whose map frame puts the robot at `initial` now.
    pub fn new(cfg: SlamConfig, initial: Pose2D) -> SlamTracker {
        SlamTracker {
            cfg,
            backend: BackendConfig {
                background: true,
                ..BackendConfig::default()
            },
            slam: None,
            pose_at_scan: initial,
            odom_at_scan: None,
            odom: None,
            covariance: [0.0; 9],
            quality: 0.0,
            scans: 0,
        }
    }

    /// A tracker resuming from a checkpoint: the robot was at `pose` (map frame) when the
    /// odometry read `odom`, so the next odometry places it at `pose` plus the motion since.
    /// Without `odom` (a checkpoint taken before any odometry) it starts at `pose`.
    pub fn resume(cfg: SlamConfig, pose: Pose2D, odom: Option<Pose2D>) -> SlamTracker {
        SlamTracker {
            odom_at_scan: odom,
            ..SlamTracker::new(cfg, pose)
        }
    }

    /// What a checkpoint needs to [`SlamTracker::resume`]: the current pose and the odometry
    /// reading it corresponds to.
    pub fn anchor(&self) -> (Pose2D, Option<Pose2D>) {
        (self.pose(), self.odom.or(self.odom_at_scan))
    }

    /// Odometry arrived.
    pub fn on_odometry(&mut self, odom: Pose2D) {
        if self.odom_at_scan.is_none() {
            self.odom_at_scan = Some(odom);
        }
        self.odom = Some(odom);
    }

    /// The current pose: the last scan's pose plus the odometry since.
    pub fn pose(&self) -> Pose2D {
        match (self.odom_at_scan, self.odom) {
            (Some(a), Some(b)) => compose(&self.pose_at_scan, &relative(&a, &b)),
            _ => self.pose_at_scan,
        }
    }

    /// Covariance of the last estimate.
    pub fn covariance(&self) -> [f64; 9] {
        self.covariance
    }

    /// Smoothed quality.
    pub fn quality(&self) -> f64 {
        self.quality
    }

    /// A scan arrived (matched with its own beam geometry).
    pub fn on_scan(&mut self, scan: &LaserScan) -> Option<ScanResult> {
        let odom = self.odom?;
        let delta = match self.odom_at_scan {
            Some(a) => relative(&a, &odom),
            None => Pose2D::default(),
        };
        let laser = LaserConfig {
            angle_min: f64::from(scan.angle_min),
            angle_increment: f64::from(scan.angle_increment),
            range_min: f64::from(scan.range_min),
            range_max: f64::from(scan.range_max),
        };
        let (cfg, backend, start) = (self.cfg, self.backend, iso(&self.pose_at_scan));
        let slam = self
            .slam
            .get_or_insert_with(|| Slam::new(cfg, backend, start));
        let est = slam.process(&iso(&delta), &laser, scan.ranges());
        self.pose_at_scan = pose(&est.pose);
        self.odom_at_scan = Some(odom);
        let c = est.covariance;
        self.covariance = [
            c[(0, 0)],
            c[(0, 1)],
            c[(0, 2)],
            c[(1, 0)],
            c[(1, 1)],
            c[(1, 2)],
            c[(2, 0)],
            c[(2, 1)],
            c[(2, 2)],
        ];
        self.scans += 1;
        let matched = est.source == EstimateSource::Matched;
        // Exponential smoothing: one poor scan does not make a poor localizer.
        self.quality = if self.scans == 1 {
            est.quality
        } else {
            0.7 * self.quality + 0.3 * est.quality
        };
        Some(ScanResult {
            pose: self.pose_at_scan,
            quality: est.quality,
            smoothed_quality: self.quality,
            matched,
        })
    }

    /// The map built so far.
    pub fn map(&self) -> Option<crate::planning::OccupancyGrid> {
        self.slam.as_ref().and_then(|f| f.map().to_occupancy_grid())
    }

    /// Scans processed.
    pub fn scans(&self) -> u64 {
        self.scans
    }

    /// Loop closures accepted so far.
    pub fn loop_closures(&self) -> usize {
        self.slam.as_ref().map_or(0, |s| s.stats().closures)
    }
}

/// Configuration of `hng module slam`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct SlamModuleConfig {
    /// Lidar input until a "LIDAR data" provider is known (default `laser/scan`).
    #[default("laser/scan".into())]
    pub scan: String,
    /// Odometry input until an "Odometry" provider is known (default `robot/odom`).
    #[default("robot/odom".into())]
    pub odom: String,
    /// Position out (default `slam/pose`).
    #[default("slam/pose".into())]
    pub pose_out: String,
    /// Map out (default `slam/map`; empty: not published).
    #[default("slam/map".into())]
    pub map_out: String,
    /// Map publication period, s (default 2).
    #[default(2.0)]
    pub map_period_s: f64,
    /// The robot's pose in the map frame at start (default the origin).
    #[default(Pose2D::default())]
    pub initial_pose: Pose2D,
    /// The operator's pose estimates: a new map starts at each (default
    /// `operator/initial_pose`; empty: none taken). See [`crate::initial_pose`].
    #[default(INITIAL_POSE_CHANNEL.into())]
    pub initial_pose_in: String,
    /// Input silence that makes the module inapt, s (default 0.5).
    #[default(0.5)]
    pub input_timeout_s: f64,
    /// Map cell size, m (default 0.05).
    #[default(0.05)]
    pub resolution: f64,
    /// While no client is contracted: match one scan in this many (default 5; 1: every
    /// scan). See [`IdleRate`].
    #[default(5)]
    pub idle_scan_every: u32,
}

/// Which scans SLAM matches: every one while a client is contracted to its offers, one in
/// `every` while none is (the first scan after a contract is always matched).
#[derive(Debug, Clone, Copy)]
pub struct IdleRate {
    every: u32,
    /// Scans left out since the last one matched.
    skipped: u32,
}

impl IdleRate {
    /// One scan in `every` while idle (0 counts as 1); the first scan is matched.
    pub fn new(every: u32) -> IdleRate {
        let every = every.max(1);
        IdleRate {
            every,
            skipped: every - 1,
        }
    }

    /// A scan arrived, `active`: a client is contracted now. True: match it.
    pub fn take(&mut self, active: bool) -> bool {
        if active || self.skipped + 1 >= self.every {
            self.skipped = 0;
            true
        } else {
            self.skipped += 1;
            false
        }
    }

    /// Scans left out since the last one matched.
    pub fn skipped(&self) -> u32 {
        self.skipped
    }
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct SlamState {
    pose: Pose2D,
    /// The odometry reading at `pose` (`None` before any odometry).
    odom: Option<Pose2D>,
    scans: u64,
    /// The operator's estimate applied last (not applied again after a restart).
    estimate: Option<EstimateId>,
}

/// Rank of SLAM's "Odometry" need.
pub const ODOMETRY_NEED: u16 = 1;
/// Rank of SLAM's "LIDAR data" need.
pub const LIDAR_NEED: u16 = 2;

/// The SLAM module.
#[derive(Debug)]
pub struct SlamModule {
    tracker: SlamTracker,
    scan: ProviderInput<LaserScan>,
    odom: ProviderInput<Odometry>,
    pose_out: Publisher<PoseWithCovariance>,
    map_out: Option<SlicePublisher<GridInfo>>,
    initial_pose: Option<InitialPoseInput>,
    restored_scans: u64,
    idle: IdleRate,
}

impl SlamModule {
    fn publish_pose(&mut self) -> ModuleResult {
        self.pose_out.publish(PoseWithCovariance {
            header: Header {
                frame_id: FrameId::MAP,
                ..Header::default()
            },
            pose: self.tracker.pose(),
            covariance: self.tracker.covariance(),
        })?;
        Ok(())
    }
}

impl Module for SlamModule {
    type Config = SlamModuleConfig;
    /// 2: the checkpoint carries the odometry reading of its pose; 3: and the operator's
    /// estimate applied last.
    const STATE_VERSION: u32 = 3;

    fn configure(ctx: &mut Context, cfg: SlamModuleConfig) -> ModuleResult<Self> {
        let timeout = seconds("input_timeout_s", cfg.input_timeout_s)?;
        crate::common::positive("resolution", cfg.resolution)?;
        if cfg.idle_scan_every == 0 {
            return Err(crate::common::field_error("idle_scan_every", "must be at least 1").into());
        }
        let mut scfg = SlamConfig::default();
        scfg.mapper.resolution = cfg.resolution;
        let map_out = if cfg.map_out.is_empty() {
            None
        } else {
            ctx.add_timer(
                seconds("map_period_s", cfg.map_period_s)?.max(Duration::from_millis(100)),
            );
            Some(ctx.slice_publisher::<GridInfo>(&cfg.map_out, 1 << 16)?)
        };
        // Provides "Localization" on `pose_out`, with Q scaled by `SLAM_Q_SCALE` so that a
        // good GPS fix is preferred and SLAM takes over where the GPS degrades, and "Mapping"
        // on `map_out` (below a surveyed map's Q = 1, so Maps is preferred where it runs).
        // SLAM keeps tracking and publishing whether selected or not; its inputs follow its
        // "Odometry" and "LIDAR data" providers, the configured channels until they are known.
        let mut offer = ServiceOffer::new("Localization", "hng/PoseWithCovariance/v1");
        offer.channel = cfg.pose_out.clone();
        ctx.provide(offer);
        if !cfg.map_out.is_empty() {
            let mut mapping = ServiceOffer::new("Mapping", "hng/GridInfo/v1");
            mapping.channel = cfg.map_out.clone();
            ctx.provide(mapping);
        }
        ctx.need(NeedSpec::required("Odometry", ODOMETRY_NEED))
            .need(NeedSpec::required("LIDAR data", LIDAR_NEED));
        ctx.set_quality(false, 0.0);
        Ok(SlamModule {
            tracker: SlamTracker::new(scfg, cfg.initial_pose),
            scan: ProviderInput::new()
                .with_deadline(Some(timeout))
                .with_fallback(ctx, &cfg.scan)?,
            odom: ProviderInput::new()
                .with_deadline(Some(timeout))
                .with_fallback(ctx, &cfg.odom)?,
            pose_out: ctx.publisher(&cfg.pose_out)?,
            map_out,
            initial_pose: InitialPoseInput::new(ctx, &cfg.initial_pose_in)?,
            restored_scans: 0,
            idle: IdleRate::new(cfg.idle_scan_every),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if self.odom.is(input) {
            let mut got = false;
            while let Some(o) = self.odom.receive()? {
                self.tracker.on_odometry(o.pose);
                got = true;
            }
            if got {
                self.publish_pose()?;
            }
        } else if self.scan.is(input) {
            let mut latest = None;
            while let Some(s) = self.scan.receive()? {
                latest = Some(*s);
            }
            // Uncontracted: one scan in `idle_scan_every` (the odometry carries the pose).
            if let Some(s) = latest
                && self.idle.take(ctx.is_active())
                && let Some(r) = self.tracker.on_scan(&s)
            {
                if !r.matched {
                    tracing::debug!(module = ctx.name(), q = r.quality, "scan not matched");
                }
                ctx.set_quality(true, (SLAM_Q_SCALE * r.smoothed_quality) as f32);
                self.publish_pose()?;
            }
        } else if let Some(ip) = &mut self.initial_pose
            && ip.is(input)
            && let Some(p) = ip.take(ctx.name(), "new map from the operator's pose estimate")?
        {
            // A new map starts at the operator's estimate, from the odometry reading of now
            // (as after a restart from a checkpoint: the local map is rebuilt from the next
            // scans).
            let (_, odom) = self.tracker.anchor();
            self.restored_scans += self.tracker.scans();
            self.tracker = SlamTracker::resume(self.tracker.cfg, p.pose, odom);
            self.publish_pose()?;
        }
        Ok(())
    }

    fn on_tick(&mut self, _ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        if let (Some(out), Some(grid)) = (&self.map_out, self.tracker.map()) {
            out.publish_copy(grid.info(), grid.data())?;
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        let what = if self.scan.is(input) {
            "lidar"
        } else {
            "odometry"
        };
        tracing::warn!(module = ctx.name(), "no {what}: cannot localize");
        ctx.set_quality(false, -1.0);
        Ok(())
    }

    hng_runtime::follow_needs!(ODOMETRY_NEED => odom, LIDAR_NEED => scan);

    hng_runtime::checkpoint_with!(Self::save_state, Self::load_state);
}

impl SlamModule {
    fn save_state(&self) -> SlamState {
        let (pose, odom) = self.tracker.anchor();
        SlamState {
            pose,
            odom,
            scans: self.restored_scans + self.tracker.scans(),
            estimate: self
                .initial_pose
                .as_ref()
                .and_then(InitialPoseInput::applied),
        }
    }

    fn load_state(&mut self, s: SlamState) -> ModuleResult {
        self.tracker = SlamTracker::resume(self.tracker.cfg, s.pose, s.odom);
        self.restored_scans = s.scans;
        if let Some(ip) = &mut self.initial_pose {
            ip.restore(s.estimate);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A 360° scan from `p` inside the axis-aligned box [0, 8] x [0, 5].
    fn box_scan(p: &Pose2D) -> LaserScan {
        box_scan_with(p, -PI, PI / 180.0, 360)
    }

    /// A scan of `n` beams from `angle_min` in steps of `inc` inside the box.
    fn box_scan_with(p: &Pose2D, angle_min: f64, inc: f64, n: usize) -> LaserScan {
        let mut s = LaserScan {
            angle_min: angle_min as f32,
            angle_increment: inc as f32,
            range_min: 0.05,
            range_max: 10.0,
            count: n as u32,
            ..Default::default()
        };
        for i in 0..n {
            let a = p.theta + angle_min + i as f64 * inc;
            let (c, sn) = (a.cos(), a.sin());
            let mut r = f64::INFINITY;
            for (d, wall) in [(c, 8.0 - p.x), (-c, p.x), (sn, 5.0 - p.y), (-sn, p.y)] {
                if d > 1e-9 {
                    r = r.min(wall / d);
                }
            }
            s.ranges[i] = if r < 10.0 { r as f32 } else { f32::INFINITY };
        }
        s
    }

    #[test]
    fn tracker_follows_a_robot_with_biased_odometry() {
        let start = Pose2D::new(2.0, 2.0, 0.0);
        let mut t = SlamTracker::new(SlamConfig::default(), start);
        let mut truth = start;
        let mut odom = Pose2D::default();
        t.on_odometry(odom);
        for k in 0..40 {
            // Truth: 5 cm forward and a slow turn per scan; odometry says 10 % more.
            let step = Pose2D::new(0.05, 0.0, 0.01);
            truth = compose(&truth, &step);
            odom = compose(&odom, &Pose2D { x: 0.055, ..step });
            t.on_odometry(odom);
            let r = t.on_scan(&box_scan(&truth)).expect("odometry is known");
            if k > 2 {
                assert!(r.matched, "scan {k}");
            }
        }
        let p = t.pose();
        let err = (p.x - truth.x).hypot(p.y - truth.y);
        assert!(
            err < 0.05,
            "SLAM {p:?} vs truth {truth:?}: {err} m (odometry drift 0.1 m)"
        );
        assert!(t.quality() > 0.5, "Q {}", t.quality());
        assert!(t.map().is_some());
    }

    /// Each scan is read with its own geometry: a 360-beam full circle, then a 361-beam
    /// half circle at 0.5 degrees, alternating. Read with the first scan's geometry, the half
    /// circles would be mirrored and rotated and fail to match.
    #[test]
    fn tracker_reads_each_scan_with_its_own_geometry() {
        let start = Pose2D::new(3.0, 2.0, 0.3);
        let mut t = SlamTracker::new(SlamConfig::default(), start);
        let mut truth = start;
        let mut odom = Pose2D::default();
        t.on_odometry(odom);
        for k in 0..20 {
            let step = Pose2D::new(0.05, 0.0, 0.02);
            truth = compose(&truth, &step);
            odom = compose(&odom, &step);
            t.on_odometry(odom);
            let scan = if k % 2 == 0 {
                box_scan(&truth)
            } else {
                box_scan_with(&truth, -PI / 2.0, PI / 360.0, 361)
            };
            let r = t.on_scan(&scan).expect("odometry is known");
            if k > 1 {
                assert!(r.matched && r.quality > 0.5, "scan {k}: {r:?}");
            }
        }
        let p = t.pose();
        assert!(
            (p.x - truth.x).hypot(p.y - truth.y) < 0.03,
            "{p:?} vs {truth:?}"
        );
    }

    #[test]
    fn idle_slam_matches_one_scan_in_n_and_every_scan_from_the_first_after_a_contract() {
        let mut r = IdleRate::new(5);
        // Uncontracted: one scan in five, the first one included.
        let idle: Vec<bool> = (0..11).map(|_| r.take(false)).collect();
        assert_eq!(
            idle,
            [
                true, false, false, false, false, true, false, false, false, false, true
            ]
        );
        // Mid-way through an idle gap a contract comes: its very first scan is matched,
        // and every one after it.
        assert!(!r.take(false));
        assert_eq!(r.skipped(), 1);
        assert!((0..6).all(|_| r.take(true)));
        // The contract ends: idle again, counting from the last scan matched.
        let after: Vec<bool> = (0..5).map(|_| r.take(false)).collect();
        assert_eq!(after, [false, false, false, false, true]);
        // 1 (or 0): every scan.
        let mut every = IdleRate::new(0);
        assert!((0..5).all(|_| every.take(false)));
    }

    #[test]
    fn a_resumed_tracker_sees_the_motion_since_its_checkpoint() {
        let start = Pose2D::new(2.0, 2.0, 0.0);
        // Odometry has its own frame: it reads (10, -3, 1) when the robot is at the start.
        let odom0 = Pose2D::new(10.0, -3.0, 1.0);
        let mut t = SlamTracker::new(SlamConfig::default(), start);
        t.on_odometry(odom0);
        t.on_scan(&box_scan(&start)).expect("odometry is known");
        let (pose, odom) = t.anchor();
        assert_eq!(odom, Some(odom0));
        // The process dies; the robot drives 1 m forward and turns a little meanwhile.
        let moved = Pose2D::new(1.0, 0.0, 0.3);
        let truth = compose(&start, &moved);
        let mut r = SlamTracker::resume(SlamConfig::default(), pose, odom);
        r.on_odometry(compose(&odom0, &moved));
        let p = r.pose();
        assert!(
            (p.x - truth.x).hypot(p.y - truth.y) < 1e-9 && (p.theta - truth.theta).abs() < 1e-9,
            "resumed at {p:?}, robot at {truth:?}"
        );
        // The first scan after the restart starts the local map there.
        let s = r.on_scan(&box_scan(&truth)).expect("odometry is known");
        assert!(
            (s.pose.x - truth.x).hypot(s.pose.y - truth.y) < 0.05,
            "{s:?}"
        );
    }

    /// The module's own loop (in-process harness): an operator's estimate moves the pose
    /// there at once (a new map from it), and an estimate with a NaN is refused.
    #[test]
    fn the_module_starts_a_new_map_at_the_operators_estimate() {
        use hng_runtime::harness::Harness;
        let mut h = Harness::new("slam").unwrap();
        let odom = h.input::<Odometry>("robot/odom").unwrap();
        let initial = h.input::<PoseWithCovariance>(INITIAL_POSE_CHANNEL).unwrap();
        let mut pose = h.output::<PoseWithCovariance>("slam/pose").unwrap();
        h.start::<SlamModule>("map_out = \"\"").unwrap();
        let estimate = |x: f64| PoseWithCovariance {
            header: Header {
                frame_id: FrameId::MAP,
                ..Header::default()
            },
            pose: Pose2D::new(x, 4.0, -1.0),
            covariance: [0.0; 9],
        };
        let at = |p: &PoseWithCovariance, x: f64| (p.pose.x - x).hypot(p.pose.y - 4.0) < 1e-6;
        let mut got = None;
        for i in 0..100 {
            odom.publish(Odometry {
                header: Header {
                    stamp_ns: i * 20_000_000,
                    frame_id: FrameId::ODOM,
                    ..Header::default()
                },
                pose: Pose2D::new(2.0, 0.0, 0.5),
                ..Odometry::default()
            })
            .unwrap();
            if i == 1 {
                initial.publish(estimate(f64::NAN)).unwrap();
                initial.publish(estimate(7.0)).unwrap();
            }
            if let Ok(p) = h.wait_for(&mut pose, Duration::from_millis(50), |p| at(p, 7.0)) {
                got = Some(p);
                break;
            }
        }
        let p = got.expect("a pose at the estimate");
        assert!((p.pose.theta + 1.0).abs() < 1e-6, "{p:?}");
        h.finish().unwrap();
    }
}
