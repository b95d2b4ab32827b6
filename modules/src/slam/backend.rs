//! The SLAM back end: a pose graph over the front end's scans, submaps of
//! consecutive scans, loop closures against old submaps, and Gauss-Newton
//! optimisation ([`super::posegraph`]) on a background thread or inline.
//!
//! - **Nodes**: a scan becomes a node when the robot moved at least
//!   [`BackendConfig::node_min_translation`] or turned
//!   [`BackendConfig::node_min_rotation`] since the last node; other scans
//!   are kept as an offset from the last node. Each node keeps its scan's
//!   end points (sensor frame, 16 bytes a point) for submaps and the map; the
//!   matching subset and normals are derived when a loop closure needs them.
//! - **Sequential edges**: the front end's motion between consecutive nodes,
//!   information from its match covariance with a floor
//!   ([`BackendConfig::sequential_sigma`]): ICP covariances are optimistic.
//! - **Submaps**: runs of [`BackendConfig::submap_scans`] consecutive nodes,
//!   rendered (at the nodes' current poses) into a likelihood field when a
//!   loop closure is tried against them.
//! - **Loop closures**: every [`BackendConfig::loop_every`] nodes, the finished
//!   submaps whose centre lies within [`BackendConfig::loop_search_radius`]
//!   of the current pose and whose last node is at least
//!   [`BackendConfig::loop_min_separation`] nodes old are candidates, nearest
//!   first; the current scan is matched against a candidate with the wide
//!   search (coarse branch-and-bound over ±[`BackendConfig::loop_linear_window`]
//!   and ±[`BackendConfig::loop_angular_window`], then the fine matcher), and
//!   the match is accepted if its score reaches
//!   [`BackendConfig::loop_min_score`]. An accepted match adds an edge from
//!   the submap's middle node with a Huber kernel.
//! - **Optimisation**: after a new closure, the whole graph is optimised. With
//!   [`BackendConfig::background`] a worker thread does it (and re-renders the
//!   map), so the scan loop never waits; the result is applied when it
//!   arrives: the optimised nodes take their new poses, and the nodes added
//!   meanwhile, the front end's pose and its local map move by the correction
//!   of the last optimised node. Inline (evaluation), it runs at once, so
//!   results are reproducible.

use smart_default::SmartDefault;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::thread::JoinHandle;

use nalgebra::{Isometry2, Matrix3, Point2, Vector2};

use super::carmen::LaserConfig;
use super::frontend::{EstimateSource, PoseEstimate, SlamConfig, SlamFrontEnd, match_robust};
use super::mapping::LogOddsMap;
use super::matcher::scan_normals;
use super::posegraph::{Edge, optimise};

/// Back-end parameters.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct BackendConfig {
    /// Loop closure on (false: the front end alone, the graph is not built).
    #[default(true)]
    pub loop_closure: bool,
    /// Optimise on a worker thread (the module) rather than inline (evaluation).
    pub background: bool,
    /// A scan becomes a node after this much translation (m). Default 0.1.
    #[default(0.1)]
    pub node_min_translation: f64,
    /// ... or this much rotation (rad). Default 5°.
    #[default(5f64.to_radians())]
    pub node_min_rotation: f64,
    /// Floor of the sequential edges' standard deviations (m, rad). Default 2 cm, 0.5°.
    #[default((0.02, 0.5f64.to_radians()))]
    pub sequential_sigma: (f64, f64),
    /// Nodes per submap. Default 10.
    #[default(10)]
    pub submap_scans: usize,
    /// Try a loop closure every this many nodes. Default 3.
    #[default(3)]
    pub loop_every: usize,
    /// A candidate submap's last node is at least this many nodes old. Default 40.
    #[default(40)]
    pub loop_min_separation: usize,
    /// Candidate submaps' centres lie within this distance (m). Default 5.
    #[default(5.0)]
    pub loop_search_radius: f64,
    /// Candidates tried per attempt, nearest first. Default 2.
    #[default(2)]
    pub loop_candidates: usize,
    /// Half-width of the loop-closure translational search (m). Default 1.5.
    #[default(1.5)]
    pub loop_linear_window: f64,
    /// Half-width of the loop-closure rotational search (rad). Default 20°.
    #[default(20f64.to_radians())]
    pub loop_angular_window: f64,
    /// Minimum fine match score to accept a closure. Default 0.6.
    #[default(0.6)]
    pub loop_min_score: f64,
    /// Standard deviations of a closure edge (m, rad). Default 5 cm, 1°.
    #[default((0.05, 1f64.to_radians()))]
    pub loop_sigma: (f64, f64),
    /// Huber threshold of closure edges (Mahalanobis). Default 3.
    #[default(3.0)]
    pub loop_huber: f64,
    /// Gauss-Newton iterations per optimisation. Default 10.
    #[default(10)]
    pub iterations: usize,
    /// Inline optimisation (no worker) re-renders the map from the optimised
    /// nodes once the map's content may have moved this far (m) since it was
    /// rendered: the sum over optimisations of the largest node displacement
    /// (translation plus rotation times 5 m). The front end ranks matches by
    /// what the map has observed ([`SlamConfig::unknown_score`]), so a map
    /// left in the frame before a large correction misjudges new structure
    /// (Örebro with [`super::WideSearch::unknown_floor`]: 90° errors after
    /// its first closures). The worker re-renders after every optimisation.
    /// Default 0.1.
    #[default(0.1)]
    pub rerender_after: f64,
}

