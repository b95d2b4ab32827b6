//! The SLAM front end: odometry prior + scan-to-local-map matching, with a
//! global log-odds map on the side.

use smart_default::SmartDefault;
use std::collections::VecDeque;

use nalgebra::{Isometry2, Matrix3, Point2, Vector2};

use super::carmen::LaserConfig;
use super::mapping::{LogOddsMap, MapperConfig};
use super::matcher::{
    FieldFloor, LikelihoodField, MatchResult, MatcherConfig, ReferenceMap, match_scan,
    scan_normals, search_candidates,
};

/// A local-map point in the map frame with its normal, if any.
type MapPoint = (Vector2<f64>, Option<Vector2<f64>>);

/// Front-end parameters.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct SlamConfig {
    /// Beam geometry.
    #[default(LaserConfig::default())]
    pub laser: LaserConfig,
    /// Scan matcher.
    #[default(MatcherConfig::default())]
    pub matcher: MatcherConfig,
    /// Global log-odds map.
    #[default(MapperConfig::default())]
    pub mapper: MapperConfig,
    /// Scans kept in the local map matched against. Default 15.
    #[default(15)]
    pub local_map_scans: usize,
    /// Local-map points farther than this from the prior are not used (m). Default 20.
    #[default(20.0)]
    pub local_map_radius: f64,
    /// Beams longer than this are not matched (m). Default 25.
    #[default(25.0)]
    pub match_max_range: f64,
    /// Below this match score the odometry prior is kept instead. Default 0.15.
    #[default(0.15)]
    pub min_score: f64,
    /// Odometry noise: translational std per metre travelled. Default 0.1.
    #[default(0.1)]
    pub odom_trans_noise: f64,
    /// Odometry noise: rotational std per radian turned. Default 0.1.
    #[default(0.1)]
    pub odom_rot_noise: f64,
    /// Below this match score the wide search ([`SlamConfig::wide`]) is run
    /// as well and the better of the two matches kept. Default 0.5.
    #[default(0.5)]
    pub wide_below_score: f64,
    /// The wide search for large steps or a useless odometry prior.
    #[default(WideSearch::default())]
    pub wide: WideSearch,
    /// Fuse the match with the odometry prior by their information, so that
    /// directions the scan does not constrain (a corridor's axis) follow the
    /// odometry. Default false: on the five shipped logs it made the per-scan
    /// error worse at every scale tried (the odometry is the weaker of the two
    /// even along corridors).
    pub fuse_odometry: bool,
    /// The scan's information is multiplied by this before fusing: the ICP
    /// Hessian counts every point as independent, which neighbouring beams on
    /// one wall are not. Default 0.01.
    #[default(0.01)]
    pub match_information_scale: f64,
    /// When the odometry reports no motion, also match from the last step
    /// repeated (a constant-velocity hypothesis) and keep the better score.
    /// Default true.
    #[default(true)]
    pub constant_velocity_hypothesis: bool,
    /// Matches are ranked by score minus this times the fraction of the
    /// scan's points that land in space the map has seen free (log-odds at
    /// most [`FREE_LOG_ODDS`] in a 3×3 cell neighbourhood): a pose that puts
    /// end points where earlier beams passed is contradicted by the data.
    /// Ranks the prior's match, the wide search's candidates and the
    /// constant-velocity match; 0 disables. Default 0.
    #[default(0.0)]
    pub free_space_penalty: f64,
    /// When set, matches are ranked by a score in which a scan point landing
    /// where the map has never observed anything counts this value instead of
    /// its (zero) field value: new structure coming into view is no evidence
    /// against a pose, so the ranking no longer prefers poses that pull the
    /// scan back over known ground (a step too short along a corridor).
    /// `None` ranks by the plain score. Default 0.5: in the ranking alone,
    /// Örebro (no odometry, long corridors) 12.21 → 10.33 cm per scan, ACES
    /// 4.16 → 4.12 cm, the other logs unchanged (front end alone; 0.3: 13.40,
    /// 0.4: 10.63, 0.7: 10.87 cm on Örebro); with
    /// [`WideSearch::unknown_floor`] as well, Örebro 7.22 cm (0.3: 10.81,
    /// 0.6: 8.82, 0.7: 9.48 cm).
    #[default(Some(0.5))]
    pub unknown_score: Option<f64>,
}

