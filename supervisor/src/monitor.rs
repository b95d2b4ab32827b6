//! The mission monitor of `hng run` (built-in mission): a thread of the `hng run` process that
//! follows the mission through the system's channels, prints progress, decides success and
//! asks the supervisor to stop everything when the mission ends.
//!
//! It reads the Manager's mission document `manager/mission` (every goal the mission ever
//! held, added ones included, with its state and the reason of a refusal), `sim/status`
//! (simulated time, collisions, minimum clearance), `sim/ground_truth` (the true pose: path
//! length and the true error at each goal; evaluation only), [`SUPERVISOR_EVENTS`] (restarts)
//! and [`CONTRACTS`] (which provider serves which need: a change of provider is a contract
//! switch).
//!
//! The true pose (100 Hz of simulated time) and the contract tables (each module's every
//! 200 ms, and on changes) do not wake the monitor one by one: it reads them in batches from
//! recorder-sized buffers ([`Node::tap_subscriber`], 64 samples), waking on its other inputs
//! or after [`BATCH_WAIT_MAX`] at most, sooner when their recent rate would fill a quarter of
//! the buffers first (at 1x real time: about 10 wake-ups a second instead of 170).
//!
//! A goal counts as reached only when the simulator's true pose is within the goal's
//! tolerance at the moment the robot reports it reached (the robot's own estimate can be off
//! by its localization error); otherwise it is `missed`, and the mission fails.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::error::{Context as _, Result};
use hng_modules::manager::{MISSION_PLAN_CHANNEL, MissionPlan};
use hng_modules::planning::progress::{NavProgress, PROGRESS_CHANNEL};

use super::nav_watch::NavWatch;

mod episodes;
mod summary;
mod truth;
pub use episodes::{Episode, EpisodeLine, EpisodeOptions, read_episodes};
use hng_runtime::msg::PoseWithCovariance;
use hng_runtime::system::{
    CONTRACTS, CommandOp, ContractRole, ContractTable, EventKind, JsonInfo, ModuleEvent,
    SUPERVISOR_COMMAND, SUPERVISOR_EVENTS, SupervisorCommand,
};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};
use hng_simulator::module::SimStatus;
pub use summary::{GoalSummary, Outcome, Summary, write_summary};
use truth::TruthLog;

/// Longest wait between two reads of the batched inputs (true pose, contract tables).
pub const BATCH_WAIT_MAX: Duration = Duration::from_millis(100);
/// Shortest such wait (at very high simulation speeds).
const BATCH_WAIT_MIN: Duration = Duration::from_millis(2);
/// Samples of a batched input's buffer (the recorder's buffer of the `State` and `Report`
/// kinds) that may arrive between two reads: a quarter of it, for scheduling slack.
const BATCH_SAMPLES: f64 = 16.0;

/// How long the monitor may sleep before its batched inputs need reading: `BATCH_SAMPLES`
/// at `rate` samples per wall second, within [`BATCH_WAIT_MIN`, `BATCH_WAIT_MAX`].
fn batch_wait(rate: f64) -> Duration {
    if rate > 0.0 && rate.is_finite() {
        Duration::from_secs_f64(BATCH_SAMPLES / rate).clamp(BATCH_WAIT_MIN, BATCH_WAIT_MAX)
    } else {
        BATCH_WAIT_MAX
    }
}

/// What the monitor needs to know.
#[derive(Debug, Clone)]
pub struct MonitorOptions {
    /// The system's prefix.
    pub prefix: String,
    /// Goals, in order (for the messages).
    pub goals: Vec<(f64, f64)>,
    /// Limit of simulated time, s.
    pub duration_s: f64,
    /// Fail when the simulator is silent this long (wall time).
    pub stall_timeout: Duration,
    /// Write the summary (JSON) to this file as soon as the mission ends, before the system
    /// is stopped (written to a temporary file and renamed: a reader sees all or nothing),
    /// so that `hng eval nav` can go on while this run stops.
    pub summary_file: Option<std::path::PathBuf>,
    /// Run these episodes (one goal each, from its own start) instead of `goals`.
    pub episodes: Option<EpisodeOptions>,
}