/// A node's scan: its valid end points (sensor frame), for the map. The
/// points within the matching range and their normals are derived when a
/// loop closure needs them, not stored: a node costs 16 bytes per point.
#[derive(Debug)]
struct NodeScan {
    all: Vec<Vector2<f64>>,
}

impl NodeScan {
    /// The points within `max_range` and their normals.
    fn matchable(&self, max_range: f64) -> (Vec<Vector2<f64>>, Vec<Option<Vector2<f64>>>) {
        let points: Vec<Vector2<f64>> = self
            .all
            .iter()
            .filter(|p| p.norm() <= max_range)
            .copied()
            .collect();
        let normals = scan_normals(&points);
        (points, normals)
    }
}

/// A loop closure that was accepted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopClosure {
    /// Node of the submap's middle.
    pub from: usize,
    /// Current node.
    pub to: usize,
    /// Fine match score.
    pub score: f64,
    /// The matched pose of `to` in the frame of `from` (the closure edge's measurement).
    pub measurement: Isometry2<f64>,
}

/// Counters of the back end.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BackendStats {
    /// Nodes in the graph.
    pub nodes: usize,
    /// Loop-closure matches tried.
    pub closures_tried: usize,
    /// Loop closures accepted.
    pub closures: usize,
    /// Optimisations applied.
    pub optimisations: usize,
    /// Optimisations that failed (the graph is kept as it was).
    pub failed_optimisations: usize,
    /// Inline re-renderings of the map ([`BackendConfig::rerender_after`]).
    pub map_renders: usize,
}

struct Job {
    poses: Vec<Isometry2<f64>>,
    edges: Vec<Edge>,
    scans: Vec<Arc<NodeScan>>,
    mapper: super::mapping::MapperConfig,
    iterations: usize,
}

struct JobResult {
    /// Nodes in the job.
    nodes: usize,
    /// Pose of the last node when the job was sent.
    sent_last: Isometry2<f64>,
    poses: Option<Vec<Isometry2<f64>>>,
    map: Option<LogOddsMap>,
}

fn run_job(job: &Job, render: bool) -> JobResult {
    let nodes = job.poses.len();
    let sent_last = job
        .poses
        .last()
        .copied()
        .unwrap_or_else(Isometry2::identity);
    let poses = optimise(&job.poses, &job.edges, job.iterations)
        .ok()
        .map(|o| o.poses);
    let map = match (&poses, render) {
        (Some(p), true) => Some(render_map(job.mapper, p, &job.scans)),
        _ => None,
    };
    JobResult {
        nodes,
        sent_last,
        poses,
        map,
    }
}

fn render_map(
    cfg: super::mapping::MapperConfig,
    poses: &[Isometry2<f64>],
    scans: &[Arc<NodeScan>],
) -> LogOddsMap {
    let mut map = LogOddsMap::new(cfg);
    for (p, s) in poses.iter().zip(scans) {
        map.integrate(p, &s.all);
    }
    map
}

