//! The operator's orders through the Interface (adjustable autonomy, docs/autonomy.md), with
//! real processes in accelerated lockstep simulation: bad orders refused with their reason and
//! nothing moving; a goal order reached within 0.3 m of true error (SLAM localization);
//! teleop with its deadman; the emergency stop stopping a moving robot; orders switched while
//! the robot moves, re-wiring the contracts without collision; `hng order` and
//! `hng behaviours` against the running system.

use std::time::{Duration, Instant};

use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{
    BEHAVIOURS_CHANNEL, Behaviours, ModuleReport, ORDER_CHANNEL, ORDER_STATUS_CHANNEL, Order,
    OrderKind, OrderStatus, Pose2D, PoseWithCovariance, Twist,
};
use hng_runtime::system::{CONTRACTS, ContractRole, ContractTable};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, Publisher, Subscriber, shm};
use hng_simulator::module::SimStatus;
use nix::sys::signal::Signal;

use crate::signals::Run;

const HNG: &str = env!("CARGO_BIN_EXE_hng");
/// Generous: a whole robot in accelerated simulation on two loaded cores.
pub(crate) const TIMEOUT: Duration = Duration::from_secs(150);

/// The launch file of a robot under orders: the Table 1 modules with SLAM as the only
/// Localization (GPS's 0.3 m noise would not reach a goal within 0.3 m) and the surveyed map,
/// the Manager with no goals (autonomy holds), in lockstep. `extra` modules (name, config
/// TOML lines) are added; `world` is a world file (default: the built-in world).
pub(crate) fn launch(
    map: &str,
    world: Option<&str>,
    start: (f64, f64, f64),
    extra: &[(&str, &str)],
) -> String {
    let mut names = vec![
        "laser",
        "robot",
        "security",
        "interface",
        "maps",
        "slam",
        "planning",
        "servo",
        "manager",
    ];
    names.extend(extra.iter().map(|e| e.0));
    let list = names
        .iter()
        .map(|n| format!("{n:?}"))
        .collect::<Vec<_>>()
        .join(", ");
    let (x, y, t) = start;
    let start = format!("{{ x = {x:?}, y = {y:?}, theta = {t:?} }}");
    let world = world.map_or(String::new(), |w| format!("world = {w:?}\n"));
    let mut s = format!(
        r#"system = "orders"
clock = "sim"

[defaults]
heartbeat_period = "200ms"
heartbeat_timeout = "5s"
start_timeout = "20s"
stop_timeout = "2s"

[[module]]
name = "simulator"
command = ["hng", "module", "simulator"]
[module.config]
{world}start = {start}
speed = 4
wait_for = [{list}]
lockstep = [{list}]

[[module]]
name = "laser"
command = ["hng", "module", "laser"]

[[module]]
name = "robot"
command = ["hng", "module", "robot"]

[[module]]
name = "security"
command = ["hng", "module", "security"]

[[module]]
name = "interface"
command = ["hng", "module", "interface"]
[module.config]
video = false

[[module]]
name = "maps"
command = ["hng", "module", "maps"]
[module.config]
map = {map:?}

[[module]]
name = "slam"
command = ["hng", "module", "slam"]
[module.config]
initial_pose = {start}

[[module]]
name = "planning"
command = ["hng", "module", "planning"]
[module.config]
goal = "interface/goal"

[[module]]
name = "servo"
command = ["hng", "module", "servo"]

[[module]]
name = "manager"
command = ["hng", "module", "manager"]
manager = true
[module.config]
goals = []
"#
    );
    for (name, config) in extra {
        s.push_str(&format!(
            "\n[[module]]\nname = {name:?}\ncommand = [\"hng\", \"module\", {name:?}]\n"
        ));
        if !config.is_empty() {
            s.push_str(&format!("[module.config]\n{config}\n"));
        }
    }
    s
}

