//! The HNG v1.0 modules as real processes: Security stops a teleoperated robot before a wall.
//!
//! `hng module simulator` (a 4.5 m room, the robot 3.3 m from the east wall facing it) +
//! `manager` + `interface` + `robot` + `laser` + `security`, all on the simulation clock, under
//! a unique prefix. The command path is the contract tree's (paper 5.8): the Manager's
//! objectives "Robot integrity" (Security, whose "Robot control" contract is 1.1) and "Human
//! control" (the Interface, 2.1); the Robot obeys the Interface within Security's speed-limit
//! envelope. The test plays an operator pushing full speed (1 m/s) straight at the wall on the
//! Interface's `hng/teleop`, one command every 0.1 s of simulated time, as a lockstep
//! participant (the world waits for it every round, so load cannot starve it; no sleeps), and
//! checks on the ground truth and the simulator's own counters that the robot
//! drove towards the wall, stopped short of it and never touched it, and on the Robot's
//! contract table that the commands came by contract.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hng_runtime::clock::lockstep::Acker;
use hng_runtime::clock::{CLOCK_CHANNEL, Clock};
use hng_runtime::msg::{self, PoseWithCovariance, Twist};
use hng_runtime::system::{CONTRACTS, ContractRole, ContractTable};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions};
use hng_simulator::SimStatus;

use crate::common::TestSystem;

/// The world: a 4.5 x 3 m room, the robot facing its east wall.
pub(crate) fn world_file() -> String {
    format!(
        r#"
name = "wall-ahead"
seed = 11
dt_s = 0.01

[robot]
start = {{ x = 1.0, y = 1.5, theta = 0.0 }}
radius = 0.2
max_linear_speed = 1.0
max_linear_accel = 2.0
cmd_timeout_s = 0.5

{walls}

[sensors.gps]
enabled = false

[sensors.camera]
enabled = false
"#,
        walls = crate::common::room_walls(4.5, 3.0)
    )
}

/// The modules of the test, all lockstep participants.
const MODULES: [&str; 5] = ["robot", "laser", "security", "interface", "manager"];
/// The test's own node: the operator pushing on `hng/teleop`, a lockstep participant too.
const OPERATOR: &str = "operator";

/// East wall face: wall line x = 4.5 minus half its 5 cm thickness.
pub(crate) const WALL_FACE_X: f64 = 4.475;
pub(crate) const RADIUS: f64 = 0.2;

/// Module processes of one test; killed on drop, before the prefix is cleaned.
struct Procs {
    children: Vec<Child>,
    sys: TestSystem,
    dir: std::path::PathBuf,
}

impl Procs {
    fn spawn(&mut self, module: &str, config: &str, sim_clock: bool) {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_hng"));
        cmd.args(["module", module])
            .env("HNG_PREFIX", &self.sys.prefix)
            .env("HNG_MODULE_NAME", module)
            .env("HNG_MODULE_CONFIG", config)
            .env("HNG_LOG", "warn")
            .env_remove("HNG_CHECKPOINT_DIR")
            // Four processes on two shared cores: sleep rather than spin between inputs.
            .env("HNG_WAIT", "blocking:0")
            .stdin(Stdio::null());
        if sim_clock {
            cmd.env("HNG_CLOCK", "sim");
        } else {
            cmd.env_remove("HNG_CLOCK");
        }
        self.children
            .push(cmd.spawn().expect("spawn an hng module"));
    }

    fn stop_all(&mut self) {
        for c in &self.children {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(c.id() as i32),
                nix::sys::signal::Signal::SIGTERM,
            );
        }
        for mut c in self.children.drain(..) {
            let Some(status) = crate::common::wait_exit(&mut c, Duration::from_secs(10)) else {
                let _ = c.kill();
                let _ = c.wait();
                panic!("a module did not stop on SIGTERM");
            };
            assert!(status.success(), "a module exited with {status}");
        }
    }
}

impl Drop for Procs {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Keeps the latest contract table of the Robot (who holds "Robot control", what it obeyed).
fn read_robot_table(
    tables: &hng_runtime::Subscriber<ContractTable>,
    latest: &mut Option<ContractTable>,
) {
    while let Some(t) = tables.receive().expect("tables") {
        if t.module() == "robot" {
            *latest = Some(*t);
        }
    }
}

#[test]
fn security_stops_a_robot_teleoperated_straight_at_a_wall() {
    let sys = TestSystem::new("secwall");
    let dir = std::env::temp_dir().join(format!("{}world", sys.prefix));
    std::fs::create_dir_all(&dir).expect("world dir");
    let world = dir.join("wall.toml");
    std::fs::write(&world, world_file()).expect("write world");
    let mut p = Procs {
        children: Vec::new(),
        sys,
        dir,
    };
    // The test is the operator, and a lockstep participant like the modules: the world
    // waits for its command every round, so the outcome does not depend on how the test
    // process is scheduled (under load, a paced simulator outran it and the Interface's
    // 0.5 s deadman stopped the robot before the wall).
    let node = Node::new(
        NodeOptions::new(OPERATOR)
            .prefix(&p.sys.prefix)
            .clock(Clock::sim()),
    )
    .expect("node");
    let teleop = node.publisher::<Twist>("hng/teleop").expect("teleop");
    let tables = node
        .subscriber::<ContractTable>(CONTRACTS)
        .expect("contract tables");
    let truth = node
        .subscriber::<PoseWithCovariance>("sim/ground_truth")
        .expect("ground truth");
    let status = node.subscriber::<SimStatus>("sim/status").expect("status");
    let clock = node.subscriber::<msg::Clock>(CLOCK_CHANNEL).expect("clock");
    let mut acker = Acker::new(&node).expect("acker");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&clock).expect("attach");