/// Log-odds at or below which a cell counts as seen free (about four misses
/// more than hits with the default mapper).
pub const FREE_LOG_ODDS: f32 = -1.5;

/// The information-weighted mean of a match (information `h`, from the scan
/// alone) and the odometry prior (covariance `prior_cov`), linearised at the
/// match: `x = x_m + (H + Ω)⁻¹·Ω·(x_p − x_m)`.
pub fn fuse(
    matched: &Isometry2<f64>,
    h: &Matrix3<f64>,
    prior: &Isometry2<f64>,
    prior_cov: &Matrix3<f64>,
) -> Isometry2<f64> {
    let Some(omega) = prior_cov.try_inverse() else {
        return *matched;
    };
    let d = nalgebra::Vector3::new(
        prior.translation.x - matched.translation.x,
        prior.translation.y - matched.translation.y,
        (prior.rotation * matched.rotation.inverse()).angle(),
    );
    let Some(inv) = (h + omega).try_inverse() else {
        return *matched;
    };
    let step = inv * (omega * d);
    if !step.iter().all(|v| v.is_finite()) {
        return *matched;
    }
    Isometry2::new(
        matched.translation.vector + step.xy(),
        matched.rotation.angle() + step.z,
    )
}

/// A wide correlative search for steps the odometry does not explain: a
/// branch-and-bound search on a coarse likelihood field over a large window
/// around the prior, then the normal (fine) matcher from its optimum.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct WideSearch {
    /// Half-width of the translational window (m). Default 3.5.
    #[default(3.5)]
    pub linear_window: f64,
    /// Half-width of the rotational window (rad). Default 90°.
    #[default(90f64.to_radians())]
    pub angular_window: f64,
    /// Coarse field cell size and Gaussian width (m). Default 0.1.
    #[default(0.1)]
    pub resolution: f64,
    /// Branch-and-bound levels on the coarse field. Default 5.
    #[default(5)]
    pub depth: usize,
    /// Penalty weights on the distance from the prior (1/m², 1/rad²). Default 0.02.
    #[default(0.02)]
    pub weight: f64,
    /// Distinct coarse optima refined by the fine matcher; the best fine
    /// score wins. Default 1.
    #[default(1)]
    pub candidates: usize,
    /// Coarse optima closer than this (m) and [`WideSearch::candidate_angle`]
    /// count as one. Default 0.5.
    #[default(0.5)]
    pub candidate_separation: f64,
    /// See [`WideSearch::candidate_separation`] (rad). Default 10°.
    #[default(10f64.to_radians())]
    pub candidate_angle: f64,
    /// Give never-observed cells of the coarse field the value
    /// [`SlamConfig::unknown_score`], so the coarse search does not prefer
    /// poses that keep the scan over known ground either. Default true: on
    /// Örebro (no odometry) it takes the front end from 10.33 to 7.22 cm and
    /// 0.73 to 0.34° per scan (ATE 6.07 → 1.94 m), and the whole pipeline
    /// to 7.88 cm and 0.71° (its 4 closures are right, within 6 cm and
    /// 1.3°); the other logs are unchanged. It was off while inline
    /// optimisation left the map unrendered after a correction
    /// ([`super::BackendConfig::rerender_after`]): the observed-space mask
    /// then lay metres from the corrected poses and Örebro fell to 9.38 cm,
    /// 1.09°.
    #[default(true)]
    pub unknown_floor: bool,
}

impl WideSearch {
    /// The coarse matcher's parameters.
    pub fn matcher(&self) -> MatcherConfig {
        MatcherConfig {
            resolution: self.resolution,
            sigma: self.resolution,
            linear_window: self.linear_window,
            angular_window: self.angular_window,
            depth: self.depth,
            translation_weight: self.weight,
            rotation_weight: self.weight,
            refine_iterations: 0,
            ..MatcherConfig::default()
        }
    }
}