/// The map of `world` (default: built-in) for Maps, written into `dir`.
pub(crate) fn write_map(dir: &std::path::Path, world: Option<&str>) -> String {
    let map = dir.join("map.yaml");
    let mut c = std::process::Command::new(HNG);
    c.args(["sim", "map"]).arg(&map);
    if let Some(w) = world {
        c.args(["--world", w]);
    }
    let out = c.output().expect("hng sim map");
    assert!(out.status.success(), "hng sim map: {out:?}");
    map.to_str().expect("path").to_owned()
}

/// What the test sees of the running system, and its operator's ports.
pub(crate) struct Watch {
    truth: Subscriber<PoseWithCovariance>,
    status: Subscriber<SimStatus>,
    orders_status: Subscriber<OrderStatus>,
    reports: Subscriber<ModuleReport>,
    behaviours_in: Subscriber<Behaviours>,
    tables: Subscriber<ContractTable>,
    orders: Publisher<Order>,
    teleop: Publisher<Twist>,
    waiter: Waiter,
    /// Latest true pose and its simulated time, s.
    pub pose: Option<(Pose2D, f64)>,
    /// True poses since `track` was cleared: (t, x, y).
    pub track: Vec<(f64, f64, f64)>,
    pub sim: Option<SimStatus>,
    /// Every order status seen.
    pub statuses: Vec<OrderStatus>,
    pub behaviours: Option<Behaviours>,
    /// Every distinct behaviours list seen.
    pub offers: Vec<Behaviours>,
    pub interface_dropped: u64,
    /// Latest contract table per module name.
    pub contracts: std::collections::BTreeMap<String, ContractTable>,
    /// Publish this teleop command every 50 ms of simulated time.
    pub drive: Option<Twist>,
    last_drive: f64,
    /// Teleop commands published so far.
    pub drive_sent: u64,
    seq: u32,
    _node: Node,
}

impl Watch {
    pub(crate) fn new(prefix: &str) -> Watch {
        let node = Node::new(NodeOptions::new("orders-test").prefix(prefix)).expect("node");
        let truth = node.subscriber("sim/ground_truth").expect("truth");
        let status = node.subscriber("sim/status").expect("status");
        let orders_status = node.subscriber(ORDER_STATUS_CHANNEL).expect("order status");
        let reports = node.subscriber(REPORT_CHANNEL).expect("reports");
        let behaviours_in = node.subscriber(BEHAVIOURS_CHANNEL).expect("behaviours");
        let tables = node.subscriber(CONTRACTS).expect("contracts");
        let orders = node.publisher(ORDER_CHANNEL).expect("orders");
        let teleop = node.publisher("hng/teleop").expect("teleop");
        let mut waiter = Waiter::new(WaitMode::Blocking {
            max_spin: Duration::ZERO,
        })
        .expect("waiter");
        waiter.attach(&truth).expect("attach");
        waiter.attach(&status).expect("attach");
        waiter.attach(&orders_status).expect("attach");
        waiter.attach(&reports).expect("attach");
        waiter.attach(&behaviours_in).expect("attach");
        Watch {
            truth,
            status,
            orders_status,
            reports,
            behaviours_in,
            tables,
            orders,
            teleop,
            waiter,
            pose: None,
            track: Vec::new(),
            sim: None,
            statuses: Vec::new(),
            behaviours: None,
            offers: Vec::new(),
            interface_dropped: 0,
            contracts: Default::default(),
            drive: None,
            last_drive: f64::NEG_INFINITY,
            drive_sent: 0,
            seq: 1000,
            _node: node,
        }
    }

    fn drain(&mut self) {
        while let Some(s) = self.status.receive().expect("status") {
            self.sim = Some(*s);
        }
        let now = self.sim_s();
        while let Some(p) = self.truth.receive().expect("truth") {
            let t = p.header.stamp_ns as f64 * 1e-9;
            self.pose = Some((p.pose, t));
            self.track.push((t, p.pose.x, p.pose.y));
        }
        while let Some(s) = self.orders_status.receive().expect("order status") {
            self.statuses.push(*s);
        }
        while let Some(r) = self.reports.receive().expect("reports") {
            if r.name() == "interface" {
                self.interface_dropped = self.interface_dropped.max(r.msgs_dropped);
            }
        }
        while let Some(b) = self.behaviours_in.receive().expect("behaviours") {
            self.behaviours = Some(*b);
            self.offers.push(*b);
        }
        while let Some(t) = self.tables.receive().expect("tables") {
            self.contracts.insert(t.module().to_string(), *t);
        }
        if let Some(cmd) = self.drive
            && now - self.last_drive >= 0.05
        {
            self.teleop.update_connections();
            self.teleop.publish(cmd).expect("teleop");
            self.last_drive = now;
            self.drive_sent += 1;
        }
    }