struct Worker {
    jobs: Sender<Job>,
    results: Receiver<JobResult>,
    handle: Option<JoinHandle<()>>,
    busy: bool,
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Closing the job channel ends the worker's loop.
        let (tx, _) = channel();
        drop(std::mem::replace(&mut self.jobs, tx));
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Front end plus pose-graph back end.
pub struct Slam {
    cfg: SlamConfig,
    be: BackendConfig,
    fe: SlamFrontEnd,
    poses: Vec<Isometry2<f64>>,
    scans: Vec<Arc<NodeScan>>,
    edges: Vec<Edge>,
    /// Per scan: (node, offset of the scan from the node).
    scan_nodes: Vec<(usize, Isometry2<f64>)>,
    closures: Vec<LoopClosure>,
    dirty: bool,
    /// How far the map's content may have moved since it was rendered (m).
    map_stale: f64,
    worker: Option<Worker>,
    stats: BackendStats,
}

impl std::fmt::Debug for Slam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Slam")
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

fn information(cov: &Matrix3<f64>, floor: (f64, f64)) -> Matrix3<f64> {
    let mut c = *cov;
    let (t2, r2) = (floor.0 * floor.0, floor.1 * floor.1);
    for (i, f) in [t2, t2, r2].into_iter().enumerate() {
        if !c[(i, i)].is_finite() || c[(i, i)] < f {
            c[(i, i)] = f;
        }
    }
    if !c.iter().all(|v| v.is_finite()) {
        c = Matrix3::from_diagonal(&nalgebra::Vector3::new(t2, t2, r2));
    }
    c.try_inverse().unwrap_or_else(|| {
        Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0 / t2, 1.0 / t2, 1.0 / r2))
    })
}

impl Slam {
    /// A SLAM pipeline starting at `initial_pose`.
    pub fn new(cfg: SlamConfig, be: BackendConfig, initial_pose: Isometry2<f64>) -> Self {
        let worker = (be.background && be.loop_closure).then(|| {
            let (jobs, job_rx) = channel::<Job>();
            let (res_tx, results) = channel();
            let handle = std::thread::Builder::new()
                .name("slam-backend".into())
                .spawn(move || {
                    while let Ok(job) = job_rx.recv() {
                        if res_tx.send(run_job(&job, true)).is_err() {
                            break;
                        }
                    }
                })
                .ok();
            Worker {
                jobs,
                results,
                handle,
                busy: false,
            }
        });
        Self {
            cfg,
            be,
            fe: SlamFrontEnd::new(cfg, initial_pose),
            poses: Vec::new(),
            scans: Vec::new(),
            edges: Vec::new(),
            scan_nodes: Vec::new(),
            closures: Vec::new(),
            dirty: false,
            map_stale: 0.0,
            worker,
            stats: BackendStats::default(),
        }
    }

    /// The front end.
    pub fn front_end(&self) -> &SlamFrontEnd {
        &self.fe
    }

    /// Back-end counters.
    pub fn stats(&self) -> BackendStats {
        BackendStats {
            nodes: self.poses.len(),
            ..self.stats
        }
    }

    /// Accepted loop closures.
    pub fn closures(&self) -> &[LoopClosure] {
        &self.closures
    }

    /// The scan (0-based, in processing order) that made node `node`, if it exists.
    pub fn node_scan(&self, node: usize) -> Option<usize> {
        self.scan_nodes
            .iter()
            .position(|(n, off)| *n == node && *off == Isometry2::identity())
    }

    /// Current pose (the front end's, corrected by the back end).
    pub fn pose(&self) -> &Isometry2<f64> {
        self.fe.pose()
    }

    /// The pose of every scan so far, as currently corrected.
    pub fn trajectory(&self) -> Vec<Isometry2<f64>> {
        self.scan_nodes
            .iter()
            .map(|(n, off)| self.poses[*n] * off)
            .collect()
    }

    /// The map: the front end's incremental map, replaced by a re-rendered
    /// one after each background optimisation (see [`Slam::finish`]).
    pub fn map(&self) -> &LogOddsMap {
        self.fe.map()
    }