/// Matches `pts` against `(points, normals)` around `prior`: the fine search
/// first; if its score is below `wide_below`, also the wide search (coarse
/// field over a large window, then the fine search from its optimum), keeping
/// the match with the higher fine score. `None` if there is nothing to match.
pub fn match_robust(
    points: Vec<Vector2<f64>>,
    normals: Vec<Option<Vector2<f64>>>,
    pts: &[Vector2<f64>],
    prior: &Isometry2<f64>,
    fine: &MatcherConfig,
    wide: &WideSearch,
    wide_below: f64,
) -> Option<MatchResult> {
    match_robust_ranked(
        points,
        normals,
        pts,
        prior,
        fine,
        wide,
        wide_below,
        &|m: &MatchResult, _: &LikelihoodField| m.score,
        None,
    )
    .map(|(m, _)| m)
}

/// [`match_robust`], choosing between matches by `rank` (higher is better;
/// given the match and the fine likelihood field of the reference) rather
/// than by their fine score. Returns the match with its rank.
#[allow(clippy::too_many_arguments)]
pub fn match_robust_ranked(
    points: Vec<Vector2<f64>>,
    normals: Vec<Option<Vector2<f64>>>,
    pts: &[Vector2<f64>],
    prior: &Isometry2<f64>,
    fine: &MatcherConfig,
    wide: &WideSearch,
    wide_below: f64,
    rank: &dyn Fn(&MatchResult, &LikelihoodField) -> f64,
    coarse_floor: Option<FieldFloor<'_>>,
) -> Option<(MatchResult, f64)> {
    let coarse_pts = (wide_below > 0.0).then(|| points.clone());
    let reference = ReferenceMap::build(points, normals, fine)?;
    let first = match_scan(&reference, pts, prior, fine)?;
    let first_rank = rank(&first, &reference.field);
    if first.score >= wide_below {
        return Some((first, first_rank));
    }
    let Some(coarse_pts) = coarse_pts else {
        return Some((first, first_rank));
    };
    let wcfg = wide.matcher();
    let coarse_normals = vec![None; coarse_pts.len()];
    let coarse = ReferenceMap::build_with_floor(coarse_pts, coarse_normals, &wcfg, coarse_floor)
        .map(|c| {
            search_candidates(
                &c,
                pts,
                prior,
                &wcfg,
                wide.candidates,
                wide.candidate_separation,
                wide.candidate_angle,
            )
            .0
        })
        .unwrap_or_default();
    let local = MatcherConfig {
        linear_window: 2.0 * wide.resolution,
        angular_window: 2f64.to_radians().max(fine.angular_window / 4.0),
        ..*fine
    };
    let second = coarse
        .iter()
        .filter_map(|(p, _)| match_scan(&reference, pts, p, &local))
        .map(|m| (rank(&m, &reference.field), m))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    match second {
        Some((r, s)) if r > first_rank => Some((s, r)),
        _ => Some((first, first_rank)),
    }
}

/// How a pose estimate was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EstimateSource {
    /// First scan, or no usable points: the prior is returned.
    Prior,
    /// Scan matched against the local map.
    Matched,
    /// Match too weak: the odometry prior is kept.
    OdometryFallback,
}

/// One pose estimate of the front end.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEstimate {
    /// Sensor pose in the map frame.
    pub pose: Isometry2<f64>,
    /// Covariance of (x, y, θ).
    pub covariance: Matrix3<f64>,
    /// Self-evaluated quality in [−1, 1] (the HNG module working quality):
    /// `2·score − 1` when matched, where `score` is the mean likelihood of the
    /// scan points on the local map (1 = every point on mapped structure,
    /// 0.5 = half of them); 0 when it cannot be evaluated (first scan), and
    /// `min(2·score − 1, −0.5)` when the match was rejected.
    pub quality: f64,
    /// Match score in [0, 1] (0 if not matched).
    pub score: f64,
    /// Where the pose came from.
    pub source: EstimateSource,
}

