//! The mission monitor of `hng run` (built-in mission): a thread of the `hng run` process that
//! follows the mission through the system's channels, prints progress, decides success and
//! asks the supervisor to stop everything when the mission ends.
//!
//! It reads `manager/status` (goals reached or refused), `sim/status` (simulated time,
//! collisions, minimum clearance), `sim/ground_truth` (path length; evaluation only),
//! [`SUPERVISOR_EVENTS`] (restarts) and [`CONTRACTS`] (which provider serves which need: a
//! change of provider is a contract switch).

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result};
use hng_modules::msgs::MissionStatus;
use hng_runtime::msg::PoseWithCovariance;
use hng_runtime::system::{
    CONTRACTS, CommandOp, ContractRole, ContractTable, EventKind, ModuleEvent, SUPERVISOR_COMMAND,
    SUPERVISOR_EVENTS, SupervisorCommand,
};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};
use hng_simulator::module::SimStatus;
use serde::Serialize;

/// The summary of a mission (`--summary FILE` writes it as JSON, with exactly these fields).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Summary {
    /// Every goal reached, no collision, within the duration.
    pub success: bool,
    /// Goals reached.
    pub goals_reached: u32,
    /// Goals in the mission.
    pub goals_total: u32,
    /// Simulated time at the end, s.
    pub sim_time_s: f64,
    /// Wall time from start to the end of the mission, s.
    pub wall_time_s: f64,
    /// Length of the true path, m.
    pub path_length_m: f64,
    /// Smallest gap between the robot and an obstacle, m (`null` if never measured).
    pub min_obstacle_distance_m: Option<f64>,
    /// Contacts begun with obstacles.
    pub collisions: u64,
    /// Times a need changed from one provider to another.
    pub contract_switches: u64,
    /// Module processes that died and were restarted.
    pub restarts: u64,
}

/// How the mission ended, with the summary.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The figures.
    pub summary: Summary,
    /// Why it failed (empty on success).
    pub failure: Option<String>,
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
                st.run(&opts, &stop2)
            })
            .context("starting the mission monitor")?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Monitor { stop, thread }),
            Ok(Err(e)) => anyhow::bail!("mission monitor: {e}"),
            Err(_) => anyhow::bail!("the mission monitor ended before it was ready"),
        }
    }

    /// Stops the monitor (if the mission did not end by itself) and returns the outcome.
    pub fn finish(self) -> Result<Outcome> {
        self.stop.store(true, Ordering::Release);
        match self.thread.join() {
            Ok(r) => r,
            Err(_) => anyhow::bail!("the mission monitor panicked"),
        }
    }
}

struct State {
    // Ports before the node.
    mission: hng_runtime::Subscriber<MissionStatus>,
    sim: hng_runtime::Subscriber<SimStatus>,
    truth: hng_runtime::Subscriber<PoseWithCovariance>,
    events: hng_runtime::Subscriber<ModuleEvent>,
    tables: hng_runtime::Subscriber<ContractTable>,
    command: hng_runtime::Publisher<SupervisorCommand>,
    waiter: Waiter,
    _node: Node,
    started: Instant,
    last_sim: Instant,
    sim_time_s: f64,
    last_pos: Option<(f64, f64)>,
    path_length_m: f64,
    min_clearance: f64,
    collisions: u64,
    reached: u32,
    refused: u32,
    done: bool,
    restarts: u64,
    switches: u64,
    names: HashMap<u32, String>,
    /// (client, service) → provider module id.
    providers: BTreeMap<(String, String), u32>,
    /// Modules that died and were not yet started again.
    dead: HashMap<String, u32>,
}

impl State {
    fn new(opts: &MonitorOptions) -> Result<State> {
        let node = Node::new(
            NodeOptions::new(&format!("hng-mission-{}", std::process::id())).prefix(&opts.prefix),
        )
        .context("creating the mission monitor's node")?;
        let mission = node.subscriber::<MissionStatus>("manager/status")?;
        let sim = node.subscriber::<SimStatus>("sim/status")?;
        let truth = node.subscriber::<PoseWithCovariance>("sim/ground_truth")?;
        let events = node.subscriber::<ModuleEvent>(SUPERVISOR_EVENTS)?;
        let tables = node.subscriber::<ContractTable>(CONTRACTS)?;
        let command = node.publisher::<SupervisorCommand>(SUPERVISOR_COMMAND)?;
        let mut waiter = Waiter::new(WaitMode::Blocking {
            max_spin: Duration::ZERO,
        })?;
        waiter.attach(&mission)?;
        waiter.attach(&sim)?;
        waiter.attach(&events)?;
        waiter.attach(&tables)?;
        let now = Instant::now();
        Ok(State {
            mission,
            sim,
            truth,
            events,
            tables,
            command,
            waiter,
            _node: node,
            started: now,
            last_sim: now,
            sim_time_s: 0.0,
            last_pos: None,
            path_length_m: 0.0,
            min_clearance: f64::INFINITY,
            collisions: 0,
            reached: 0,
            refused: 0,
            done: false,
            restarts: 0,
            switches: 0,
            names: HashMap::new(),
            providers: BTreeMap::new(),
            dead: HashMap::new(),
        })
    }