    /// Processes one scan with its beam geometry: the front end, then the
    /// back end's bookkeeping, loop-closure search and optimisation.
    pub fn process(
        &mut self,
        odom_delta: &Isometry2<f64>,
        laser: &LaserConfig,
        ranges: &[f32],
    ) -> PoseEstimate {
        self.poll();
        let all = laser.points(ranges);
        let est = self.fe.process_points(odom_delta, &all);
        if !self.be.loop_closure {
            // Front end alone: no graph, the scan's pose is kept as is.
            self.poses.push(est.pose);
            self.scan_nodes
                .push((self.poses.len() - 1, Isometry2::identity()));
            return est;
        }
        let last = self.poses.len().checked_sub(1);
        let new_node = match last {
            None => true,
            Some(l) => {
                let d = self.poses[l].inverse() * est.pose;
                d.translation.vector.norm() >= self.be.node_min_translation
                    || d.rotation.angle().abs() >= self.be.node_min_rotation
            }
        };
        if !new_node {
            if let Some(l) = last {
                self.scan_nodes
                    .push((l, self.poses[l].inverse() * est.pose));
            }
            return est;
        }
        let k = self.poses.len();
        if let Some(l) = last {
            let cov = match est.source {
                EstimateSource::Matched => est.covariance,
                _ => Matrix3::from_diagonal_element(f64::INFINITY),
            };
            let floor = if est.source == EstimateSource::Matched {
                self.be.sequential_sigma
            } else {
                // Odometry only: 10 % of the step, at least 5 cm and 2 degrees.
                let d = self.poses[l].inverse() * est.pose;
                (
                    (0.1 * d.translation.vector.norm()).max(0.05),
                    (0.1 * d.rotation.angle().abs()).max(2f64.to_radians()),
                )
            };
            self.edges.push(Edge {
                from: l,
                to: k,
                measurement: self.poses[l].inverse() * est.pose,
                information: information(&cov, floor),
                huber: None,
            });
        }
        self.poses.push(est.pose);
        self.scans.push(Arc::new(NodeScan { all }));
        self.scan_nodes.push((k, Isometry2::identity()));
        if self.be.loop_closure && k > 0 && k.is_multiple_of(self.be.loop_every.max(1)) {
            self.try_close(k);
        }
        if self.dirty {
            self.optimise_now_or_later();
        }
        est
    }

    fn submap_range(&self, s: usize) -> std::ops::Range<usize> {
        let n = self.be.submap_scans.max(1);
        s * n..((s + 1) * n).min(self.poses.len())
    }

    fn try_close(&mut self, k: usize) {
        let n = self.be.submap_scans.max(1);
        let here = self.poses[k].translation.vector;
        let r2 = self.be.loop_search_radius.powi(2);
        let mut cands: Vec<(f64, usize)> = (0..self.poses.len() / n)
            .filter_map(|s| {
                let range = self.submap_range(s);
                if range.len() < n || range.end + self.be.loop_min_separation > k {
                    return None;
                }
                let c = range
                    .clone()
                    .map(|i| self.poses[i].translation.vector)
                    .sum::<Vector2<f64>>()
                    / range.len() as f64;
                let d2 = (c - here).norm_squared();
                (d2 <= r2).then_some((d2, s))
            })
            .collect();
        cands.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (current, _) = self.scans[k].matchable(self.cfg.match_max_range);
        for &(_, s) in cands.iter().take(self.be.loop_candidates) {
            self.stats.closures_tried += 1;
            let range = self.submap_range(s);
            let (mut pts, mut nrm) = (Vec::new(), Vec::new());
            for i in range.clone() {
                let p = self.poses[i];
                let (points, normals) = self.scans[i].matchable(self.cfg.match_max_range);
                for (q, nq) in points.iter().zip(&normals) {
                    pts.push((p * Point2::from(*q)).coords);
                    nrm.push(nq.map(|v| p.rotation * v));
                }
            }
            let wide = super::frontend::WideSearch {
                linear_window: self.be.loop_linear_window,
                angular_window: self.be.loop_angular_window,
                ..self.cfg.wide
            };
            let Some(m) = match_robust(
                pts,
                nrm,
                &current,
                &self.poses[k],
                &self.cfg.matcher,
                &wide,
                f64::INFINITY,
            ) else {
                continue;
            };
            if m.score < self.be.loop_min_score {
                continue;
            }
            let mid = range.start + range.len() / 2;
            let (st, sr) = self.be.loop_sigma;
            self.edges.push(Edge {
                from: mid,
                to: k,
                measurement: self.poses[mid].inverse() * m.pose,
                information: Matrix3::from_diagonal(&nalgebra::Vector3::new(
                    1.0 / (st * st),
                    1.0 / (st * st),
                    1.0 / (sr * sr),
                )),
                huber: Some(self.be.loop_huber),
            });
            self.closures.push(LoopClosure {
                from: mid,
                to: k,
                score: m.score,
                measurement: self.poses[mid].inverse() * m.pose,
            });
            self.stats.closures += 1;
            self.dirty = true;
        }
    }