    p.spawn("robot", "", true);
    p.spawn("laser", "", true);
    p.spawn("security", "", true);
    p.spawn("interface", "", true);
    p.spawn("manager", "", true);
    p.spawn(
        "simulator",
        &format!(
            "world = {:?}\nspeed = \"max\"\nwait_for = {MODULES:?}\nwait_timeout_s = 60.0\n\
             lockstep = {:?}\nlockstep_timeout_s = 60.0\n",
            world.to_string_lossy(),
            [&MODULES[..], &[OPERATOR]].concat(),
        ),
        false,
    );

    let push = Twist {
        linear_x: 1.0,
        ..Default::default()
    };
    // One command every 0.1 s of simulated time, the Interface's deadman being 0.5 s.
    const COMMAND_PERIOD_NS: u64 = 100_000_000;
    let end_ns = 7_000_000_000u64; // 7 s of simulated time: 3.3 m at 1 m/s, then standing
    let deadline = Instant::now() + Duration::from_secs(120);
    let (mut x, mut max_x, mut t_ns) = (1.0_f64, 1.0_f64, 0u64);
    let mut robot_table = None;
    let mut x_at_6s = None;
    let mut next_command_ns = 0u64;
    while t_ns < end_ns {
        assert!(
            Instant::now() < deadline,
            "simulation too slow: at {t_ns} ns"
        );
        let Some(first) = clock
            .receive_timeout(&mut waiter, Duration::from_secs(5))
            .expect("wait for the clock")
        else {
            continue;
        };
        let mut latest = first;
        while let Some(c) = clock.receive().expect("clock") {
            latest = c;
        }
        node.clock().set_sim_ns(latest.sim_time_ns);
        // Everything the round brought is in the queues now (published before the round).
        while let Some(g) = truth.receive().expect("receive") {
            x = g.pose.x;
            max_x = max_x.max(x);
            t_ns = g.header.stamp_ns;
            assert!(
                (g.pose.y - 1.5).abs() < 0.2,
                "the robot drove straight: {:?}",
                g.pose
            );
            if x_at_6s.is_none() && t_ns >= 6_000_000_000 {
                x_at_6s = Some(x);
            }
        }
        if latest.sim_time_ns >= next_command_ns {
            teleop.publish(push).expect("teleop");
            next_command_ns = latest.sim_time_ns + COMMAND_PERIOD_NS;
        }
        read_robot_table(&tables, &mut robot_table);
        acker
            .after_iteration(&node, latest.round, 0, next_command_ns)
            .expect("acknowledge the round");
    }
    read_robot_table(&tables, &mut robot_table);
    let s = *status.latest().expect("status").expect("a status sample");
    p.stop_all();

    let gap = WALL_FACE_X - x - RADIUS;
    eprintln!(
        "robot stopped at x = {x:.3} m, gap to the wall {gap:.3} m, min clearance {:.3} m",
        s.min_clearance
    );
    assert!(
        max_x > 3.5,
        "the robot drove towards the wall (max x {max_x})"
    );
    assert!(gap > 0.0, "the robot stopped before contact: gap {gap} m");
    assert!(
        gap < 0.6,
        "it was stopped by Security, not far away: gap {gap} m"
    );
    let x6 = x_at_6s.expect("passed 6 s");
    assert!(
        (x - x6).abs() < 0.05,
        "held while still pushed: {x6} -> {x}"
    );
    assert_eq!(s.collisions, 0, "no collision: {s:?}");
    assert!(s.min_clearance > 0.0, "never touched: {s:?}");
    assert!(s.accepted_commands > 0);
    let t = robot_table.expect("the Robot published its contract table");
    let mut clients: Vec<(String, Vec<u16>)> = t
        .entries()
        .iter()
        .filter(|e| e.role() == Some(ContractRole::Provider) && e.service() == "Robot control")
        .map(|e| (e.service().to_string(), e.priority().to_vec()))
        .collect();
    clients.sort_by(|a, b| a.1.cmp(&b.1));
    let priorities: Vec<&[u16]> = clients.iter().map(|c| c.1.as_slice()).collect();
    assert_eq!(
        priorities,
        [&[1u16, 1][..], &[2, 1][..]],
        "Robot control held by Security (1.1) and the Interface (2.1)"
    );
    assert!(
        t.commands_accepted > 0,
        "the Robot obeyed a contract holder: {:?}",
        t.commands_accepted
    );
    assert_eq!(
        t.commands_preempted, 0,
        "Security sends no command to preempt the Interface's: it limits them by its envelope"
    );
}