/// Odometry-prior plus scan-to-map SLAM front end.
#[derive(Debug, Clone)]
pub struct SlamFrontEnd {
    cfg: SlamConfig,
    pose: Isometry2<f64>,
    /// Recent scans: map-frame points and normals.
    local: VecDeque<Vec<MapPoint>>,
    map: LogOddsMap,
    scans: usize,
    /// Motion between the last two estimates (sensor frame), the
    /// constant-velocity hypothesis when the odometry reports no motion.
    last_step: Isometry2<f64>,
}

impl SlamFrontEnd {
    /// A front end starting at `initial_pose` with an empty map.
    pub fn new(cfg: SlamConfig, initial_pose: Isometry2<f64>) -> Self {
        Self {
            cfg,
            pose: initial_pose,
            local: VecDeque::new(),
            map: LogOddsMap::new(cfg.mapper),
            scans: 0,
            last_step: Isometry2::identity(),
        }
    }

    /// Current pose estimate.
    pub fn pose(&self) -> &Isometry2<f64> {
        &self.pose
    }

    /// The global log-odds map built so far.
    pub fn map(&self) -> &LogOddsMap {
        &self.map
    }

    /// Scans processed.
    pub fn scans(&self) -> usize {
        self.scans
    }

    fn odom_covariance(&self, delta: &Isometry2<f64>) -> Matrix3<f64> {
        let t = delta.translation.vector.norm();
        let r = delta.rotation.angle().abs();
        let st = (self.cfg.odom_trans_noise * t).max(0.01);
        let sr = (self.cfg.odom_rot_noise * r).max(0.2f64.to_radians());
        Matrix3::from_diagonal(&nalgebra::Vector3::new(st * st, st * st, sr * sr))
    }

    /// Processes one scan with the configured beam geometry: `odom_delta` is
    /// the odometry motion since the previous scan (sensor frame), `ranges`
    /// the readings.
    pub fn process(&mut self, odom_delta: &Isometry2<f64>, ranges: &[f32]) -> PoseEstimate {
        let all = self.cfg.laser.points(ranges);
        self.process_points(odom_delta, &all)
    }

    /// Processes one scan with its own beam geometry.
    pub fn process_scan(
        &mut self,
        odom_delta: &Isometry2<f64>,
        laser: &LaserConfig,
        ranges: &[f32],
    ) -> PoseEstimate {
        let all = laser.points(ranges);
        self.process_points(odom_delta, &all)
    }

    /// Moves the pose and the local map by `correction` (map frame), after
    /// the back end has corrected the trajectory.
    pub fn apply_correction(&mut self, correction: &Isometry2<f64>) {
        self.pose = correction * self.pose;
        let rot = correction.rotation;
        for scan in &mut self.local {
            for (p, n) in scan.iter_mut() {
                *p = (correction * Point2::from(*p)).coords;
                *n = n.map(|n| rot * n);
            }
        }
    }

    /// Replaces the global map (after the back end re-rendered it).
    pub fn set_map(&mut self, map: LogOddsMap) {
        self.map = map;
    }