    fn say(&self, what: &str) {
        println!("[{:7.1} s] {what}", self.sim_time_s);
    }

    fn run(&mut self, opts: &MonitorOptions, stop: &AtomicBool) -> Result<Outcome> {
        let total = u32::try_from(opts.goals.len()).unwrap_or(u32::MAX);
        let mut failure: Option<String> = None;
        while !stop.load(Ordering::Acquire) {
            // The ground truth comes at 100 Hz simulated: read it on the other wake-ups
            // rather than waking for every sample.
            self.waiter.wait(Some(Duration::from_millis(100)))?;
            self.read(opts)?;
            if let Some(f) = self.verdict(opts, total) {
                failure = f;
                break;
            }
        }
        let ended = !stop.load(Ordering::Acquire);
        let summary = Summary {
            success: ended && failure.is_none(),
            goals_reached: self.reached,
            goals_total: total,
            sim_time_s: self.sim_time_s,
            wall_time_s: self.started.elapsed().as_secs_f64(),
            path_length_m: self.path_length_m,
            min_obstacle_distance_m: self.min_clearance.is_finite().then_some(self.min_clearance),
            collisions: self.collisions,
            contract_switches: self.switches,
            restarts: self.restarts,
        };
        if ended {
            // Stop the system: the supervisor stops every module in order.
            let _ = self
                .command
                .publish(SupervisorCommand::new(CommandOp::Shutdown, ""));
        } else if failure.is_none() {
            failure = Some("the system was stopped before the mission ended".to_owned());
        }
        Ok(Outcome { summary, failure })
    }

    /// `Some(None)`: success; `Some(Some(why))`: failure; `None`: going on.
    fn verdict(&self, opts: &MonitorOptions, total: u32) -> Option<Option<String>> {
        if self.collisions > 0 {
            return Some(Some(format!(
                "the robot collided with an obstacle ({} contacts)",
                self.collisions
            )));
        }
        if self.done {
            if self.reached >= total {
                return Some(None);
            }
            return Some(Some(format!(
                "{} of {total} goals refused (unreachable or outside the map; see planning's log)",
                self.refused
            )));
        }
        if self.sim_time_s > opts.duration_s {
            return Some(Some(format!(
                "the mission took longer than its duration ({} s simulated): {} of {total} goals reached",
                opts.duration_s, self.reached
            )));
        }
        if self.last_sim.elapsed() > opts.stall_timeout {
            return Some(Some(format!(
                "the simulator has been silent for {:?}",
                opts.stall_timeout
            )));
        }
        None
    }

    fn read(&mut self, opts: &MonitorOptions) -> Result<()> {
        while let Some(s) = self.sim.receive()? {
            self.last_sim = Instant::now();
            self.sim_time_s = s.sim_time_ns as f64 * 1e-9;
            if s.min_clearance.is_finite() {
                self.min_clearance = self.min_clearance.min(s.min_clearance);
            }
            if s.collisions > self.collisions {
                self.collisions = s.collisions;
                self.say(&format!("COLLISION ({} so far)", s.collisions));
            }
        }
        while let Some(p) = self.truth.receive()? {
            let (x, y) = (p.pose.x, p.pose.y);
            if let Some((px, py)) = self.last_pos {
                self.path_length_m += (x - px).hypot(y - py);
            }
            self.last_pos = Some((x, y));
        }
        while let Some(m) = self.mission.receive()? {
            let m = *m;
            for i in self.reached..m.goals_reached {
                let at = opts
                    .goals
                    .get(i as usize)
                    .map(|(x, y)| format!(" ({x:.2}, {y:.2})"))
                    .unwrap_or_default();
                self.say(&format!(
                    "goal reached{at}: {} of {} goals done",
                    i + 1 + m.goals_refused,
                    m.goals_total
                ));
            }
            for _ in self.refused..m.goals_refused {
                self.say(
                    "goal REFUSED by Planning (unreachable or outside the map); the robot holds",
                );
            }
            self.reached = self.reached.max(m.goals_reached);
            self.refused = self.refused.max(m.goals_refused);
            self.done = m.done != 0 && m.goals_total > 0;
        }
        while let Some(e) = self.events.receive()? {
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
        while let Some(t) = self.tables.receive()? {
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
        Ok(())
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "mission {}: {} of {} goals reached",
            if self.success { "SUCCEEDED" } else { "FAILED" },
            self.goals_reached,
            self.goals_total
        )?;
        writeln!(
            f,
            "  time              {:.1} s simulated, {:.1} s wall",
            self.sim_time_s, self.wall_time_s
        )?;
        writeln!(f, "  path length       {:.2} m", self.path_length_m)?;
        match self.min_obstacle_distance_m {
            Some(d) => writeln!(f, "  min obstacle dist {d:.3} m")?,
            None => writeln!(f, "  min obstacle dist -")?,
        }
        writeln!(f, "  collisions        {}", self.collisions)?;
        writeln!(f, "  contract switches {}", self.contract_switches)?;
        write!(f, "  restarts          {}", self.restarts)
    }
}
