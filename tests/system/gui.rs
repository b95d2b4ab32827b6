//! The operator page (hng-gui, docs/operator.md) against the built-in mission: bad input and
//! wrong tokens are refused with a 4xx and publish nothing; a client that stops reading is
//! dropped without slowing anything; a real browser (headless Chromium driven by the npm
//! package playwright-core) sees the robot, sends it to a goal and stops it; and a beacon
//! clicked in the camera image is designated, with the field of view the images carry.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use hng_runtime::clock::CLOCK_CHANNEL;
use hng_runtime::msg::{
    BeaconTrack, Clock, DESIGNATION_CHANNEL, Designation, FrameId, ImageInfo, LaserScan,
    ORDER_CHANNEL, Order, OrderKind, PoseWithCovariance, TRACK_SEEN,
};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, shm};
use serde_json::Value;

/// A mission under `hng run` with its page on a free port.
struct GuiRun {
    prefix: String,
    dir: PathBuf,
    child: Child,
    addr: String,
    url: String,
    lines: mpsc::Receiver<String>,
}

/// `hng --prefix PREFIX run --run-dir DIR/run ARGS`, its stdout read line by line.
fn spawn_run(prefix: &str, dir: &Path, args: &[&str]) -> (Child, mpsc::Receiver<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_hng"))
        .env("HNG_LOG", "warn")
        .args(["--prefix", prefix, "run", "--run-dir"])
        .arg(dir.join("run"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .expect("hng run");
    let lines = crate::common::stdout_lines(child.stdout.take().expect("stdout"));
    (child, lines)
}

/// Waits for the first line that starts with `start`: that line, and the lines before it.
fn wait_line(
    lines: &mpsc::Receiver<String>,
    start: &str,
    timeout: Duration,
) -> (String, Vec<String>) {
    let mut seen = Vec::new();
    loop {
        match lines.recv_timeout(timeout) {
            Ok(l) if l.starts_with(start) => return (l, seen),
            Ok(l) => seen.push(l),
            Err(e) => panic!("no line {start:?} ({e}); output: {seen:?}"),
        }
    }
}

impl GuiRun {
    fn start(tag: &str, speed: &str, extra: &[&str]) -> GuiRun {
        let prefix = shm::unique_prefix(tag);
        let dir = std::env::temp_dir().join(format!("hng-test-{}", prefix.trim_end_matches('_')));
        std::fs::create_dir_all(&dir).expect("test dir");
        let args = [
            &[
                "--speed",
                speed,
                "--duration",
                "900",
                "--gui",
                "127.0.0.1:0",
            ],
            extra,
        ]
        .concat();
        let (child, lines) = spawn_run(&prefix, &dir, &args);
        let (said, seen) = wait_line(&lines, "operator page: ", Duration::from_secs(60));
        let url = said["operator page: ".len()..].trim().to_owned();
        assert!(
            seen.len() <= 3,
            "the address is among the first lines: {seen:?}"
        );
        let addr = url
            .trim_start_matches("http://")
            .split('/')
            .next()
            .expect("host:port")
            .to_owned();
        GuiRun {
            prefix,
            dir,
            child,
            addr,
            url,
            lines,
        }
    }

    /// One HTTP request (`Connection: close`): status and body.
    fn http(&self, method: &str, path: &str, auth: Option<&str>, body: &str) -> (u16, String) {
        let mut s = TcpStream::connect(&self.addr).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(30)))
            .expect("timeout");
        let auth = auth.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
        write!(
            s,
            "{method} {path} HTTP/1.1\r\nHost: {}\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            self.addr,
            body.len()
        )
        .expect("write");
        let mut out = String::new();
        s.read_to_string(&mut out).expect("read");
        let status = out
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .unwrap_or(0);
        let body = out.split("\r\n\r\n").nth(1).unwrap_or("").to_owned();
        (status, body)
    }

    /// A WebSocket handshake on `/ws` (optionally with `?token=`): the open stream and the
    /// status line.
    fn ws(&self, token: Option<&str>) -> (TcpStream, String) {
        self.ws_on(TcpStream::connect(&self.addr).expect("connect"), token)
    }

    /// A WebSocket client whose receive buffer is a few kilobytes: a client that stops
    /// reading then fills its buffers within seconds, whatever the frames' size and the
    /// machine's load.
    fn ws_small_buffer(&self) -> (TcpStream, String) {
        let s = TcpStream::connect(&self.addr).expect("connect");
        nix::sys::socket::setsockopt(&s, nix::sys::socket::sockopt::RcvBuf, &4096)
            .expect("SO_RCVBUF");
        self.ws_on(s, None)
    }

    fn ws_on(&self, mut s: TcpStream, token: Option<&str>) -> (TcpStream, String) {
        let q = token.map_or(String::new(), |t| format!("?token={t}"));
        write!(
            s,
            "GET /ws{q} HTTP/1.1\r\nHost: {}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
            self.addr
        )
        .expect("write");
        let mut line = String::new();
        let mut r = BufReader::new(s.try_clone().expect("clone"));
        r.read_line(&mut line).expect("status line");
        (s, line)
    }
}