    /// Waits until `pred` holds for what was read.
    pub(crate) fn until(&mut self, what: &str, mut pred: impl FnMut(&Watch) -> bool) {
        let deadline = Instant::now() + TIMEOUT;
        loop {
            self.drain();
            if pred(self) {
                return;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "{what} within {TIMEOUT:?}: pose {:?}, sim {:.2} s, interface dropped {}, last statuses {:?}",
                self.pose,
                self.sim_s(),
                self.interface_dropped,
                self.statuses
                    .iter()
                    .rev()
                    .take(3)
                    .map(|s| (s.seq, s.accepted, s.active, s.reason().to_string()))
                    .collect::<Vec<_>>()
            );
            self.waiter
                .wait(Some(left.min(Duration::from_millis(50))))
                .expect("wait");
        }
    }

    pub(crate) fn sim_s(&self) -> f64 {
        self.sim.map_or(0.0, |s| s.sim_time_ns as f64 * 1e-9)
    }

    pub(crate) fn xy(&self) -> (f64, f64) {
        let (p, _) = self.pose.expect("pose");
        (p.x, p.y)
    }

    /// Sends `o` and waits for the Interface's answer to it.
    pub(crate) fn order(&mut self, mut o: Order) -> OrderStatus {
        self.seq += 1;
        o.seq = self.seq;
        let seq = self.seq;
        self.orders.update_connections();
        self.orders.publish(o).expect("order");
        let from = self.statuses.len();
        self.until("the Interface's answer", |w| {
            w.statuses[from..].iter().any(|s| s.seq == seq)
        });
        *self.statuses[from..]
            .iter()
            .find(|s| s.seq == seq)
            .expect("answer")
    }

    /// Waits until the robot's true pose has moved less than 2 mm for `still_s` simulated s.
    pub(crate) fn until_still(&mut self, what: &str, still_s: f64) {
        let mut last = self.xy();
        let mut since = self.sim_s();
        self.until(what, |w| {
            let p = w.xy();
            if dist(p, last) > 0.002 {
                last = p;
                since = w.sim_s();
            }
            w.sim_s() - since > still_s
        });
    }

    /// The provider module's name of `need` of module `client` in the contract tables.
    pub(crate) fn provider_of(&self, client: &str, need: u16) -> Option<String> {
        let t = self.contracts.get(client)?;
        let e = t
            .entries()
            .iter()
            .find(|e| e.role == ContractRole::Client as u8 && e.need == need)?;
        self.contracts
            .values()
            .find(|m| m.module_id == e.peer)
            .map(|m| m.module().to_string())
    }

    pub(crate) fn collisions(&self) -> u64 {
        self.sim.map_or(0, |s| s.collisions)
    }
}

pub(crate) fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()
}

pub(crate) fn goal(kind: OrderKind, pts: &[(f64, f64)]) -> Order {
    let mut o = Order::new(kind);
    for (i, (x, y)) in pts.iter().enumerate() {
        o.points[i] = Pose2D::new(*x, *y, 0.0);
    }
    o.count = pts.len() as u32;
    o
}

fn forward(v: f64) -> Twist {
    Twist {
        linear_x: v,
        ..Default::default()
    }
}

