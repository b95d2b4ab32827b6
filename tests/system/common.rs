//! Shared helpers: unique prefixes, spawned module processes that never outlive a test, and
//! [`Watch`], what a test sees of a running robot (true poses, simulator status, orders,
//! behaviours, contracts) with its operator's ports.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{
    BEHAVIOURS_CHANNEL, Behaviours, ModuleReport, ORDER_CHANNEL, ORDER_STATUS_CHANNEL, Order,
    OrderKind, OrderStatus, Pose2D, PoseWithCovariance, Twist, module_id,
};
use hng_runtime::system::{CONTRACTS, ContractRole, ContractTable};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, Publisher, Subscriber, shm};
use hng_simulator::module::SimStatus;

/// A launch file: its header (`system`, `clock = "sim"`, the `[defaults]` of supervision given
/// as `heartbeat_timeout_s` and `start_timeout_s`, seconds), then one `[[module]]` entry per `(name, keys,
/// config)`: built-in module `name` (`hng module NAME`), its extra keys (`manager = true`) and
/// its `config` table (TOML lines; none when empty).
pub(crate) fn launch_file(
    system: &str,
    heartbeat_timeout_s: f64,
    start_timeout_s: f64,
    modules: &[(&str, &str, &str)],
) -> String {
    let mut s = format!(
        "system = {system:?}\nclock = \"sim\"\n\n[defaults]\nheartbeat_period_s = 0.2\n\
         heartbeat_timeout_s = {heartbeat_timeout_s:?}\nstart_timeout_s = {start_timeout_s:?}\n\
         stop_timeout_s = 2.0\n"
    );
    for (name, keys, config) in modules {
        s.push_str(&format!(
            "\n[[module]]\nname = {name:?}\ncommand = [\"hng\", \"module\", {name:?}]\n"
        ));
        if !keys.is_empty() {
            s.push_str(&format!("{keys}\n"));
        }
        if !config.is_empty() {
            s.push_str(&format!("[module.config]\n{config}\n"));
        }
    }
    s
}

/// The world-file walls (`[[walls]]` tables) of a closed `width` x `height` m room with a
/// corner at the origin, axis-aligned.
pub(crate) fn room_walls(width: f64, height: f64) -> String {
    let corners = [(0.0, 0.0), (width, 0.0), (width, height), (0.0, height)];
    let mut s = String::new();
    for (i, a) in corners.iter().enumerate() {
        let b = corners[(i + 1) % 4];
        s.push_str(&format!(
            "\n[[walls]]\nfrom = [{:?}, {:?}]\nto = [{:?}, {:?}]\n",
            a.0, a.1, b.0, b.1
        ));
    }
    s
}

/// Generous: a whole robot in accelerated simulation on two loaded cores.
pub(crate) const TIMEOUT: Duration = Duration::from_secs(150);

/// Waits on `waiter` (its channels) until `poll`, which reads what arrived, gives a value;
/// panics with `why()` when `timeout` passes first.
pub(crate) fn wait_until<T>(
    waiter: &mut Waiter,
    timeout: Duration,
    mut poll: impl FnMut() -> Option<T>,
    why: impl FnOnce() -> String,
) -> T {
    waiter
        .wait_for(timeout, || Ok(poll()))
        .expect("wait")
        .unwrap_or_else(|| panic!("{}", why()))
}

/// Polls `done` every `every` until it holds, for what no channel announces (a process's
/// end, a file's content); panics with `why()` when `timeout` passes first.
pub(crate) fn poll_until(
    timeout: Duration,
    every: Duration,
    mut done: impl FnMut() -> bool,
    why: impl FnOnce() -> String,
) {
    let deadline = Instant::now() + timeout;
    while !done() {
        assert!(Instant::now() < deadline, "{}", why());
        std::thread::sleep(every);
    }
}