impl Drop for GuiRun {
    fn drop(&mut self) {
        // The supervisor's orderly stop first.
        let _ = crate::common::terminate(&mut self.child, Duration::from_secs(20));
        let _ = self.child.kill();
        let _ = self.child.wait();
        while self.lines.try_recv().is_ok() {}
        shm::remove_prefix_files(&self.prefix);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Sends STOP until the Interface answers it (it may still be starting): the robot holds,
/// and the mission does not end under the test. Returns the answer's body.
fn hold(run: &GuiRun, token: Option<&str>) -> String {
    let deadline = Instant::now() + Duration::from_secs(90);
    loop {
        let (code, text) = run.http("POST", "/api/order", token, r#"{"kind":"stop"}"#);
        if code == 200 {
            return text;
        }
        assert!(
            code == 202 && Instant::now() < deadline,
            "no answer to STOP: {code} {text}"
        );
    }
}

/// Orders seen on the order channel within `wait`.
fn orders_seen(
    sub: &hng_runtime::Subscriber<Order>,
    waiter: &mut Waiter,
    wait: Duration,
) -> Vec<Order> {
    let end = Instant::now() + wait;
    let mut got = Vec::new();
    loop {
        while let Some(o) = sub.receive().expect("receive") {
            got.push(*o);
        }
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return got;
        }
        waiter.wait(Some(left)).expect("wait");
    }
}

#[test]
fn the_operator_page_refuses_bad_orders_and_wrong_tokens_and_publishes_nothing_for_them() {
    let _heavy = crate::common::heavy();
    let run = GuiRun::start("gui_bad", "2", &["--gui-token", "s3cret"]);
    assert!(run.url.ends_with("?token=s3cret"), "{}", run.url);
    let node = Node::new(NodeOptions::new("gui-test-orders").prefix(&run.prefix)).expect("node");
    let sub = node
        .subscriber::<Order>(ORDER_CHANNEL)
        .expect("order subscriber");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&sub).expect("attach");
    // A good order, with the token in the query as the page's address carries it, goes out
    // once, as a Stop (which also holds the robot: the mission does not end under the test).
    let stop = r#"{"kind":"stop"}"#;
    hold(&run, Some("s3cret"));
    let _ = orders_seen(&sub, &mut waiter, Duration::from_millis(200));
    let (code, text) = run.http("POST", "/api/order?token=s3cret", None, stop);
    assert_eq!(code, 200, "the Interface answers: {text}");
    let sent = orders_seen(&sub, &mut waiter, Duration::from_secs(1));
    assert_eq!(sent.len(), 1, "{sent:?}");
    assert_eq!(sent[0].kind, OrderKind::Stop as u32);
    let v: Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(v["seq"].as_u64(), Some(u64::from(sent[0].seq)), "{text}");
    assert_eq!(v["answer"]["accepted"], true, "{text}");
    // The page itself is public; everything under /api and the stream need the token.
    assert_eq!(run.http("GET", "/", None, "").0, 200);
    let (code, body) = run.http("POST", "/api/order", None, stop);
    assert_eq!(code, 401, "{body}");
    assert!(body.contains("token"), "{body}");
    let (code, body) = run.http("POST", "/api/order", Some("wrong"), stop);
    assert_eq!(code, 403, "{body}");
    let (_ws, status) = run.ws(None);
    assert!(status.contains(" 401 "), "{status}");
    let (_ws, status) = run.ws(Some("nope"));
    assert!(status.contains(" 403 "), "{status}");
    for (path, body, want, says) in [
        ("/api/order", "{not json", 400, "order"),
        ("/api/order", r#"{"kind":"fly"}"#, 400, "fly"),
        ("/api/order", r#"{"kind":"stop","speed":1}"#, 400, "speed"),
        ("/api/order", r#"{"kind":"goal","points":[]}"#, 422, "point"),
        (
            "/api/order",
            r#"{"kind":"goal","points":[{"x":1e999,"y":0}]}"#,
            400,
            "order",
        ),
        (
            "/api/order",
            r#"{"kind":"goal","points":[{"x":1e300,"y":0}]}"#,
            422,
            "points[0].x",
        ),
        ("/api/order", r#"{"kind":"reach_beacon"}"#, 422, "beacon_id"),
        ("/api/teleop", r#"{"linear_x":9}"#, 422, "linear_x"),
        ("/api/teleop", r#"{"linear_x":"NaN"}"#, 400, "teleop"),
        (
            "/api/module",
            r#"{"op":"explode","module":"slam"}"#,
            400,
            "explode",
        ),
    ] {
        let (code, text) = run.http("POST", path, Some("s3cret"), body);
        assert_eq!(code, want, "{path} {body}: {text}");
        let v: Value = serde_json::from_str(&text).unwrap_or(Value::Null);
        let msg = v["error"].as_str().unwrap_or("");
        assert!(msg.contains(says), "{path} {body}: {text}");
    }
    // An unknown module is the supervisor's to refuse: 409 with its list of modules.
    let (code, text) = run.http(
        "POST",
        "/api/module",
        Some("s3cret"),
        r#"{"op":"kill","module":"nosuch"}"#,
    );
    assert_eq!(code, 409, "{text}");
    assert!(text.contains("slam"), "{text}");
    let bad = orders_seen(&sub, &mut waiter, Duration::from_millis(500));
    assert!(bad.is_empty(), "refused requests published orders: {bad:?}");
    // What only the Interface can judge comes back as its answer: a goal far outside the map.
    let (code, text) = run.http(
        "POST",
        "/api/order",
        Some("s3cret"),
        r#"{"kind":"goal","points":[{"x":500,"y":500}]}"#,
    );
    assert_eq!(code, 200, "{text}");
    let v: Value = serde_json::from_str(&text).expect("JSON");
    assert!(v["answer"].is_object(), "{text}");
}

#[test]
fn a_client_that_stops_reading_is_dropped_and_never_slows_the_robot() {
    let _heavy = crate::common::heavy();
    let run = GuiRun::start("gui_slow", "2", &[]);
    let node = Node::new(NodeOptions::new("gui-test-slow").prefix(&run.prefix)).expect("node");
    let scans = node.subscriber::<LaserScan>("laser/scan").expect("scans");
    let clock = node.subscriber::<Clock>(CLOCK_CHANNEL).expect("clock");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&scans).expect("attach");
    // Hold the robot (the mission does not end under the test).
    hold(&run, None);
    // Scans flow before the client gets stuck (under load the laser's first scan can come
    // seconds after the page is up).
    let deadline = Instant::now() + Duration::from_secs(60);
    while scans.receive().expect("scan").is_none() {
        assert!(Instant::now() < deadline, "no scan within 60 s");
        waiter.wait(Some(Duration::from_millis(500))).expect("wait");
    }
    // A client that completes the handshake and then never reads a byte (with a small
    // receive buffer, so that its buffers fill in seconds rather than after megabytes).
    let (stuck, status) = run.ws_small_buffer();
    assert!(status.contains(" 101 "), "{status}");
    let started = Instant::now();
    let mut per_second = Vec::new();
    let mut dropped = false;
    let mut sim_start = None;
    let mut sim_end = 0;
    // The drop comes once the socket's buffers are full and a send then waits 5 s: with binary
    // images (no base64) that takes ~10-15 s on an idle machine, longer under load. The bound
    // only ends a failing run; a passing one ends at the drop.
    while started.elapsed() < Duration::from_secs(90) && !(dropped && per_second.len() >= 3) {
        let end = Instant::now() + Duration::from_secs(1);
        let mut n = 0;
        while Instant::now() < end {
            waiter
                .wait(Some(end.saturating_duration_since(Instant::now())))
                .expect("wait");
            while scans.receive().expect("scan").is_some() {
                n += 1;
            }
        }
        if let Some(c) = clock.latest().expect("clock") {
            sim_start.get_or_insert(c.sim_time_ns);
            sim_end = c.sim_time_ns;
        }
        per_second.push(n);
        let (code, text) = run.http("GET", "/api/info", None, "");
        assert_eq!(
            code, 200,
            "the server answers while a client is stuck: {text}"
        );
        let v: Value = serde_json::from_str(&text).expect("info JSON");
        dropped = v["stream"]["clients_dropped"].as_u64().unwrap_or(0) >= 1;
    }
    drop(stuck);
    assert!(
        dropped,
        "the stuck client was never dropped: scans/s {per_second:?}"
    );
    // Scans flowed every second the client was stuck, and simulated time advanced.
    assert!(
        per_second.iter().all(|n| *n > 0),
        "scans per second: {per_second:?}"
    );
    let sim_s = (sim_end - sim_start.unwrap_or(sim_end)) as f64 / 1e9;
    assert!(
        sim_s > 1.0,
        "simulated time advanced {sim_s} s in {:?}",
        started.elapsed()
    );
}

#[test]
fn a_real_browser_sees_the_robot_sends_it_to_a_goal_and_stops_it() {
    let js = hng::bench::browsers::js_dir();
    if let Some(why) = hng::bench::browsers::missing() {
        crate::common::skip(
            "a_real_browser_sees_the_robot_sends_it_to_a_goal_and_stops_it",
            &why,
        );
        return;
    }
    let _heavy = crate::common::heavy();
    let artefacts = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/gui-artefacts");
    let run = GuiRun::start("gui_browser", "2", &[]);
    let node = Node::new(NodeOptions::new("gui-test-browser").prefix(&run.prefix)).expect("node");
    let orders = node.subscriber::<Order>(ORDER_CHANNEL).expect("orders");
    let clock = node.subscriber::<Clock>(CLOCK_CHANNEL).expect("clock");
    let truth = node
        .subscriber::<PoseWithCovariance>("sim/ground_truth")
        .expect("ground truth");
    let mut waiter = Waiter::new(WaitMode::default()).expect("waiter");
    waiter.attach(&orders).expect("attach");
    waiter.attach(&truth).expect("attach");
    // Mission goal 3 of the default world: free and reachable from the start.
    let goal = (6.0, 6.5);
    let mut driver = Command::new("node")
        .arg(js.join("gui.mjs"))
        .arg(&run.url)
        .arg(&artefacts)
        .args([goal.0.to_string(), goal.1.to_string(), "240000".into()])
        .current_dir(&js)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node gui.mjs");
    let (tx, events) = mpsc::channel::<Value>();
    let out = driver.stdout.take().expect("stdout");
    // The driver's stderr, kept for the failure report (read on a thread so a full pipe
    // never blocks it).
    let stderr = {
        let mut err = driver.stderr.take().expect("stderr");
        std::thread::spawn(move || {
            let mut s = String::new();
            let _ = std::io::Read::read_to_string(&mut err, &mut s);
            s
        })
    };
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            let v = serde_json::from_str(&l).unwrap_or(Value::String(l));
            if tx.send(v).is_err() {
                break;
            }
        }
    });
    let mut log = Vec::new();
    let mut stop_at_sim: Option<u64> = None;
    let mut goal_true_error = None;
    let mut stopped_after: Option<f64> = None;
    let mut track: Vec<(u64, f64, f64)> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(400);
    let mut done = false;
    while Instant::now() < deadline && !done {
        waiter.wait(Some(Duration::from_millis(20))).expect("wait");
        let sim_now = clock.latest().expect("clock").map(|c| c.sim_time_ns);
        while let Some(o) = orders.receive().expect("order") {
            if o.kind == OrderKind::Stop as u32 && stop_at_sim.is_none() {
                stop_at_sim = sim_now.or_else(|| track.last().map(|t| t.0));
            }
        }
        while let Some(t) = truth.receive().expect("truth") {
            track.push((t.header.stamp_ns, t.pose.x, t.pose.y));
        }
        while let Ok(e) = events.try_recv() {
            if e["event"] == "goal_reached_on_page"
                && let Some(&(_, x, y)) = track.last()
            {
                goal_true_error = Some(((x - goal.0).powi(2) + (y - goal.1).powi(2)).sqrt());
            }
            if e["event"] == "done" || e["event"] == "error" {
                done = true;
            }
            log.push(e);
        }
        if let Some(t0) = stop_at_sim
            && stopped_after.is_none()
        {
            // Stopped: the true pose moves less than 2 mm over 0.1 s of simulated time.
            let after: Vec<_> = track.iter().filter(|t| t.0 >= t0).collect();
            for (i, a) in after.iter().enumerate() {
                if let Some(b) = after[i..].iter().find(|b| b.0 >= a.0 + 100_000_000) {
                    if ((b.1 - a.1).powi(2) + (b.2 - a.2).powi(2)).sqrt() < 0.002 {
                        stopped_after = Some((a.0 - t0) as f64 / 1e9);
                        break;
                    }
                } else {
                    break;
                }
            }
        }
    }
    if !done {
        // The deadline passed: the driver is stopped, and its report says so.
        let _ = driver.kill();
    }
    let status = driver.wait().expect("driver");
    let stderr = stderr.join().unwrap_or_default();
    let text = format!("{log:#?}");
    assert!(
        status.success() && done,
        "the browser driver failed ({status}{}): {text}\nits stderr:\n{stderr}",
        if done {
            ""
        } else {
            ", no end within the test's deadline"
        }
    );
    assert!(log.iter().any(|e| e["event"] == "live"), "{text}");
    let labels = log
        .iter()
        .find(|e| e["event"] == "labels")
        .expect("contract graph labels");
    eprintln!("gui browser test: contract graph {labels}");
    assert_eq!(
        labels["overlaps"].as_array().map(Vec::len),
        Some(0),
        "contract graph labels overlap: {labels}"
    );
    let clicked = log
        .iter()
        .find(|e| e["event"] == "goal_clicked")
        .expect("goal clicked");
    assert_eq!(
        clicked["answer"]["status"], 200,
        "the Interface answered: {clicked}"
    );
    assert_eq!(
        clicked["answer"]["body"]["answer"]["accepted"], true,
        "{clicked}"
    );
    // Planning's whole path was drawn, and it leads to the clicked goal.
    let drawn = log
        .iter()
        .find(|e| e["event"] == "path_drawn")
        .expect("path drawn");
    let points = drawn["path"]["points"].as_array().expect("points");
    let last = points.last().expect("a point");
    let (lx, ly) = (last[0].as_f64().expect("x"), last[1].as_f64().expect("y"));
    assert!(
        points.len() >= 2 && ((lx - goal.0).powi(2) + (ly - goal.1).powi(2)).sqrt() < 0.3,
        "the drawn path ends at the goal: {drawn}"
    );
    let err = goal_true_error.expect("goal reached on the page");
    assert!(
        err < 0.5,
        "true distance to the goal when the page showed it reached: {err} m"
    );
    let stopped = stopped_after.expect("the robot stopped after STOP");
    eprintln!(
        "gui browser test: goal true error {err:.3} m, stopped {stopped:.3} s (simulated) after STOP"
    );
    assert!(
        stopped <= 0.3,
        "stopped {stopped} s of simulated time after STOP: {text}"
    );
    assert!(artefacts.join("gui-stop.png").exists());
}

/// The column (fraction of the image's width) where a pinhole camera of horizontal field of
/// view `hfov` sees `bearing` (counter-clockwise positive): the test's own arithmetic, not
/// the page's.
fn column_of(bearing: f64, hfov: f64) -> f64 {
    let focal_in_widths = 0.5 / (hfov / 2.0).tan();
    0.5 - focal_in_widths * bearing.tan()
}

#[test]
fn a_beacon_clicked_in_the_camera_image_is_designated_with_the_cameras_field_of_view() {
    if let Some(why) = hng::bench::browsers::missing() {
        crate::common::skip(
            "a_beacon_clicked_in_the_camera_image_is_designated_with_the_cameras_field_of_view",
            &why,
        );
        return;
    }
    let js = hng::bench::browsers::js_dir();
    let artefacts = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/gui-artefacts");
    let prefix = shm::unique_prefix("gui_designate");
    // No mission: this test is the camera and a tracker. The images say their field of view
    // is 1.0 rad; two beacons are tracked 0.1 rad apart, so a page that assumed another field
    // of view (the simulator's default 1.2 rad) would designate the wrong one.
    let hfov = 1.0;
    let (hit, other, miss) = (0.30, 0.40, -0.40);
    let server =
        hng::bench::gui::serve_page(&prefix, hng_gui::Channels::default()).expect("page server");
    let node = Node::new(NodeOptions::new("gui-test-camera").prefix(&prefix)).expect("node");
    let designations = node
        .subscriber::<Designation>(DESIGNATION_CHANNEL)
        .expect("designations");
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let feeder = {
        let (prefix, stop) = (prefix.clone(), std::sync::Arc::clone(&stop));
        std::thread::spawn(move || {
            let node =
                Node::new(NodeOptions::new("gui-test-tracker").prefix(&prefix)).expect("node");
            let (w, h) = (320u32, 240u32);
            let images = node
                .slice_publisher::<ImageInfo>("camera/image", (w * h * 3) as usize)
                .expect("images");
            let tracks = node
                .publisher::<BeaconTrack>("tracker_colour/track")
                .expect("tracks");
            let pixels: Vec<u8> = (0..w * h * 3).map(|i| (i % 251) as u8).collect();
            let info = ImageInfo {
                width: w,
                height: h,
                step: w * 3,
                encoding: FrameId::new("rgb8").expect("encoding"),
                hfov,
                ..Default::default()
            };
            while !stop.load(std::sync::atomic::Ordering::Acquire) {
                images.publish_copy(info, &pixels).expect("image");
                for (id, bearing) in [(4, hit), (7, other)] {
                    tracks
                        .publish(BeaconTrack {
                            beacon_id: id,
                            state: TRACK_SEEN,
                            bearing,
                            range: 3.0,
                            quality: 0.8,
                            ..Default::default()
                        })
                        .expect("track");
                }
                // A camera's pace: one image and its tracks every 100 ms.
                std::thread::sleep(Duration::from_millis(100));
            }
        })
    };
    let url = format!("http://{}/", server.local_addr());
    let out = Command::new("node")
        .arg(js.join("designate.mjs"))
        .arg(&url)
        .arg(&artefacts)
        .arg(column_of(hit, hfov).to_string())
        .arg(column_of(miss, hfov).to_string())
        .current_dir(&js)
        .stderr(Stdio::piped())
        .output()
        .expect("node designate.mjs");
    stop.store(true, std::sync::atomic::Ordering::Release);
    feeder.join().expect("feeder");
    let log: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or(Value::String(l.to_owned())))
        .collect();
    let mut got = Vec::new();
    while let Some(d) = designations.receive().expect("designation") {
        got.push((d.beacon_id, d.active));
    }
    server.stop();
    drop(designations);
    drop(node);
    shm::remove_prefix_files(&prefix);
    let text = format!("{log:#?}");
    assert!(
        out.status.success() && log.iter().any(|e| e["event"] == "done"),
        "the browser driver failed ({}): {text}\nits stderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let tracked = log
        .iter()
        .find(|e| e["event"] == "tracked")
        .expect("tracked");
    assert_eq!(tracked["hfov"].as_f64(), Some(hfov), "{tracked}");
    let hit_answer = log.iter().find(|e| e["event"] == "hit").expect("hit");
    assert_eq!(hit_answer["answer"]["status"], 200, "{hit_answer}");
    assert_eq!(hit_answer["answer"]["body"]["beacon_id"], 4, "{hit_answer}");
    let missed = log.iter().find(|e| e["event"] == "miss").expect("miss");
    assert_eq!(
        missed["answers"], 1,
        "a click beside every beacon sent nothing: {missed}"
    );
    // On the data plane: beacon 4 designated, once; the click beside them published nothing.
    assert_eq!(got, vec![(4, 1)], "designations published: {text}");
    assert!(artefacts.join("gui-camera.png").exists());
}

#[test]
fn a_busy_page_address_is_reported_and_the_run_goes_on_without_the_page() {
    // Something else holds the port: the run says so among its first lines and goes on.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
    let addr = taken.local_addr().expect("address");
    let prefix = shm::unique_prefix("gui_busy");
    let dir = std::env::temp_dir().join(format!("hng-test-{}", prefix.trim_end_matches('_')));
    std::fs::create_dir_all(&dir).expect("test dir");
    let file = dir.join("launch.toml");
    std::fs::write(
        &file,
        "system = \"busy\"\n[[module]]\nname = \"probe\"\ncommand = [\"hng\", \"module\", \"heartbeat-probe\"]\n",
    )
    .expect("launch file");
    let addr = addr.to_string();
    let file = file.to_str().expect("path");
    let (mut child, lines) = spawn_run(&prefix, &dir, &["--no-rm", "--gui", &addr, file]);
    let (said, seen) = wait_line(&lines, "operator page:", Duration::from_secs(30));
    // The run goes on: its module runs (the supervisor's status, as `hng ps --json` reads it).
    let deadline = Instant::now() + Duration::from_secs(30);
    let running = loop {
        let ps = Command::new(env!("CARGO_BIN_EXE_hng"))
            .args(["--prefix", &prefix, "ps", "--json"])
            .output()
            .expect("hng ps");
        let doc: Value = serde_json::from_slice(&ps.stdout).unwrap_or(Value::Null);
        let state = doc["modules"]
            .as_array()
            .and_then(|ms| ms.iter().find(|m| m["name"] == "probe"))
            .map(|m| m["state"].clone());
        if state.as_ref().is_some_and(|s| s == "running") || Instant::now() > deadline {
            break state;
        }
        // Waiting for the module's start: the supervisor's status, polled.
        std::thread::sleep(Duration::from_millis(100));
    };
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
    let status = child.wait().expect("wait");
    drop(taken);
    let files = shm::prefix_files(&prefix);
    shm::remove_prefix_files(&prefix);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        said.starts_with("operator page: not served: cannot listen on")
            && said.contains(&addr.to_string())
            && said.contains("the run goes on without it"),
        "{said}"
    );
    assert!(
        seen.len() <= 3,
        "among the first lines: {seen:?} then {said}"
    );
    assert_eq!(running, Some(Value::from("running")), "the run went on");
    assert!(status.success(), "an orderly stop: {status:?}");
    assert!(files.is_empty(), "left {files:?}");
}