#[test]
fn orders_of_every_level_do_what_they_say_and_bad_ones_move_nothing() {
    let _heavy = crate::common::heavy();
    let prefix = shm::unique_prefix("orders");
    let dir = crate::signals::test_dir(&prefix);
    std::fs::create_dir_all(&dir).expect("dir");
    let map = write_map(&dir, None);
    let file = dir.join("orders.toml");
    std::fs::write(&file, launch(&map, None, (2.0, 2.0, 0.0), &[])).expect("launch");
    let mut watch = Watch::new(&prefix);
    let mut run = Run::start_on(&prefix, &[file.to_str().expect("path")]);
    watch.until("simulated time running and Planning contracted", |w| {
        w.sim_s() > 1.0
            && w.pose.is_some()
            && w.statuses.last().is_some_and(|s| s.active == 0)
            && w.provider_of("interface", 2).as_deref() == Some("planning")
    });
    let rest = watch.xy();

    // Bad orders: refused with their reason, counted, and nothing moves.
    let dropped = watch.interface_dropped;
    let mut nan = goal(OrderKind::Goal, &[(f64::NAN, 3.0)]);
    let bad: Vec<(Order, &str)> = vec![
        (
            Order {
                kind: 42,
                ..Default::default()
            },
            "unknown order kind 42",
        ),
        (std::mem::take(&mut nan), "point 1 x is not finite"),
        (goal(OrderKind::Goal, &[(1e7, 3.0)]), "is beyond"),
        (goal(OrderKind::Waypoints, &[]), "1 to 16 points"),
        (
            Order {
                kind: OrderKind::FollowWall as u32,
                side: 3,
                ..Default::default()
            },
            "side 3 is neither",
        ),
        (
            Order {
                kind: OrderKind::FollowWall as u32,
                side: 1,
                ..Default::default()
            },
            "no \"Follow wall\" provider",
        ),
        (
            Order {
                kind: OrderKind::ReachBeacon as u32,
                beacon_id: 77,
                ..Default::default()
            },
            "beacon 77 is not known",
        ),
    ];
    let n_bad = bad.len() as u64;
    for (o, why) in bad {
        let s = watch.order(o);
        assert_eq!(s.accepted, 0, "{o:?} accepted: {}", s.reason());
        assert!(
            s.reason().contains(why),
            "{:?} does not say {why:?}",
            s.reason()
        );
        assert_eq!(s.active, 0, "a refused order changed nothing");
    }
    // NaN teleop commands: dropped and counted too.
    watch.drive = Some(forward(f64::NAN));
    let sent = watch.drive_sent;
    watch.until("10 NaN commands sent", |w| w.drive_sent >= sent + 10);
    watch.drive = None;
    let n_nan = watch.drive_sent - sent;
    watch.until("the refusals and drops counted", |w| {
        w.interface_dropped >= dropped + n_bad + n_nan
    });
    let t0 = watch.sim_s();
    watch.until("one more simulated second", |w| w.sim_s() > t0 + 1.0);
    assert!(dist(watch.xy(), rest) < 0.01, "bad orders moved the robot");

    // A goal order: reached within 0.3 m of true error, then the order ends (autonomy).
    let target = (5.5, 3.0);
    let s = watch.order(goal(OrderKind::Goal, &[target]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    assert_eq!(s.active, 1);
    let seq = s.seq;
    watch.until("the goal order reached", |w| {
        w.statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached"))
    });
    watch.until_still("the robot at rest at the goal", 0.5);
    let err = dist(watch.xy(), target);
    eprintln!("goal order: true error {err:.3} m");
    assert!(err <= 0.3, "goal reached {err:.3} m from the truth");

    // Teleop: the commands drive it; when they stop, the deadman stops it.
    let s = watch.order(Order::new(OrderKind::Teleop));
    assert_eq!((s.accepted, s.in_force), (1, OrderKind::Teleop as u32));
    watch.until("Planning released under teleop", |w| {
        w.provider_of("interface", 2).is_none()
    });
    let start = watch.xy();
    watch.drive = Some(Twist {
        linear_x: 0.25,
        angular_z: 0.3,
        ..Default::default()
    });
    watch.until("the robot moving under teleop", |w| {
        dist(w.xy(), start) > 0.3
    });
    watch.drive = None;
    let released = watch.sim_s();
    watch.until_still("the deadman stopping the robot", 0.3);
    let stopped_after = watch.sim_s() - 0.3 - released;
    eprintln!("teleop deadman: at rest {stopped_after:.2} s after the last command");
    assert!(stopped_after < 1.2, "deadman took {stopped_after:.2} s");

    // Emergency stop while moving: the robot stops within 0.3 s (+ one scan period of
    // Security's relay) and teleop commands then move nothing.
    watch.drive = Some(forward(0.25));
    let start = watch.xy();
    watch.until("the robot moving again", |w| dist(w.xy(), start) > 0.2);
    let s = watch.order(Order::new(OrderKind::Stop));
    assert_eq!((s.accepted, s.in_force), (1, OrderKind::Stop as u32));
    let t_stop = s.header.stamp_ns as f64 * 1e-9;
    watch.track.clear();
    watch.until_still("the robot stopped", 0.5);
    let moving_until = watch
        .track
        .windows(2)
        .filter(|w| dist((w[0].1, w[0].2), (w[1].1, w[1].2)) > 1e-4)
        .map(|w| w[1].0)
        .fold(t_stop, f64::max);
    let stop_time = moving_until - t_stop;
    eprintln!("stop order: robot at rest {stop_time:.3} s (simulated) after the order");
    assert!(
        stop_time <= 0.35,
        "stopped {stop_time:.3} s after the order"
    );
    let held = watch.xy();
    let t0 = watch.sim_s();
    watch.until("1 s of teleop under stop", |w| w.sim_s() > t0 + 1.0);
    assert!(
        dist(watch.xy(), held) < 0.01,
        "teleop moved a stopped robot"
    );
    watch.drive = None;

    // Switching orders while moving: a far goal, then waypoints elsewhere, then another goal,
    // then release; no collision, and Planning is re-contracted for each.
    let collisions = watch.collisions();
    let s = watch.order(goal(OrderKind::Goal, &[(3.0, 11.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    watch.until("Planning contracted for the goal", |w| {
        w.provider_of("interface", 2).as_deref() == Some("planning")
    });
    let start = watch.xy();
    watch.until("moving to the goal", |w| dist(w.xy(), start) > 0.8);
    let s = watch.order(goal(OrderKind::Waypoints, &[(6.0, 6.5), (5.5, 3.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    let seq = s.seq;
    watch.until("the first waypoint passed", |w| {
        dist(w.xy(), (6.0, 6.5)) < 0.5
    });
    let s = watch.order(goal(OrderKind::Goal, &[(2.0, 2.0)]));
    assert_eq!(s.accepted, 1, "{}", s.reason());
    assert!(
        !watch
            .statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached")),
        "the waypoints were replaced before their end"
    );
    let seq = s.seq;
    watch.until("the last goal reached", |w| {
        w.statuses
            .iter()
            .any(|s| s.seq == seq && s.active == 0 && s.reason().contains("reached"))
    });
    assert_eq!(
        watch.collisions(),
        collisions,
        "a collision while switching"
    );
    let s = watch.order(Order::new(OrderKind::Release));
    assert_eq!((s.accepted, s.active), (1, 0));

    // `hng order` from the terminal: refusals exit 1 with the reason; show tells the state.
    let out = run.hng(&["order", "follow-wall", "left"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("refused by the Interface"), "{err}");
    let out = run.hng(&["order", "goal", "1,nan"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not finite"));
    let out = run.hng(&["order", "stop"]);
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("stop in force"));
    let out = run.hng(&["order", "show", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(v["in_force"], "stop");
    let out = run.hng(&["behaviours", "--once", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let kinds: Vec<&str> = v["items"]
        .as_array()
        .expect("items")
        .iter()
        .filter_map(|i| i["kind"].as_str())
        .collect();
    assert!(
        kinds.contains(&"goal") && !kinds.contains(&"follow_wall"),
        "{kinds:?}"
    );

    drop(watch);
    run.signal(Signal::SIGTERM);
    let status = run.wait();
    run.assert_left_nothing();
    assert_eq!(status.code(), Some(0));
}