/// Waits (blocking, with a deadline) for the first report of module `name` that satisfies
/// `pred`.
pub fn wait_for_report(
    node: &hng_runtime::Node,
    name: &str,
    timeout: Duration,
    mut pred: impl FnMut(&ModuleReport) -> bool,
) -> ModuleReport {
    let sub = node
        .subscriber::<ModuleReport>(REPORT_CHANNEL)
        .expect("report subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&sub).expect("attach");
    wait_until(
        &mut waiter,
        timeout,
        || {
            std::iter::from_fn(|| sub.receive().expect("receive report"))
                .find(|r| r.name() == name && pred(r))
                .map(|r| *r)
        },
        || format!("no matching report from {name} within {timeout:?}"),
    )
}

/// A test's isolated system: its prefix, and the processes it started.
pub struct TestSystem {
    pub prefix: String,
    children: Vec<Child>,
}

impl TestSystem {
    pub fn new(tag: &str) -> TestSystem {
        TestSystem {
            prefix: shm::unique_prefix(tag),
            children: Vec::new(),
        }
    }

    /// A node of the test's own on this system's prefix.
    pub fn node(&self, name: &str) -> Node {
        Node::new(NodeOptions::new(name).prefix(&self.prefix)).expect("node")
    }

    /// Starts the fixture module `role` with `HNG_*` settings for this system.
    pub fn spawn_testmod(&mut self, role: &str, name: &str, config: &str) -> u32 {
        self.spawn_testmod_with(role, name, config, &[])
    }

    /// Like [`TestSystem::spawn_testmod`], with extra environment variables.
    pub fn spawn_testmod_with(
        &mut self,
        role: &str,
        name: &str,
        config: &str,
        env: &[(&str, &str)],
    ) -> u32 {
        self.spawn(
            Command::new(env!("CARGO_BIN_EXE_hng-testmod"))
                .arg(role)
                .envs(env.iter().copied())
                .env("HNG_MODULE_NAME", name)
                .env("HNG_MODULE_CONFIG", config)
                .env(
                    "HNG_LOG",
                    std::env::var("HNG_TEST_LOG").unwrap_or("warn".into()),
                ),
        )
    }

    /// Starts `cmd` with this system's prefix; it is stopped with the system.
    pub fn spawn(&mut self, cmd: &mut Command) -> u32 {
        let child = cmd
            .env("HNG_PREFIX", &self.prefix)
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn");
        let pid = child.id();
        self.children.push(child);
        pid
    }

    /// Stops every child ([`TestSystem::stop_all`]); each must exit successfully.
    pub fn stop_cleanly(&mut self) {
        let statuses = self.stop_all();
        assert!(
            statuses.iter().all(|s| s.success()),
            "not every child stopped cleanly: {statuses:?}"
        );
    }

    /// Sends SIGTERM to every child and waits for each; returns their exit statuses.
    pub fn stop_all(&mut self) -> Vec<std::process::ExitStatus> {
        let mut out = Vec::new();
        for mut c in self.children.drain(..) {
            let status = terminate(&mut c, Duration::from_secs(10)).unwrap_or_else(|| {
                let _ = c.kill();
                c.wait().expect("wait child")
            });
            out.push(status);
        }
        out
    }
}

impl Drop for TestSystem {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
        shm::remove_prefix_files(&self.prefix);
    }
}

/// Starts `hng run ARGS --no-gui --status-period 0.1 --run-dir DIR FILE` on `prefix`: stdout
/// discarded, its log (INFO) in `DIR/run.log`.
pub(crate) fn spawn_hng_run(
    prefix: &str,
    dir: &std::path::Path,
    file: &std::path::Path,
    args: &[&str],
) -> Child {
    let log = std::fs::File::create(dir.join("run.log")).expect("log file");
    hng_run(prefix, log)
        .args(args)
        .args(["--no-gui", "--status-period", "0.1", "--run-dir"])
        .arg(dir)
        .arg(file)
        .stdout(Stdio::null())
        .spawn()
        .expect("spawn hng run")
}

/// `hng run` on `prefix`, no input, its log (INFO) to `log`; the caller adds its arguments and
/// says where stdout goes.
pub(crate) fn hng_run(prefix: &str, log: std::fs::File) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_hng"));
    cmd.arg("run")
        .env("HNG_PREFIX", prefix)
        .env("HNG_LOG", "info")
        .stdin(Stdio::null())
        .stderr(log);
    cmd
}