/// The monitor thread.
pub struct Monitor {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Result<Outcome>>,
}

impl Monitor {
    /// Starts the monitor (before the modules, so that it misses nothing).
    pub fn start(opts: MonitorOptions) -> Result<Monitor> {
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = Arc::clone(&stop);
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
        let thread = std::thread::Builder::new()
            .name("hng-mission".into())
            .spawn(move || {
                let mut st = match State::new(&opts) {
                    Ok(s) => {
                        let _ = ready_tx.send(Ok(()));
                        s
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(format!("{e:#}")));
                        return Err(e);
                    }
                };
                let r = st.run(&opts, &stop2);
                if let Err(e) = &r {
                    // Nobody would see the mission end: say why and stop the system.
                    st.say(&format!(
                        "the mission monitor failed: {e:#}; stopping the system"
                    ));
                    let _ = st
                        .command
                        .publish(SupervisorCommand::new(CommandOp::Shutdown, ""));
                }
                r
            })
            .context("starting the mission monitor")?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Monitor { stop, thread }),
            Ok(Err(e)) => crate::error::bail!("mission monitor: {e}"),
            Err(_) => crate::error::bail!("the mission monitor ended before it was ready"),
        }
    }

    /// Stops the monitor (if the mission did not end by itself) and returns the outcome.
    pub fn finish(self) -> Result<Outcome> {
        self.stop.store(true, Ordering::Release);
        match self.thread.join() {
            Ok(r) => r,
            Err(_) => crate::error::bail!("the mission monitor panicked"),
        }
    }
}

struct State {
    // Ports before the node.
    mission: hng_runtime::SliceSubscriber<JsonInfo>,
    sim: hng_runtime::Subscriber<SimStatus>,
    truth: hng_runtime::Subscriber<PoseWithCovariance>,
    events: hng_runtime::Subscriber<ModuleEvent>,
    tables: hng_runtime::Subscriber<ContractTable>,
    progress: hng_runtime::Subscriber<NavProgress>,
    nav: NavWatch,
    command: hng_runtime::Publisher<SupervisorCommand>,
    waiter: Waiter,
    _node: Node,
    started: Instant,
    /// The batched inputs' samples counted since `counted_since` (true poses, tables), and
    /// their recent rate (samples per wall second, the faster of the two).
    counted_since: Instant,
    counted: (u32, u32),
    batch_rate: f64,
    last_sim: Instant,
    sim_time_s: f64,
    last_pos: Option<(f64, f64)>,
    /// Recent true poses and path counters.
    log: TruthLog,
    /// Path length of the simulator processes before the current one, m, and the current
    /// one's.
    path_before_m: f64,
    path_length_m: f64,
    min_clearance: f64,
    collisions: u64,
    /// Teleports the simulator refused, by its latest status.
    teleports_refused: u64,
    /// Every goal seen in the Manager's documents, in mission order.
    goals: Vec<GoalSummary>,
    done: bool,
    /// The stamp of the Manager's document that said the mission done (simulated ns).
    done_at_ns: Option<u64>,
    restarts: u64,
    switches: u64,
    names: HashMap<u32, String>,
    /// (client, service) → provider module id.
    providers: BTreeMap<(String, String), u32>,
    /// Modules that died and were not yet started again.
    dead: HashMap<String, u32>,
    /// True poses lost so far had been said.
    truth_loss_said: bool,
    /// The episodes, if the run has them.
    episodes: Option<episodes::Runner>,
    /// Since when (simulated s, the stamp of its document) the Manager has held no goal.
    idle_since: Option<f64>,
    /// Least clearance since the current episode's goal was given, m.
    episode_min_clearance: f64,
    /// Simulated time (s) each goal was first seen in the Manager's documents and dealt with.
    goal_times: HashMap<u32, GoalTimes>,
}

