//! The simulator module (`hng module simulator`) as a real process: sensor rates in simulated
//! time, the clock, velocity commands, rejected commands, hybrid runs, the map for late
//! joiners, determinism across processes, sim-clock followers, SIGTERM and checkpoints.

use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use hng_runtime::clock::CLOCK_CHANNEL;
use hng_runtime::msg::{self, GridInfo, LaserScan, Message, PoseWithCovariance, Twist};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, SliceSubscriber, Subscriber};
use hng_simulator::{SimStatus, World};

use crate::common::{TestSystem, wait_until};

const SEC: u64 = 1_000_000_000;

/// A test system with simulator processes; they are stopped before the prefix is cleaned.
struct SimSystem {
    sims: Vec<Child>,
    observer: Option<Node>,
    sys: TestSystem,
}

impl SimSystem {
    fn new(tag: &str) -> SimSystem {
        let sys = TestSystem::new(tag);
        let node = sys.node("observer");
        SimSystem {
            sims: Vec::new(),
            observer: Some(node),
            sys,
        }
    }

    /// The test's own node.
    fn node(&self) -> &Node {
        self.observer.as_ref().expect("the observer node is open")
    }

    fn spawn_sim(&mut self, config: &str, env: &[(&str, &str)]) {
        let child = Command::new(env!("CARGO_BIN_EXE_hng"))
            .args(["module", "simulator"])
            .envs(env.iter().copied())
            .env("HNG_PREFIX", &self.sys.prefix)
            .env("HNG_MODULE_NAME", "simulator")
            .env("HNG_MODULE_CONFIG", config)
            .env("HNG_LOG", "warn")
            .env("HNG_CLOCK", "sim") // as `hng run` sets it; the simulator ignores it
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn hng module simulator");
        self.sims.push(child);
    }

    fn watch<T: Message>(&self, channel: &str) -> Watch<T> {
        let sub = self.node().subscriber::<T>(channel).expect("subscriber");
        let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
        waiter.attach(&sub).expect("attach");
        Watch { sub, waiter }
    }

    /// SIGTERM to every simulator; their exit statuses.
    fn stop_sims(&mut self) -> Vec<ExitStatus> {
        self.sims.drain(..).map(terminate).collect()
    }
}