/// Waits up to `timeout` for `child` to exit; `None` if it has not (or cannot be asked).
pub(crate) fn wait_exit(child: &mut Child, timeout: Duration) -> Option<std::process::ExitStatus> {
    let deadline = Instant::now() + timeout;
    loop {
        match child.try_wait() {
            Ok(Some(s)) => return Some(s),
            Ok(None) if Instant::now() < deadline => {}
            _ => return None,
        }
        // Waiting for a process to exit: poll its status at 5 ms intervals.
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Sends SIGTERM to `child` and waits up to `timeout` for it to exit ([`wait_exit`]).
pub(crate) fn terminate(child: &mut Child, timeout: Duration) -> Option<std::process::ExitStatus> {
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    wait_exit(child, timeout)
}

/// A child process killed (SIGKILL) and reaped on drop: a test that fails never leaves a
/// process behind (the modules of an `hng run` follow it by their parent-death signal).
pub(crate) struct Reaped(pub(crate) Child);

impl Reaped {
    /// Whether the child still runs (it has not exited).
    pub(crate) fn running(&mut self) -> bool {
        self.0.try_wait().expect("try_wait").is_none()
    }

    /// Waits for the child to end: its exit status, stdout and stderr (each empty unless
    /// piped).
    pub(crate) fn finish(&mut self) -> (std::process::ExitStatus, String, String) {
        use std::io::Read as _;
        let mut out = String::new();
        let mut err = String::new();
        if let Some(mut o) = self.0.stdout.take() {
            o.read_to_string(&mut out).expect("stdout");
        }
        if let Some(mut e) = self.0.stderr.take() {
            e.read_to_string(&mut err).expect("stderr");
        }
        (self.0.wait().expect("wait"), out, err)
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Tests that load the machine (a whole robot in accelerated simulation, CPU-share
/// measurements) hold this lock, so that they never run beside each other on a small machine:
/// what they measure is then the system under test, not the neighbouring test.
pub fn heavy() -> std::sync::MutexGuard<'static, ()> {
    static HEAVY: std::sync::Mutex<()> = std::sync::Mutex::new(());
    HEAVY
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Says that `test` skipped because `why` (a client it needs is missing), where the runner's
/// summary cannot hide it: straight to the process's stderr (cargo's test harness captures
/// only `eprintln!`), and as a line in `target/skipped-tests.txt`, which `.ci/run` prints
/// after the tests. A skip is never silent.
pub fn skip(test: &str, why: &str) {
    use std::io::Write as _;
    let line = format!("SKIPPED {test}: {why}\n");
    let _ = std::io::stderr().write_all(line.as_bytes());
    let list = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/skipped-tests.txt");
    if let Ok(mut file) = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&list)
    {
        let _ = file.write_all(line.as_bytes());
    }
}

/// What the test sees of the running system, and its operator's ports.
pub(crate) struct Watch {
    truth: Subscriber<PoseWithCovariance>,
    status: Subscriber<SimStatus>,
    orders_status: Subscriber<OrderStatus>,
    reports: Subscriber<ModuleReport>,
    behaviours_in: Subscriber<Behaviours>,
    tables: Subscriber<ContractTable>,
    /// The Robot's command input, where the Interface forwards teleop commands.
    robot_cmds: Subscriber<Twist>,
    orders: Publisher<Order>,
    teleop: Publisher<Twist>,
    waiter: Waiter,
    /// Latest true pose and its simulated time, s.
    pub pose: Option<(Pose2D, f64)>,
    /// True poses since `track` was cleared: (t, x, y).
    pub track: Vec<(f64, f64, f64)>,
    /// True headings, with `track`: (t, theta).
    pub headings: Vec<(f64, f64)>,
    pub sim: Option<SimStatus>,
    /// Every order status seen.
    pub statuses: Vec<OrderStatus>,
    pub behaviours: Option<Behaviours>,
    /// Every distinct behaviours list seen.
    pub offers: Vec<Behaviours>,
    pub interface_dropped: u64,
    /// Latest contract table per module name.
    pub contracts: std::collections::BTreeMap<String, ContractTable>,
    /// Every change of a client's provider, from every table read (not only the latest):
    /// (the table's stamp in s, client module, need, provider id or 0 for none).
    pub provider_changes: Vec<(f64, String, u16, u32)>,
    /// Publish this teleop command every 50 ms of simulated time (by the poses' stamps).
    pub drive: Option<Twist>,
    last_drive: f64,
    /// Teleop commands published so far.
    pub drive_sent: u64,
    /// Simulated time (s) of the Interface's last non-zero command to the Robot, by its stamp:
    /// when the Interface received the last teleop command it forwarded (lockstep), however
    /// late the test published it.
    pub last_forwarded: Option<f64>,
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
        // Every table, not only the latest (provider_changes): a recorder's buffer.
        let tables = node.tap_subscriber(CONTRACTS).expect("contracts");
        let robot_cmds = node
            .tap_subscriber("robot/cmd_vel")
            .expect("robot commands");
        let orders = node.publisher(ORDER_CHANNEL).expect("orders");
        let teleop = node.publisher("hng/teleop").expect("teleop");
        let mut waiter = Waiter::new(WaitMode::SLEEP).expect("waiter");
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
            robot_cmds,
            orders,
            teleop,
            waiter,
            pose: None,
            track: Vec::new(),
            headings: Vec::new(),
            sim: None,
            statuses: Vec::new(),
            behaviours: None,
            offers: Vec::new(),
            interface_dropped: 0,
            contracts: Default::default(),
            provider_changes: Vec::new(),
            drive: None,
            last_drive: f64::NEG_INFINITY,
            drive_sent: 0,
            last_forwarded: None,
            seq: 1000,
            _node: node,
        }
    }

    fn drain(&mut self) {
        while let Some(s) = self.status.receive().expect("status") {
            self.sim = Some(*s);
        }
        while let Some(p) = self.truth.receive().expect("truth") {
            let t = p.header.stamp_ns as f64 * 1e-9;
            self.pose = Some((p.pose, t));
            self.track.push((t, p.pose.x, p.pose.y));
            self.headings.push((t, p.pose.theta));
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
            let module = t.module().to_string();
            let before = self.contracts.insert(module.clone(), *t);
            let stamp = t.header.stamp_ns as f64 * 1e-9;
            // Every need this table or the one before has a provider for.
            let needs: std::collections::BTreeSet<u16> = t
                .entries()
                .iter()
                .chain(before.iter().flat_map(|b| b.entries()))
                .filter(|e| e.role == ContractRole::Client as u8)
                .map(|e| e.need)
                .collect();
            for need in needs {
                let now = client_provider(&t, need);
                if before.as_ref().and_then(|b| client_provider(b, need)) != now {
                    self.provider_changes
                        .push((stamp, module.clone(), need, now.unwrap_or(0)));
                }
            }
        }
        let interface = module_id("interface");
        while let Some(c) = self.robot_cmds.receive().expect("robot commands") {
            if c.header.source == interface && (c.linear_x != 0.0 || c.angular_z != 0.0) {
                self.last_forwarded = Some(c.header.stamp_ns as f64 * 1e-9);
            }
        }
        // Paced by the true poses' stamps (the simulator's status comes every 100 ms of wall
        // time only).
        let now = self.pose_t();
        if let Some(cmd) = self.drive
            && (now - self.last_drive >= 0.05 || now < self.last_drive)
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

    /// Waits until the robot's true pose has stayed within 1 mm and 5 mrad of where it last
    /// moved to for `still_s` simulated seconds (by the poses' own time stamps); returns the
    /// time it last moved (the stamp of the pose that left that bound).
    ///
    /// The bound holds over the whole span, not between consecutive poses: at 100 poses per
    /// second, a robot creeping at 0.05 m/s moves 0.5 mm per pose, and a per-pose bound
    /// called it at rest (whether it did depended on how many poses the test's loop read).
    pub(crate) fn until_still(&mut self, what: &str, still_s: f64) -> f64 {
        const STILL_M: f64 = 0.001;
        const STILL_RAD: f64 = 0.005;
        let (p0, t0) = self.pose.expect("pose");
        let mut rest = (p0.x, p0.y, p0.theta);
        let mut since = t0;
        let mut seen = self.track.len();
        self.until(what, |w| {
            let new = w.track.iter().zip(&w.headings).skip(seen);
            for (&(t, x, y), &(_, theta)) in new {
                let turned = (theta - rest.2 + std::f64::consts::PI)
                    .rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                if dist((x, y), (rest.0, rest.1)) > STILL_M || turned.abs() > STILL_RAD {
                    since = t;
                    rest = (x, y, theta);
                }
            }
            seen = w.track.len();
            w.pose.is_some_and(|(_, t)| t - since > still_s)
        });
        since
    }

    /// The time stamp of the latest true pose, s.
    pub(crate) fn pose_t(&self) -> f64 {
        self.pose.map_or(0.0, |(_, t)| t)
    }

    /// The provider module's name of `need` of module `client` in the contract tables.
    pub(crate) fn provider_of(&self, client: &str, need: u16) -> Option<String> {
        self.module_name(client_provider(self.contracts.get(client)?, need)?)
    }

    /// The name of the module with id `id`, by its contract table.
    pub(crate) fn module_name(&self, id: u32) -> Option<String> {
        self.contracts
            .values()
            .find(|m| m.module_id == id)
            .map(|m| m.module().to_string())
    }

    pub(crate) fn collisions(&self) -> u64 {
        self.sim.map_or(0, |s| s.collisions)
    }
}

/// The id of the module that provides `need` to the module whose contract table is `table`
/// (none: no client entry for it, or one without a peer).
fn client_provider(table: &ContractTable, need: u16) -> Option<u32> {
    table
        .entries()
        .iter()
        .find(|e| e.role == ContractRole::Client as u8 && e.need == need)
        .map(|e| e.peer)
        .filter(|&peer| peer != 0)
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

/// The JSON documents, one a line, that a command wrote on stdout; it must have succeeded.
pub(crate) fn json_lines(out: &std::process::Output) -> Vec<serde_json::Value> {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON document per line"))
        .collect()
}

/// The lines a child writes on `stdout`, read by a thread of their own and handed out in order
/// (the receiver's `recv_timeout` waits for the next one with a deadline).
pub fn stdout_lines(stdout: std::process::ChildStdout) -> std::sync::mpsc::Receiver<String> {
    use std::io::BufRead;
    let (tx, lines) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    lines
}