/// When the Manager took a goal and when it dealt with it (reached or refused): the stamps
/// of its documents, simulated s, and the true path's length then, m (where known).
#[derive(Debug, Clone, Copy)]
struct GoalTimes {
    taken_s: f64,
    taken_path_m: Option<f64>,
    dealt: Option<(f64, Option<f64>)>,
}

impl State {
    fn new(opts: &MonitorOptions) -> Result<State> {
        let node = Node::new(
            NodeOptions::new(&format!("hng-mission-{}", std::process::id())).prefix(&opts.prefix),
        )
        .context("creating the mission monitor's node")?;
        let mission = node.slice_subscriber::<JsonInfo>(MISSION_PLAN_CHANNEL)?;
        let sim = node.subscriber::<SimStatus>("sim/status")?;
        // Read in batches (see the module docs): recorder-sized buffers, not waited on.
        let truth = node.tap_subscriber::<PoseWithCovariance>("sim/ground_truth")?;
        let events = node.subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)?;
        let tables = node.tap_subscriber::<ContractTable>(CONTRACTS)?;
        let command = node.publisher::<SupervisorCommand>(SUPERVISOR_COMMAND)?;
        let progress = node.subscriber::<NavProgress>(PROGRESS_CHANNEL)?;
        let episodes = match &opts.episodes {
            Some(e) => Some(episodes::Runner::new(&node, e)?),
            None => None,
        };
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&mission)?;
        waiter.attach(&sim)?;
        waiter.attach(&events)?;
        waiter.attach(&progress)?;
        let now = Instant::now();
        Ok(State {
            mission,
            sim,
            truth,
            events,
            tables,
            progress,
            nav: NavWatch::default(),
            command,
            waiter,
            _node: node,
            started: now,
            counted_since: now,
            counted: (0, 0),
            batch_rate: 0.0,
            last_sim: now,
            sim_time_s: 0.0,
            last_pos: None,
            log: TruthLog::default(),
            path_before_m: 0.0,
            path_length_m: 0.0,
            min_clearance: f64::INFINITY,
            collisions: 0,
            teleports_refused: 0,
            goals: Vec::new(),
            done: false,
            done_at_ns: None,
            truth_loss_said: false,
            restarts: 0,
            switches: 0,
            names: HashMap::new(),
            providers: BTreeMap::new(),
            dead: HashMap::new(),
            episodes,
            idle_since: None,
            episode_min_clearance: f64::INFINITY,
            goal_times: HashMap::new(),
        })
    }

    /// A progress line at the simulated time the monitor has read up to.
    fn say(&self, what: &str) {
        Self::say_at(self.sim_time_s, what);
    }

    /// A progress line about something stamped `t` (simulated s).
    fn say_at(t: f64, what: &str) {
        crate::say!("[{t:7.1} s] {what}");
    }

    fn run(&mut self, opts: &MonitorOptions, stop: &AtomicBool) -> Result<Outcome> {
        let mut failure: Option<String> = None;
        // A channel that cannot be read is read again at the next pass (what the others gave
        // is used); one that stays unreadable as long as a silent simulator fails the mission.
        let mut unreadable_since: Option<Instant> = None;
        while !stop.load(Ordering::Acquire) {
            self.waiter.wait(Some(batch_wait(self.batch_rate)))?;
            match self.read() {
                Ok(()) => unreadable_since = None,
                Err(e) => {
                    let since = *unreadable_since.get_or_insert_with(|| {
                        self.say(&format!(
                            "monitor: a channel could not be read ({e:#}); trying again"
                        ));
                        Instant::now()
                    });
                    if since.elapsed() > opts.stall_timeout {
                        failure = Some(format!(
                            "the mission monitor could not read its channels for {:?}: {e:#}",
                            opts.stall_timeout
                        ));
                        break;
                    }
                    // Back off: the failed channel's unread data would end every wait.
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
            }
            let verdict = if self.episodes.is_some() {
                match self.step_episodes()? {
                    Some(f) => Some(f),
                    None => self.silent(opts),
                }
            } else {
                self.verdict(opts)
            };
            if let Some(f) = verdict {
                failure = f;
                break;
            }
        }
        let ended = !stop.load(Ordering::Acquire);
        if self.goals.is_empty() {
            // The Manager never published its mission: the configured goals, never pursued.
            for (i, &(x, y)) in opts.goals.iter().enumerate() {
                self.goals.push(GoalSummary {
                    id: u32::try_from(i + 1).unwrap_or(u32::MAX),
                    x,
                    y,
                    tolerance_m: 0.2,
                    state: "pending".to_owned(),
                    reason: Some("the Manager never published the mission".to_owned()),
                    true_error_m: None,
                });
            }
        }
        // Goals never dealt with: their true distance at the end.
        for g in &mut self.goals {
            if g.true_error_m.is_none()
                && let Some((x, y)) = self.last_pos
            {
                g.true_error_m = Some((x - g.x).hypot(y - g.y));
            }
        }
        if !ended && failure.is_none() {
            failure = Some("the system was stopped before the mission ended".to_owned());
        }
        // A mission the Manager said done ends at the stamp of that document, not when the
        // monitor read it (the robot still rolls out its last command).
        let (mut sim_time_s, mut path_length_m) =
            (self.sim_time_s, self.path_before_m + self.path_length_m);
        if let Some(end) = self.done_at_ns.filter(|_| self.done) {
            sim_time_s = end as f64 * 1e-9;
            path_length_m = self.log.path_at(end).unwrap_or(path_length_m);
        }
        let summary = Summary {
            success: ended && failure.is_none(),
            goals_reached: self.reached(),
            goals_total: u32::try_from(self.goals.len()).unwrap_or(u32::MAX),
            goals: self.goals.clone(),
            sim_time_s,
            wall_time_s: self.started.elapsed().as_secs_f64(),
            path_length_m,
            min_obstacle_distance_m: self.min_clearance.is_finite().then_some(self.min_clearance),
            collisions: self.collisions,
            contract_switches: self.switches,
            restarts: self.restarts,
            stuck_time_s: self.nav.stuck_time_s(),
            stalls: self.nav.stalls(),
            recoveries: self.nav.recoveries(),
            true_poses_lost: self.truth.stats().dropped,
            failure: failure.clone(),
        };
        if ended {
            if let Some(f) = &opts.summary_file
                && let Err(e) = write_summary(f, &summary)
            {
                self.say(&format!("{e:#}"));
            }
            // Stop the system: the supervisor stops every module in order.
            let _ = self
                .command
                .publish(SupervisorCommand::new(CommandOp::Shutdown, ""));
        }
        Ok(Outcome { summary, failure })
    }

    fn reached(&self) -> u32 {
        let n = self.goals.iter().filter(|g| g.state == "reached").count();
        u32::try_from(n).unwrap_or(u32::MAX)
    }

    /// The goals not reached, with their state and reason.
    fn not_reached(&self) -> String {
        self.goals
            .iter()
            .filter(|g| g.state != "reached")
            .map(|g| {
                let why = g
                    .reason
                    .as_deref()
                    .map(|r| format!(": {r}"))
                    .unwrap_or_default();
                format!("goal {} ({:.2}, {:.2}) {}{why}", g.id, g.x, g.y, g.state)
            })
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// `Some(None)`: success; `Some(Some(why))`: failure; `None`: going on.
    fn verdict(&self, opts: &MonitorOptions) -> Option<Option<String>> {
        let total = self.goals.len();
        if self.collisions > 0 {
            return Some(Some(format!(
                "the robot collided with an obstacle ({} contacts)",
                self.collisions
            )));
        }
        if self.done {
            if self.reached() as usize >= total {
                return Some(None);
            }
            return Some(Some(format!(
                "{} of {total} goals not reached: {}",
                total - self.reached() as usize,
                self.not_reached()
            )));
        }
        if self.sim_time_s > opts.duration_s {
            return Some(Some(format!(
                "the mission took longer than its duration ({} s simulated): {} of {total} goals reached; {}",
                opts.duration_s,
                self.reached(),
                self.not_reached()
            )));
        }
        self.silent(opts)
    }

    /// A failure if the simulator has been silent too long.
    fn silent(&self, opts: &MonitorOptions) -> Option<Option<String>> {
        (self.last_sim.elapsed() > opts.stall_timeout).then(|| {
            Some(format!(
                "the simulator has been silent for {:?}",
                opts.stall_timeout
            ))
        })
    }

    fn on_progress(&mut self, m: &NavProgress) {
        let line = self.nav.on_progress(m);
        Self::say_at(m.header.stamp_ns as f64 * 1e-9, &line);
    }

    /// Reads every channel. A channel that fails to read ends its own pass only: the others
    /// are still read and everything taken is used; the first error is returned after.
    fn read(&mut self) -> Result<()> {
        let mut err = None;
        for s in drain(|| self.sim.receive(), |s| *s, &mut err) {
            self.last_sim = Instant::now();
            self.sim_time_s = s.sim_time_ns as f64 * 1e-9;
            if s.path_length_m + 1e-9 < self.path_length_m {
                // A restarted simulator counts from 0 again.
                self.path_before_m += self.path_length_m;
            }
            self.path_length_m = s.path_length_m;
            self.teleports_refused = s.teleports_refused;
            self.log
                .push_path(s.sim_time_ns, self.path_before_m + self.path_length_m);
            if s.min_clearance.is_finite() {
                self.min_clearance = self.min_clearance.min(s.min_clearance);
                self.episode_min_clearance = self.episode_min_clearance.min(s.min_clearance);
            }
            if s.collisions > self.collisions {
                self.collisions = s.collisions;
                self.say(&format!("COLLISION ({} so far)", s.collisions));
            }
        }
        // The Manager's documents before the true poses: a document stamped `t` is sent after
        // the true pose of `t` (in its lockstep round), so every true pose up to the
        // documents' stamps is here when they are read. Both are then taken in stamp order:
        // the mission's state at each true pose is that of its simulated time, not of when
        // the monitor read it.
        let docs = drain(
            || self.mission.receive(),
            |m| {
                let plan = serde_json::from_slice::<MissionPlan>(m.data());
                (m.header().header.stamp_ns, plan)
            },
            &mut err,
        );
        let mut plans = Vec::new();
        for (stamp, plan) in docs {
            match plan {
                Ok(p) => plans.push((stamp, p)),
                Err(e) => self.say(&format!("unreadable mission document ignored: {e}")),
            }
        }
        // Planning's progress messages after the documents for the same reason (a goal it
        // gives up is reported by Planning before the Manager refuses it), printed in stamp
        // order with them, the cause first at one stamp.
        let mut progress = drain(|| self.progress.receive(), |m| *m, &mut err)
            .into_iter()
            .peekable();
        let poses = drain(
            || self.truth.receive(),
            |p| (p.header.stamp_ns, p.pose.x, p.pose.y),
            &mut err,
        );
        let truths = u32::try_from(poses.len()).unwrap_or(u32::MAX);
        let mut poses = poses.into_iter().peekable();
        for (stamp, p) in plans {
            while let Some(pose) = poses.next_if(|(t, _, _)| *t <= stamp) {
                self.on_truth(pose);
            }
            while let Some(m) = progress.next_if(|m| m.header.stamp_ns <= stamp) {
                self.on_progress(&m);
            }
            let truth = self.truth_at(stamp);
            self.on_plan(&p, truth, stamp);
        }
        poses.for_each(|pose| self.on_truth(pose));
        progress.for_each(|m| self.on_progress(&m));
        let lost = self.truth.stats().dropped;
        if lost > 0 && !self.truth_loss_said {
            self.truth_loss_said = true;
            self.say(&format!(
                "monitor: {lost} true poses lost before it could read them (the machine is too \
                 loaded for it); goals are judged against the nearest pose it has, and the \
                 summary counts the losses (true_poses_lost)"
            ));
        }
        for e in drain(|| self.events.receive(), |e| *e, &mut err) {
            let name = e.module().to_owned();
            match e.kind() {
                Some(EventKind::Died) => {
                    self.say(&format!("module {name} died (pid {})", e.pid));
                    self.dead.insert(name, e.pid);
                }
                Some(EventKind::Started) if self.dead.remove(&name).is_some() => {
                    self.restarts += 1;
                    self.say(&format!("module {name} restarted (pid {})", e.pid));
                }
                Some(EventKind::Deactivated) => {
                    self.say(&format!("module {name} DEACTIVATED (failed too often)"));
                }
                _ => {}
            }
        }
        let mut changed = Vec::new();
        let mut tables = 0u32;
        for t in drain(|| self.tables.receive(), |t| *t, &mut err) {
            tables += 1;
            let client = t.module().to_owned();
            self.names.insert(t.module_id, client.clone());
            for e in t.entries() {
                if e.role() != Some(ContractRole::Client) {
                    continue;
                }
                let key = (client.clone(), e.service().to_owned());
                if let Some(old) = self.providers.insert(key.clone(), e.peer)
                    && old != e.peer
                {
                    changed.push((key, old, e.peer));
                }
            }
        }
        // The batched inputs' rate, over at least 20 ms: a rise counts at once, a fall slowly.
        self.counted.0 += truths;
        self.counted.1 += tables;
        let dt = self.counted_since.elapsed().as_secs_f64();
        if dt >= 0.02 {
            let rate = f64::from(self.counted.0.max(self.counted.1)) / dt;
            self.batch_rate = if rate > self.batch_rate {
                rate
            } else {
                0.8 * self.batch_rate + 0.2 * rate
            };
            self.counted = (0, 0);
            self.counted_since = Instant::now();
        }
        for ((client, service), old, new) in changed {
            self.switches += 1;
            let name = |id: u32| {
                self.names
                    .get(&id)
                    .cloned()
                    .unwrap_or_else(|| format!("m{id}"))
            };
            self.say(&format!(
                "contract switch: {client} {service}: {} -> {}",
                name(old),
                name(new)
            ));
        }
        err.map_or(Ok(()), |e| Err(e.into()))
    }
}

/// Every sample waiting on a channel (`next`: its subscriber's `receive`), each made an
/// owned value by `take` at once (a subscriber may hold only a few samples). A read error
/// ends this channel's pass and is kept in `err`, the first one only.
fn drain<S, T>(
    mut next: impl FnMut() -> std::result::Result<Option<S>, hng_runtime::Error>,
    mut take: impl FnMut(S) -> T,
    err: &mut Option<hng_runtime::Error>,
) -> Vec<T> {
    let mut out = Vec::new();
    loop {
        match next() {
            Ok(Some(s)) => out.push(take(s)),
            Ok(None) => return out,
            Err(e) => {
                err.get_or_insert(e);
                return out;
            }
        }
    }
}

impl State {
    /// The true position at simulated time `ns`: the last sample at or before it (the
    /// oldest kept if none is that old, the latest known if none is kept).
    fn truth_at(&self, ns: u64) -> Option<(f64, f64)> {
        self.log.at(ns).or(self.last_pos)
    }

    /// A true pose (simulated ns, x, y).
    fn on_truth(&mut self, (ns, x, y): (u64, f64, f64)) {
        self.last_pos = Some((x, y));
        self.log.push_pose(ns, x, y);
        let active = !self.done && !self.goals.is_empty();
        self.nav.on_truth(ns as f64 * 1e-9, x, y, active);
    }

    /// A mission document (published at simulated time when the true position was `truth`):
    /// new goals are added, goals dealt with are judged against the true pose.
    fn on_plan(&mut self, p: &MissionPlan, truth: Option<(f64, f64)>, stamp_ns: u64) {
        let stamp_s = stamp_ns as f64 * 1e-9;
        for e in &p.goals {
            let known = self.goals.iter().position(|g| g.id == e.id);
            let i = match known {
                Some(i) => i,
                None => {
                    if !self.goals.is_empty() && self.sim_time_s > 0.0 {
                        let line = format!("goal {} added ({:.2}, {:.2})", e.id, e.x, e.y);
                        Self::say_at(stamp_s, &line);
                    }
                    self.goals.push(GoalSummary {
                        id: e.id,
                        x: e.x,
                        y: e.y,
                        tolerance_m: e.tolerance_m,
                        state: e.state.clone(),
                        reason: None,
                        true_error_m: None,
                    });
                    let taken = GoalTimes {
                        taken_s: stamp_s,
                        taken_path_m: self.log.path_at(stamp_ns),
                        dealt: None,
                    };
                    self.goal_times.insert(e.id, taken);
                    self.goals.len() - 1
                }
            };
            let g = &mut self.goals[i];
            let settled = matches!(g.state.as_str(), "reached" | "missed" | "refused");
            if settled {
                continue;
            }
            g.state = e.state.clone();
            if matches!(e.state.as_str(), "reached" | "refused")
                && let Some(t) = self.goal_times.get_mut(&e.id)
            {
                t.dealt = Some((stamp_s, self.log.path_at(stamp_ns)));
            }
            let g = &mut self.goals[i];
            let error = truth.map(|(x, y)| (x - g.x).hypot(y - g.y));
            let line = match e.state.as_str() {
                "reached" => {
                    g.true_error_m = error;
                    match error {
                        Some(err) if err <= g.tolerance_m => {
                            format!(
                                "goal reached ({:.2}, {:.2}), id {}: true error {err:.3} m",
                                g.x, g.y, g.id
                            )
                        }
                        Some(err) => {
                            g.state = "missed".to_owned();
                            let why = format!(
                                "reported reached, but the true pose is {err:.3} m away (tolerance {:.2} m)",
                                g.tolerance_m
                            );
                            g.reason = Some(why.clone());
                            format!("goal MISSED ({:.2}, {:.2}), id {}: {why}", g.x, g.y, g.id)
                        }
                        None => {
                            g.state = "missed".to_owned();
                            g.reason = Some(
                                "reported reached, but no ground truth to check it".to_owned(),
                            );
                            format!(
                                "goal MISSED ({:.2}, {:.2}), id {}: reported reached, no ground truth to check it",
                                g.x, g.y, g.id
                            )
                        }
                    }
                }
                "refused" => {
                    g.true_error_m = error;
                    g.reason = e.reason.clone();
                    format!(
                        "goal REFUSED ({:.2}, {:.2}), id {}: {}",
                        g.x,
                        g.y,
                        g.id,
                        e.reason.as_deref().unwrap_or("see planning's log")
                    )
                }
                _ => continue,
            };
            let done = self
                .goals
                .iter()
                .filter(|g| matches!(g.state.as_str(), "reached" | "missed" | "refused"))
                .count();
            Self::say_at(
                stamp_s,
                &format!("{line}; {done} of {} goals done", self.goals.len()),
            );
        }
        let done = p.done && p.goals_total > 0;
        if done && !self.done {
            self.done_at_ns = Some(stamp_ns);
        }
        self.done = done;
        if p.current_goal_id != 0 {
            self.idle_since = None;
        } else if self.idle_since.is_none() {
            self.idle_since = Some(stamp_s);
        }
    }
}