    fn job(&self) -> Job {
        Job {
            poses: self.poses.clone(),
            edges: self.edges.clone(),
            scans: self.scans.clone(),
            mapper: self.cfg.mapper,
            iterations: self.be.iterations,
        }
    }

    fn optimise_now_or_later(&mut self) {
        match &mut self.worker {
            Some(w) if w.busy => {}
            Some(w) => {
                let job = Job {
                    poses: self.poses.clone(),
                    edges: self.edges.clone(),
                    scans: self.scans.clone(),
                    mapper: self.cfg.mapper,
                    iterations: self.be.iterations,
                };
                if w.jobs.send(job).is_ok() {
                    w.busy = true;
                    self.dirty = false;
                }
            }
            None => {
                let r = run_job(&self.job(), false);
                self.dirty = false;
                self.apply(r);
            }
        }
    }

    /// Applies a finished background optimisation, if any.
    fn poll(&mut self) {
        let Some(w) = &mut self.worker else {
            return;
        };
        match w.results.try_recv() {
            Ok(r) => {
                w.busy = false;
                self.apply(r);
                if self.dirty {
                    self.optimise_now_or_later();
                }
            }
            Err(TryRecvError::Empty) => {}
            Err(TryRecvError::Disconnected) => {
                // The worker is gone: optimise inline from now on.
                self.worker = None;
            }
        }
    }

    fn apply(&mut self, r: JobResult) {
        let Some(opt) = r.poses else {
            self.stats.failed_optimisations += 1;
            return;
        };
        let m = r.nodes;
        let Some(last_opt) = opt.last() else {
            return;
        };
        let correction = last_opt * r.sent_last.inverse();
        let moved = self.poses[..m]
            .iter()
            .zip(&opt)
            .map(|(a, b)| {
                let d = a.inverse() * b;
                d.translation.vector.norm() + 5.0 * d.rotation.angle().abs()
            })
            .fold(0.0, f64::max);
        self.poses[..m].copy_from_slice(&opt);
        for p in &mut self.poses[m..] {
            *p = correction * *p;
        }
        self.fe.apply_correction(&correction);
        if let Some(mut map) = r.map {
            for (p, s) in self.poses[m..].iter().zip(&self.scans[m..]) {
                map.integrate(p, &s.all);
            }
            self.fe.set_map(map);
            self.map_stale = 0.0;
        } else {
            self.map_stale += moved;
            if self.map_stale > self.be.rerender_after {
                let map = render_map(self.cfg.mapper, &self.poses, &self.scans);
                self.fe.set_map(map);
                self.map_stale = 0.0;
                self.stats.map_renders += 1;
            }
        }
        self.stats.optimisations += 1;
    }

    /// Waits for a running background optimisation, runs a last one inline
    /// if closures were added since, and re-renders the map from the final
    /// poses. For the end of a log.
    pub fn finish(&mut self) {
        if let Some(w) = &mut self.worker
            && w.busy
            && let Ok(r) = w.results.recv()
        {
            w.busy = false;
            self.apply(r);
        }
        if self.dirty {
            let r = run_job(&self.job(), false);
            self.dirty = false;
            self.apply(r);
        }
        if self.be.loop_closure && !self.poses.is_empty() {
            let map = render_map(self.cfg.mapper, &self.poses, &self.scans);
            self.fe.set_map(map);
        }
    }
}