impl Drop for SimSystem {
    fn drop(&mut self) {
        for c in &mut self.sims {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn terminate(mut c: Child) -> ExitStatus {
    crate::common::terminate(&mut c, Duration::from_secs(10)).unwrap_or_else(|| {
        let _ = c.kill();
        panic!("the simulator did not stop within 10 s of SIGTERM");
    })
}

/// A subscriber with its own waiter.
struct Watch<T: Message> {
    sub: Subscriber<T>,
    waiter: Waiter,
}

impl<T: Message> Watch<T> {
    /// The next message, waiting at most until `deadline`.
    fn next(&mut self, deadline: Instant, what: &str) -> T {
        wait_until(
            &mut self.waiter,
            deadline.saturating_duration_since(Instant::now()),
            || self.sub.receive().expect("receive").map(|s| *s),
            || format!("timed out waiting for {what}"),
        )
    }

    /// Messages until one satisfies `done` (included).
    fn until(&mut self, deadline: Instant, what: &str, mut done: impl FnMut(&T) -> bool) -> Vec<T> {
        let mut out = Vec::new();
        loop {
            let m = self.next(deadline, what);
            let stop = done(&m);
            out.push(m);
            if stop {
                return out;
            }
        }
    }
}

fn deadline() -> Instant {
    Instant::now() + Duration::from_secs(15)
}

fn assert_clean_exit(statuses: &[ExitStatus]) {
    assert!(
        statuses.iter().all(|s| s.success()),
        "SIGTERM must stop the simulator cleanly: {statuses:?}"
    );
}

#[test]
fn sim_scans_come_at_their_rate_in_simulated_time_and_the_clock_advances() {
    let mut s = SimSystem::new("simrate");
    let mut scans = s.watch::<LaserScan>("sim/scan");
    let mut clock = s.watch::<msg::Clock>(CLOCK_CHANNEL);
    s.spawn_sim(r#"speed = 10"#, &[]);

    let got = scans.until(deadline(), "scans", |m| m.header.stamp_ns >= 3 * SEC);
    // A reader that falls behind loses the oldest scans (sequence gaps); every scan it gets
    // is 100 ms of simulated time per sequence number after the previous one.
    for w in got.windows(2) {
        let seqs = w[1].header.seq - w[0].header.seq;
        assert_eq!(
            w[1].header.stamp_ns - w[0].header.stamp_ns,
            seqs * SEC / 10,
            "10 Hz in simulated time"
        );
    }
    assert!(got.iter().all(|m| m.header.stamp_ns % (SEC / 10) == 0));
    let per_second: Vec<usize> = (0..3)
        .map(|sec| {
            got.iter()
                .filter(|m| m.header.stamp_ns > sec * SEC && m.header.stamp_ns <= (sec + 1) * SEC)
                .count()
        })
        .collect();
    assert_eq!(
        per_second[2], 10,
        "scans per simulated second: {per_second:?}"
    );
    let first = &got[0];
    assert_eq!(first.header.frame_id, msg::FrameId::LASER);
    assert_eq!(first.ranges().len(), 360);
    assert!(
        first.ranges().iter().all(|r| *r > 0.0),
        "no NaN, nothing too close"
    );
    assert!(first.ranges().iter().filter(|r| r.is_finite()).count() > 300);

    // The clock: at least as far as the scans, and moving on.
    let now = clock
        .until(deadline(), "the clock", |c| c.sim_time_ns >= 3 * SEC)
        .last()
        .map_or(0, |c| c.sim_time_ns);
    let later = clock.until(deadline(), "the clock", |c| c.sim_time_ns >= now + SEC);
    for w in later.windows(2) {
        assert!(
            w[1].sim_time_ns >= w[0].sim_time_ns,
            "the clock never goes back"
        );
    }

    assert_clean_exit(&s.stop_sims());
    drop((scans, clock));
    s.observer = None;
    // After a clean stop only the system's own files remain (management file, wake
    // segments, CPU register).
    let left = hng_runtime::shm::leftovers(&s.sys.prefix);
    assert!(left.is_empty(), "left behind after a clean stop: {left:?}");
}

#[test]
fn the_same_seed_gives_bit_identical_scans_in_two_processes() {
    // One simulator at a time, read from its start; scans are matched by their stamps.
    let scans_of = |seed: u64| -> Vec<(u64, Vec<u32>)> {
        let mut s = SimSystem::new("simdet");
        let mut scans = s.watch::<LaserScan>("sim/scan");
        s.spawn_sim(&format!("speed = 10\nseed = {seed}"), &[]);
        let got = scans.until(deadline(), "scans", |m| m.header.stamp_ns >= 2 * SEC);
        assert_clean_exit(&s.stop_sims());
        got.iter()
            .map(|m| {
                let bits = m.ranges().iter().map(|r| r.to_bits()).collect();
                (m.header.stamp_ns, bits)
            })
            .collect()
    };
    let (a, b, other) = (scans_of(42), scans_of(42), scans_of(43));
    let mut common = 0;
    for (t, ra) in &a {
        if let Some((_, rb)) = b.iter().find(|(tb, _)| tb == t) {
            let differ = ra.iter().zip(rb).filter(|(x, y)| x != y).count();
            assert_eq!(
                differ,
                0,
                "scan at {} ms: {differ} beams differ between runs with the same seed",
                t / 1_000_000
            );
            assert_eq!(ra.len(), rb.len());
            common += 1;
        }
        if let Some((_, ro)) = other.iter().find(|(to, _)| to == t) {
            assert_ne!(ra, ro, "another seed, other noise");
        }
    }
    assert!(
        common >= 10,
        "only {common} scans of the first 20 seen in both runs"
    );
    assert_ne!(a[0].1, a[1].1, "noise differs scan to scan");
}

#[test]
fn cmd_vel_moves_the_robot_and_a_nan_command_is_rejected_and_stops_it() {
    let mut s = SimSystem::new("simcmd");
    let mut truth = s.watch::<PoseWithCovariance>("sim/ground_truth");
    let mut odom = s.watch::<msg::Odometry>("sim/odom");
    let mut status = s.watch::<SimStatus>("sim/status");
    let cmd = s
        .node()
        .publisher::<Twist>("sim/cmd_vel")
        .expect("publisher");
    // Speed 2: the test is no lockstep participant, and at speed 10 a test process scheduled
    // out for 50 ms of wall time (load 16 and more) let the 0.5 s command timeout fire.
    s.spawn_sim(r#"speed = 2"#, &[]);

    // Closed loop in simulated time: one command per ground-truth message (100 Hz).
    let go = Twist {
        linear_x: 0.4,
        ..Default::default()
    };
    let start = truth.next(deadline(), "ground truth");
    let mut last = start;
    let mut published = 0u64;
    while last.header.stamp_ns < start.header.stamp_ns + 2 * SEC {
        cmd.publish(go).expect("publish");
        published += 1;
        last = truth.next(deadline(), "ground truth");
    }
    let (dx, dy) = (last.pose.x - start.pose.x, last.pose.y - start.pose.y);
    assert!(
        dx > 0.6 && dx < 0.81,
        "0.4 m/s for 2 s moved the robot {dx} m"
    );
    assert!(dy.abs() < 0.01, "straight ahead: dy = {dy}");
    let od = odom.until(deadline(), "odometry", |o| {
        o.header.stamp_ns >= last.header.stamp_ns
    });
    let od_x = od.last().expect("odometry").pose.x;
    assert_eq!(
        od.last().expect("odometry").header.frame_id,
        msg::FrameId::ODOM
    );
    assert!(
        (od_x - (last.pose.x - 2.0)).abs() < 0.05,
        "odometry {od_x} follows the true motion {}",
        last.pose.x - 2.0
    );

    // A NaN command: rejected, counted, and the robot stops at once (well before the 0.5 s
    // command timeout would stop it).
    cmd.publish(Twist {
        linear_x: f64::NAN,
        ..go
    })
    .expect("publish");
    let t0 = last.header.stamp_ns;
    let after = truth.until(deadline(), "ground truth", |m| {
        m.header.stamp_ns >= t0 + SEC * 45 / 100
    });
    let stopped: Vec<_> = after
        .iter()
        .filter(|m| m.header.stamp_ns >= t0 + SEC * 35 / 100)
        .collect();
    assert!(stopped.len() >= 5);
    for m in &stopped {
        assert!(
            (m.pose.x - stopped[0].pose.x).abs() < 1e-9,
            "the robot stopped: x {} then {}",
            stopped[0].pose.x,
            m.pose.x
        );
    }
    let st = status.until(deadline(), "status", |st| st.rejected_commands > 0);
    let st = st.last().expect("status");
    assert_eq!(st.rejected_commands, 1);
    // Every command this test sent was accepted, bar those a loaded machine lets a newer one
    // overwrite in the simulator's queue before it reads them (a slow test also sends fewer:
    // one per ground-truth message it receives).
    assert!(
        st.accepted_commands <= published && 2 * st.accepted_commands >= published,
        "{} of {published} commands accepted: {st:?}",
        st.accepted_commands
    );
    assert_eq!(
        st.command_timeouts, 0,
        "stopped by the rejection, not the timeout"
    );
    assert_clean_exit(&s.stop_sims());
}

#[test]
fn a_teleport_moves_the_robot_without_counting_the_jump_and_one_into_a_pillar_is_refused() {
    use hng_simulator::module::SimTeleport;
    let mut s = SimSystem::new("simteleport");
    let mut truth = s.watch::<PoseWithCovariance>("sim/ground_truth");
    let mut status = s.watch::<SimStatus>("sim/status");
    let teleport = s
        .node()
        .publisher::<SimTeleport>("sim/teleport")
        .expect("publisher");
    s.spawn_sim(r#"speed = 10"#, &[]);
    let to = |x: f64, y: f64, theta: f64| SimTeleport {
        pose: msg::Pose2D::new(x, y, theta),
        ..SimTeleport::default()
    };
    let start = truth.next(deadline(), "ground truth");
    assert!((start.pose.x - 2.0).abs() < 0.01, "{start:?}");

    // Into the south room, 8.5 m away.
    teleport.publish(to(10.0, 5.0, 1.0)).expect("publish");
    let there = truth.until(deadline(), "the robot at (10, 5)", |m| {
        (m.pose.x - 10.0).hypot(m.pose.y - 5.0) < 0.01
    });
    let there = there.last().expect("ground truth");
    assert!((there.pose.theta - 1.0).abs() < 0.01, "{there:?}");
    let t = there.header.stamp_ns;
    let st = status.until(deadline(), "status after the teleport", |st| {
        st.header.stamp_ns >= t
    });
    let st = st.last().expect("status");
    assert!(
        st.path_length_m < 0.1,
        "the jump is not a path: {} m",
        st.path_length_m
    );
    assert_eq!((st.teleports, st.teleports_refused), (1, 0), "{st:?}");

    // Into the pillar at (4, 5), and a NaN: refused, the robot stays; then (11, 6): it goes
    // there, and no step between shows it anywhere else (ground truth comes every step).
    teleport.publish(to(4.0, 5.0, 0.0)).expect("publish");
    teleport.publish(to(f64::NAN, 5.0, 0.0)).expect("publish");
    teleport.publish(to(11.0, 6.0, 0.0)).expect("publish");
    let later = truth.until(deadline(), "the robot at (11, 6)", |m| {
        (m.pose.x - 11.0).hypot(m.pose.y - 6.0) < 0.01
    });
    for m in &later {
        let at = |x: f64, y: f64| (m.pose.x - x).hypot(m.pose.y - y) < 0.01;
        assert!(
            at(10.0, 5.0) || at(11.0, 6.0),
            "only at (10, 5) or (11, 6): {m:?}"
        );
    }
    // The status counts both answers (published at once after each).
    let st = status.until(deadline(), "status counting the three teleports", |st| {
        st.teleports == 2
    });
    let st = st.last().expect("status");
    assert_eq!(st.teleports_refused, 2, "{st:?}");
    assert_clean_exit(&s.stop_sims());
}

#[test]
fn a_switched_off_sensor_leaves_its_channel_to_another_driver() {
    let mut s = SimSystem::new("simhyb");
    let scans = s.watch::<LaserScan>("sim/scan");
    let mut truth = s.watch::<PoseWithCovariance>("sim/ground_truth");
    s.spawn_sim("speed = 20\n[sensors]\nlidar = false\ncamera = false", &[]);
    // The real driver (here: this test) publishes the scans.
    let driver = s.node().publisher::<LaserScan>("sim/scan").expect("driver");
    driver
        .publish(LaserScan {
            count: 7,
            ..Default::default()
        })
        .expect("publish");
    truth.until(deadline(), "ground truth", |m| m.header.stamp_ns >= SEC);
    let mut seen = 0;
    while let Some(m) = scans.sub.receive().expect("receive") {
        assert_eq!(m.count, 7, "only the driver's scans: {m:?}");
        assert_eq!(m.header.source, s.node().id());
        seen += 1;
    }
    assert_eq!(seen, 1);
    assert_clean_exit(&s.stop_sims());
}

#[test]
fn a_late_subscriber_gets_the_ground_truth_map() {
    let mut s = SimSystem::new("simmap");
    let mut clock = s.watch::<msg::Clock>(CLOCK_CHANNEL);
    s.spawn_sim("speed = 20", &[]);
    // Join well after the map was published.
    clock.until(deadline(), "the clock", |c| c.sim_time_ns >= SEC / 2);
    let map: SliceSubscriber<GridInfo> = s.node().slice_subscriber("sim/map").expect("subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&map).expect("attach");
    let end = deadline();
    let sample = loop {
        if let Some(m) = map.receive().expect("receive") {
            break m;
        }
        let left = end.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "no map for the late subscriber");
        waiter.wait(Some(left)).expect("wait");
    };
    let want = hng_simulator::grid_from_world(&World::default_world(), 0.05).expect("grid");
    let info = sample.header();
    assert_eq!(info.header.frame_id, msg::FrameId::MAP);
    assert_eq!((info.width, info.height), (want.width(), want.height()));
    assert!((f64::from(info.resolution) - 0.05).abs() < 1e-9);
    assert_eq!(
        (info.origin.x, info.origin.y),
        (want.origin()[0], want.origin()[1])
    );
    assert_eq!(sample.data(), want.data());
    assert_clean_exit(&s.stop_sims());
}

#[test]
fn a_module_on_the_sim_clock_ticks_in_simulated_time() {
    let mut s = SimSystem::new("simclk");
    let mut counts = s.watch::<msg::Goal>("test/count");
    s.spawn_sim("speed = 10", &[]);
    s.sys.spawn_testmod_with(
        "counter",
        "counter",
        "period_s = 0.1",
        &[("HNG_CLOCK", "sim")],
    );
    let first = counts.next(deadline(), "the first counter tick");
    let ticks = counts.until(deadline(), "counter ticks", |g| g.id >= first.id + 20);
    let last = ticks.last().expect("ticks");
    // A timer on the simulation clock never fires before its time in simulated time (a
    // follower that falls behind skips periods rather than bursting). A tick is stamped when it
    // is handled, up to one clock step after its scheduled time, so the bound holds for the
    // span: n ticks later is at least n - 1 periods later.
    for w in ticks.windows(2) {
        assert!(w[1].id > w[0].id && w[1].header.stamp_ns > w[0].header.stamp_ns);
    }
    let span = last.header.stamp_ns - first.header.stamp_ns;
    let periods = u64::from(last.id - first.id);
    assert!(
        span >= (periods - 1) * 100_000_000,
        "{periods} ticks of a 100 ms timer spanned only {span} ns of simulated time"
    );
    // The stamps are simulated time: never ahead of the simulator's clock (a wall-clock
    // stamp, the machine's uptime, would be far ahead of a simulation that started seconds ago).
    let clock = s
        .node()
        .subscriber::<msg::Clock>(hng_runtime::clock::CLOCK_CHANNEL)
        .expect("clock subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&clock).expect("attach");
    let end = deadline();
    let now = loop {
        s.node().update_connections();
        if let Some(c) = clock.latest().expect("clock") {
            break c.sim_time_ns;
        }
        let left = end.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "no simulation clock");
        waiter.wait(Some(left)).expect("wait");
    };
    assert!(
        last.header.stamp_ns <= now,
        "tick stamped {} ns, simulation clock at {now} ns",
        last.header.stamp_ns
    );
    assert_clean_exit(&s.stop_sims());
    s.sys.stop_cleanly();
}

#[test]
fn a_restarted_simulator_resumes_from_its_checkpoint() {
    let mut s = SimSystem::new("simckpt");
    let dir = std::env::temp_dir().join(format!("{}ckpt", s.sys.prefix));
    let dir_s = dir.to_string_lossy().into_owned();
    let env = [("HNG_CHECKPOINT_DIR", dir_s.as_str())];
    let mut truth = s.watch::<PoseWithCovariance>("sim/ground_truth");
    let cmd = s
        .node()
        .publisher::<Twist>("sim/cmd_vel")
        .expect("publisher");
    s.spawn_sim("speed = 10", &env);
    let start = truth.next(deadline(), "ground truth");
    let mut last = start;
    while last.header.stamp_ns < start.header.stamp_ns + SEC {
        cmd.publish(Twist {
            linear_x: 0.5,
            ..Default::default()
        })
        .expect("publish");
        last = truth.next(deadline(), "ground truth");
    }
    assert_clean_exit(&s.stop_sims()); // writes the final checkpoint
    let mut before = last;
    while let Some(m) = truth.sub.receive().expect("drain") {
        before = *m;
    }
    assert!(before.pose.x > start.pose.x + 0.3);

    s.spawn_sim("speed = 10", &env);
    let resumed = truth.next(deadline(), "ground truth after the restart");
    assert!(
        resumed.header.stamp_ns > before.header.stamp_ns,
        "simulated time resumes: {} after {}",
        resumed.header.stamp_ns,
        before.header.stamp_ns
    );
    assert!(
        (resumed.pose.x - before.pose.x).abs() < 0.05
            && (resumed.pose.y - before.pose.y).abs() < 0.01,
        "the robot resumes where it was: {:?} vs {:?}",
        resumed.pose,
        before.pose
    );
    assert_clean_exit(&s.stop_sims());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sigterm_stops_a_simulator_running_as_fast_as_possible() {
    let mut s = SimSystem::new("simmax");
    let mut clock = s.watch::<msg::Clock>(CLOCK_CHANNEL);
    let mut status = s.watch::<SimStatus>("sim/status");
    // Physics and the light sensors only: camera images cost their own time
    // (`hng bench vision`, render per frame) and are switched off here.
    s.spawn_sim("speed = \"max\"\nsensors = { camera_image = false }", &[]);
    clock.until(deadline(), "the clock", |c| c.sim_time_ns >= 20 * SEC);
    let st = status.until(deadline(), "status", |st| st.sim_time_ns >= 20 * SEC);
    let st = st.last().expect("status");
    assert_eq!(st.target_factor, 0.0, "max speed");
    assert!(
        st.realtime_factor > 20.0,
        "as fast as possible: {} x real time",
        st.realtime_factor
    );
    let t = Instant::now();
    assert_clean_exit(&s.stop_sims());
    assert!(
        t.elapsed() < Duration::from_secs(2),
        "SIGTERM handled at once"
    );
}

/// Paused start: simulated time stays at 0 while a module it waits for is not up, and runs
/// once that module has sent its first report.
#[test]
fn simulated_time_waits_for_the_modules_it_waits_for() {
    use hng_runtime::module::REPORT_CHANNEL;
    use hng_runtime::msg::ModuleReport;
    let mut s = SimSystem::new("sim-wait");
    let mut clock = s.watch::<msg::Clock>(CLOCK_CHANNEL);
    let mut reports = s.watch::<ModuleReport>(REPORT_CHANNEL);
    s.spawn_sim(
        "speed = \"max\"\nwait_for = [\"late\"]\nwait_timeout_s = 600",
        &[("HNG_REPORT_PERIOD_MS", "50")],
    );
    // The simulator runs (three of its reports: its ticks have come many times at `max`)...
    let mut seen = 0;
    reports.until(deadline(), "the simulator's reports", |r| {
        seen += usize::from(r.name() == "simulator");
        seen >= 3
    });
    // ...but simulated time has not moved.
    let first = clock.next(deadline(), "the clock");
    assert_eq!(first.sim_time_ns, 0, "{first:?}");
    while let Some(c) = clock.sub.receive().expect("receive") {
        assert_eq!(c.sim_time_ns, 0, "time moved before `late` was up: {c:?}");
    }
    s.sys.spawn_testmod("counter", "late", "");
    clock.until(deadline(), "the clock", |c| c.sim_time_ns >= SEC);
    assert_clean_exit(&s.stop_sims());
}