    /// Processes one scan given as end points in the sensor frame.
    pub fn process_points(
        &mut self,
        odom_delta: &Isometry2<f64>,
        all: &[Vector2<f64>],
    ) -> PoseEstimate {
        let prior = self.pose * odom_delta;
        let pts: Vec<Vector2<f64>> = all
            .iter()
            .filter(|p| p.norm() <= self.cfg.match_max_range)
            .copied()
            .collect();
        let center = prior.translation.vector;
        let r2 = self.cfg.local_map_radius * self.cfg.local_map_radius;
        let (local_pts, local_normals): (Vec<_>, Vec<_>) = self
            .local
            .iter()
            .flatten()
            .filter(|(p, _)| (p - center).norm_squared() <= r2)
            .copied()
            .unzip();
        // Odometry reporting no motion at all is no evidence that the robot stood
        // still (a log without odometry, a stalled encoder): verify with the wide search.
        let still = *odom_delta == Isometry2::identity();
        let wide_below = if still && self.scans > 0 {
            f64::INFINITY
        } else {
            self.cfg.wide_below_score
        };
        // Without odometry, a second hypothesis: the last step repeated
        // (constant velocity), matched the same way; the higher score wins.
        let mut seeds: Vec<Isometry2<f64>> = Vec::new();
        if still && self.cfg.constant_velocity_hypothesis && self.scans > 1 {
            seeds.push(self.pose * self.last_step);
        }
        seeds.retain(|p| (p.translation.vector - prior.translation.vector).norm() > 0.5);
        let penalty = self.cfg.free_space_penalty;
        let unknown = self.cfg.unknown_score;
        let map = &self.map;
        let rank = |m: &MatchResult, field: &LikelihoodField| -> f64 {
            if pts.is_empty() || (penalty <= 0.0 && unknown.is_none()) {
                return m.score;
            }
            let (mut sum, mut free) = (0.0, 0usize);
            for p in &pts {
                let q = (m.pose * Point2::from(*p)).coords;
                sum += match unknown {
                    Some(c) if !map.is_observed(&q) => c,
                    _ => field.interpolate(&q).0,
                };
                if penalty > 0.0 && map.is_free(&q, FREE_LOG_ODDS) {
                    free += 1;
                }
            }
            let n = pts.len() as f64;
            sum / n - penalty * free as f64 / n
        };
        let unknown_floor = |q: &Vector2<f64>| -> f32 {
            match unknown {
                Some(c) if !map.is_observed(q) => c as f32,
                _ => 0.0,
            }
        };
        let floor: Option<FieldFloor<'_>> =
            (self.cfg.wide.unknown_floor && unknown.is_some()).then_some(&unknown_floor);
        let second = seeds
            .iter()
            .filter_map(|p| {
                match_robust_ranked(
                    local_pts.clone(),
                    local_normals.clone(),
                    &pts,
                    p,
                    &self.cfg.matcher,
                    &self.cfg.wide,
                    wide_below,
                    &rank,
                    floor,
                )
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let matched = match_robust_ranked(
            local_pts,
            local_normals,
            &pts,
            &prior,
            &self.cfg.matcher,
            &self.cfg.wide,
            wide_below,
            &rank,
            floor,
        );
        let matched = match (matched, second) {
            (Some(a), Some(b)) if b.1 > a.1 => Some(b.0),
            (a, None) => a.map(|a| a.0),
            (a, b) => a.or(b).map(|m| m.0),
        };
        let est = match matched {
            None => PoseEstimate {
                pose: prior,
                covariance: self.odom_covariance(odom_delta),
                quality: 0.0,
                score: 0.0,
                source: EstimateSource::Prior,
            },
            Some(r) if r.score >= self.cfg.min_score => PoseEstimate {
                pose: if still || !self.cfg.fuse_odometry {
                    r.pose
                } else {
                    fuse(
                        &r.pose,
                        &(r.information * self.cfg.match_information_scale),
                        &prior,
                        &self.odom_covariance(odom_delta),
                    )
                },
                covariance: r.covariance,
                quality: (2.0 * r.score - 1.0).clamp(-1.0, 1.0),
                score: r.score,
                source: EstimateSource::Matched,
            },
            Some(r) => PoseEstimate {
                pose: prior,
                covariance: self.odom_covariance(odom_delta),
                quality: (2.0 * r.score - 1.0).clamp(-1.0, -0.5),
                score: r.score,
                source: EstimateSource::OdometryFallback,
            },
        };
        self.last_step = self.pose.inverse() * est.pose;
        self.pose = est.pose;
        let rot = est.pose.rotation;
        self.local.push_back(
            pts.iter()
                .zip(scan_normals(&pts))
                .map(|(p, n)| ((est.pose * Point2::from(*p)).coords, n.map(|n| rot * n)))
                .collect(),
        );
        while self.local.len() > self.cfg.local_map_scans.max(1) {
            self.local.pop_front();
        }
        self.map.integrate(&est.pose, all);
        self.scans += 1;
        est
    }
}
