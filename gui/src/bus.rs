//! The bus thread: the operator station's node on the data plane. It subscribes to the
//! channels the page shows, keeps only the latest message of each, and encodes each topic
//! at a bounded rate ([`min_interval`]) into the [`Hub`], and only while a page is connected.
//! It never waits on a client.

use std::borrow::Cow;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use hng_runtime::clock::CLOCK_CHANNEL;
use hng_runtime::msg::{
    BEHAVIOURS_CHANNEL, BeaconObservation, BeaconTrack, Behaviours, Clock, DESIGNATION_CHANNEL,
    Designation, Goal, GridInfo, ImageInfo, LaserScan, Message, ORDER_STATUS_CHANNEL, Odometry,
    OrderKind, OrderStatus, PLANNED_PATH_CHANNEL, PathInfo, PoseWithCovariance, Waypoint,
};
use hng_runtime::system::{
    CONTRACTS, ContractRole, ContractTable, EventKind, JsonInfo, ModuleEvent, RM_STATUS,
    SUPERVISOR_EVENTS, SUPERVISOR_STATUS,
};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, NodeOptions, SliceSubscriber, Subscriber};
use serde_json::{Value, json};

use crate::hub::{Hub, TOPICS};

mod tracks;
use tracks::{Tracks, tracks};

/// The channels the page reads (configurable for other systems).
#[derive(Debug, Clone)]
pub struct Channels {
    /// Lidar scans.
    pub scan: String,
    /// Localization outputs; the one contracted to Planning is shown as the robot's pose.
    pub poses: Vec<String>,
    /// The simulator's ground truth (shown faintly, when it exists).
    pub truth: String,
    /// Odometry (speed shown).
    pub odom: String,
    /// The surveyed map.
    pub map: String,
    /// SLAM's map.
    pub slam_map: String,
    /// Planning's carrot.
    pub waypoint: String,
    /// Planning's whole planned path (`PathInfo`).
    pub path: String,
    /// The Manager's current goal.
    pub goal: String,
    /// The Manager's mission (JSON).
    pub mission: String,
    /// Beacons seen by a beacon camera (`BeaconObservation`; empty: none, the default: the
    /// robot's camera gives images, and its beacons are the trackers' tracks).
    pub beacons: String,
    /// The trackers' `BeaconTrack` channels ("Track beacon" offers); each beacon tracked is
    /// shown with the tracker that tracks it and the clients contracted to that tracker.
    pub tracks: Vec<String>,
    /// Camera images.
    pub image: String,
}

impl Default for Channels {
    fn default() -> Self {
        Channels {
            scan: "laser/scan".into(),
            poses: vec!["slam/pose".into(), "gps/pose".into()],
            truth: "sim/ground_truth".into(),
            odom: "robot/odom".into(),
            map: "maps/map".into(),
            slam_map: "slam/map".into(),
            waypoint: "planning/waypoint".into(),
            path: PLANNED_PATH_CHANNEL.into(),
            goal: "manager/goal".into(),
            mission: "manager/mission".into(),
            beacons: String::new(),
            tracks: vec![
                "tracker_colour/track".into(),
                "tracker_histogram/track".into(),
            ],
            image: "camera/image".into(),
        }
    }
}

/// Least time between two frames of a topic (the stream's bounded rate).
pub fn min_interval(topic: &str) -> Duration {
    Duration::from_millis(match topic {
        "order_status" | "events" | "designation" => 0,
        // About 10 Hz, the lidar's own rate (a page drawing at 20 Hz cost a browser about
        // twice the CPU); 90 ms, so that a 10 Hz lidar's scan is never held back by jitter.
        "pose" | "truth" | "odom" | "scan" => 90,
        "clock" | "waypoint" | "path" | "goal" | "beacons" | "tracks" | "behaviours" => 100,
        "image" => 200,
        "status" | "mission" => 250,
        "contracts" => 500,
        _ => 1000,
    })
}

/// When a topic's next frame may go: a generic cell rate algorithm with a burst of one
/// interval. Each frame sent moves the time to `max(it + interval, now)`, so the stream keeps
/// to one frame per [`min_interval`] in the long run, yet a source at or below that rate is
/// never held back by its jitter. With a plain "interval since the last frame" one late frame
/// delayed every later one (a backlog of up to 75 ms at 10 Hz, shrinking by 10 ms a frame).
#[derive(Debug, Clone, Copy, Default)]
struct Pace {
    allowed_from: Option<Instant>,
}

impl Pace {
    /// When the next frame may go (`now` when nothing was sent yet).
    fn due(self, now: Instant) -> Instant {
        self.allowed_from.unwrap_or(now)
    }

    /// A frame of `topic` went at `now`.
    fn sent(&mut self, now: Instant, topic: &str) {
        self.allowed_from = Some(
            self.allowed_from
                .map_or(now, |a| (a + min_interval(topic)).max(now)),
        );
    }
}

/// Most events kept for the timeline.
const EVENTS_KEPT: usize = 200;

/// Contract tables older than this belong to a dead module.
const TABLE_TTL: Duration = Duration::from_secs(3);

enum Latest {
    None,
    Json(Value),
}

struct Fixed<T: Message> {
    sub: Subscriber<T>,
    latest: Option<T>,
}

impl<T: Message> Fixed<T> {
    fn poll(&mut self) -> bool {
        let mut got = false;
        loop {
            match self.sub.receive() {
                Ok(Some(s)) => {
                    self.latest = Some(*s);
                    got = true;
                }
                Ok(None) => return got,
                Err(e) => {
                    tracing::debug!("{}: {e}", self.sub.channel());
                    return got;
                }
            }
        }
    }
}

struct Sliced<H: hng_runtime::msg::SliceMessage> {
    sub: SliceSubscriber<H>,
    latest: Option<(H, Vec<H::Elem>)>,
}

impl<H: hng_runtime::msg::SliceMessage> Sliced<H> {
    fn poll(&mut self) -> bool {
        match self.sub.latest() {
            Ok(Some(s)) => {
                self.latest = Some((*s.header(), s.data().to_vec()));
                true
            }
            Ok(None) => false,
            Err(e) => {
                tracing::debug!("{}: {e}", self.sub.channel());
                false
            }
        }
    }
}

/// A subscriber on `ch` that `w` watches, or `None` (said once) when it cannot be opened.
fn watched<K: hng_runtime::channel::Kind>(
    w: &mut Waiter,
    ch: &str,
    opened: Result<hng_runtime::channel::Receiver<K>, hng_runtime::Error>,
) -> Option<hng_runtime::channel::Receiver<K>> {
    match opened {
        Ok(sub) => {
            if let Err(e) = w.attach(&sub) {
                tracing::warn!("operator page: cannot wait on {ch}: {e}");
            }
            Some(sub)
        }
        Err(e) => {
            tracing::warn!("operator page: not showing {ch}: {e}");
            None
        }
    }
}

fn fixed<T: Message>(node: &Node, w: &mut Waiter, ch: &str) -> Option<Fixed<T>> {
    watched(w, ch, node.subscriber::<T>(ch)).map(|sub| Fixed { sub, latest: None })
}

fn sliced<H: hng_runtime::msg::SliceMessage>(
    node: &Node,
    w: &mut Waiter,
    ch: &str,
) -> Option<Sliced<H>> {
    watched(w, ch, node.slice_subscriber::<H>(ch)).map(|sub| Sliced { sub, latest: None })
}

struct Sources {
    clock: Option<Fixed<Clock>>,
    scan: Option<Fixed<LaserScan>>,
    poses: Vec<(String, Fixed<PoseWithCovariance>)>,
    truth: Option<Fixed<PoseWithCovariance>>,
    odom: Option<Fixed<Odometry>>,
    map: Option<Sliced<GridInfo>>,
    slam_map: Option<Sliced<GridInfo>>,
    waypoint: Option<Fixed<Waypoint>>,
    path: Option<Sliced<PathInfo>>,
    goal: Option<Fixed<Goal>>,
    mission: Option<Sliced<JsonInfo>>,
    beacons: Option<Fixed<BeaconObservation>>,
    tracks: Tracks,
    image: Option<Sliced<ImageInfo>>,
    order_status: Option<Fixed<OrderStatus>>,
    behaviours: Option<Fixed<Behaviours>>,
    designation: Option<Fixed<Designation>>,
    supervisor: Option<Sliced<JsonInfo>>,
    rm: Option<Sliced<JsonInfo>>,
    events: Option<Fixed<ModuleEvent>>,
    tables: Option<Fixed<ContractTable>>,
}

/// What the bus thread keeps beside the latest messages.
struct State {
    hub: Arc<Hub>,
    dirty: Vec<bool>,
    /// Per topic, when its next frame may go.
    pace: Vec<Pace>,
    tables: BTreeMap<u32, (Instant, ContractTable)>,
    /// (client, service) -> provider, to see switches.
    holders: BTreeMap<(String, String), String>,
    events: VecDeque<Value>,
    sim_ns: u64,
    supervisor: Latest,
    rm: Latest,
}

impl State {
    fn mark(&mut self, topic: &str) {
        if let Some(i) = Hub::index(topic) {
            self.dirty[i] = true;
        }
    }

    fn event(&mut self, kind: &str, text: String) {
        let e = json!({
            "wall_ms": std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_millis() as u64)
                .unwrap_or(0),
            "sim_s": self.sim_ns as f64 / 1e9,
            "kind": kind,
            "text": text,
        });
        if self.events.len() == EVENTS_KEPT {
            self.events.pop_front();
        }
        self.events.push_back(e);
        self.mark("events");
    }
}

/// The bus thread's options.
#[derive(Debug, Clone)]
pub struct BusOptions {
    /// The system's prefix.
    pub prefix: String,
    /// Channels to read.
    pub channels: Channels,
}

/// A node of the operator page's process in the system under `prefix`, named `NAME-PID`.
pub(crate) fn node(prefix: &str, name: &str) -> Result<Node, crate::Error> {
    Ok(Node::new(
        NodeOptions::new(&format!("{name}-{}", std::process::id())).prefix(prefix),
    )?)
}

/// Runs until `stop` is set. Errors only when the node cannot be created.
pub fn run(opts: &BusOptions, hub: &Arc<Hub>, stop: &AtomicBool) -> Result<(), crate::Error> {
    let node = node(&opts.prefix, "hng-gui")?;
    let mut w = Waiter::new(WaitMode::SLEEP)?;
    let c = &opts.channels;
    let mut src = Sources {
        clock: fixed(&node, &mut w, CLOCK_CHANNEL),
        scan: fixed(&node, &mut w, &c.scan),
        poses: c
            .poses
            .iter()
            .filter_map(|p| fixed(&node, &mut w, p).map(|f| (p.clone(), f)))
            .collect(),
        truth: fixed(&node, &mut w, &c.truth),
        odom: fixed(&node, &mut w, &c.odom),
        map: sliced(&node, &mut w, &c.map),
        slam_map: sliced(&node, &mut w, &c.slam_map),
        waypoint: fixed(&node, &mut w, &c.waypoint),
        path: sliced(&node, &mut w, &c.path),
        goal: fixed(&node, &mut w, &c.goal),
        mission: sliced(&node, &mut w, &c.mission),
        beacons: (!c.beacons.is_empty())
            .then(|| fixed(&node, &mut w, &c.beacons))
            .flatten(),
        tracks: Tracks::new(
            c.tracks
                .iter()
                .filter_map(|ch| {
                    let f: Fixed<BeaconTrack> = fixed(&node, &mut w, ch)?;
                    Some((ch.clone(), f.sub))
                })
                .collect(),
        ),
        // Opened while a browser watches (below).
        image: None,
        order_status: fixed(&node, &mut w, ORDER_STATUS_CHANNEL),
        behaviours: fixed(&node, &mut w, BEHAVIOURS_CHANNEL),
        designation: fixed(&node, &mut w, DESIGNATION_CHANNEL),
        supervisor: sliced(&node, &mut w, SUPERVISOR_STATUS),
        rm: sliced(&node, &mut w, RM_STATUS),
        events: fixed(&node, &mut w, SUPERVISOR_EVENTS),
        tables: fixed(&node, &mut w, CONTRACTS),
    };
    let mut st = State {
        hub: Arc::clone(hub),
        dirty: vec![false; TOPICS.len()],
        pace: vec![Pace::default(); TOPICS.len()],
        tables: BTreeMap::new(),
        holders: BTreeMap::new(),
        events: VecDeque::new(),
        sim_ns: 0,
        supervisor: Latest::None,
        rm: Latest::None,
    };
    let mut had_clients = 0;
    while !stop.load(Ordering::Acquire) {
        poll_all(&mut src, &mut st);
        let clients = hub.clients();
        // The camera image is read only while a browser watches: a reader of `camera/image`
        // makes the Camera relay, and the simulator render, every frame.
        if clients > 0 && had_clients == 0 {
            src.image = sliced(&node, &mut w, &c.image);
        } else if clients == 0
            && let Some(i) = src.image.take()
        {
            let _ = w.detach(i.sub.id());
        }
        if clients > had_clients {
            // A newcomer gets every topic held.
            st.dirty.iter_mut().for_each(|d| *d = true);
            st.pace.iter_mut().for_each(|p| *p = Pace::default());
        }
        had_clients = clients;
        let now = Instant::now();
        let mut next: Option<Instant> = None;
        if clients > 0 {
            for (i, topic) in TOPICS.iter().enumerate() {
                if !st.dirty[i] {
                    continue;
                }
                let due = st.pace[i].due(now);
                if due <= now {
                    st.dirty[i] = false;
                    let put = if let Some((v, bytes, stamp)) = encode_bulk(topic, &src) {
                        hub.put_binary(topic, &v, &bytes, stamp);
                        true
                    } else if let Some((v, stamp)) = encode(topic, &src, &st) {
                        hub.put_json(topic, &v, stamp);
                        true
                    } else {
                        false
                    };
                    if put {
                        st.pace[i].sent(now, topic);
                    }
                } else {
                    next = Some(next.map_or(due, |n: Instant| n.min(due)));
                }
            }
        }
        // Woken by data; the timeout bounds a pending frame's delay and the stop's.
        let limit = Duration::from_millis(if clients > 0 { 100 } else { 250 });
        let timeout = next.map_or(limit, |n| n.saturating_duration_since(now).min(limit));
        node.update_connections();
        w.wait(Some(timeout))?;
    }
    Ok(())
}

fn poll_all(src: &mut Sources, st: &mut State) {
    macro_rules! take {
        ($field:ident, $topic:expr) => {
            if let Some(s) = src.$field.as_mut()
                && s.poll()
            {
                st.mark($topic);
            }
        };
    }
    if let Some(c) = src.clock.as_mut()
        && c.poll()
    {
        if let Some(l) = &c.latest {
            st.sim_ns = l.sim_time_ns;
        }
        st.mark("clock");
    }
    take!(scan, "scan");
    take!(truth, "truth");
    take!(odom, "odom");
    take!(map, "map");
    take!(slam_map, "slam_map");
    take!(waypoint, "waypoint");
    take!(path, "path");
    take!(goal, "goal");
    take!(mission, "mission");
    take!(beacons, "beacons");
    if src.tracks.poll() {
        st.mark("tracks");
    }
    take!(image, "image");
    take!(behaviours, "behaviours");
    take!(designation, "designation");
    for (_, p) in &mut src.poses {
        if p.poll() {
            st.mark("pose");
        }
    }
    if let Some(s) = src.order_status.as_mut()
        && s.poll()
    {
        st.mark("order_status");
        if let Some(o) = &s.latest {
            if let Ok(v) = serde_json::to_value(o) {
                st.hub.answer(o.seq, v);
            }
            let text = format!(
                "order {} {}{}",
                o.seq,
                if o.accepted != 0 {
                    "accepted"
                } else {
                    "refused"
                },
                if o.reason().is_empty() {
                    String::new()
                } else {
                    format!(": {}", o.reason())
                }
            );
            st.event("order", text);
        }
    }
    for (slot, topic) in [(&mut src.supervisor, 0), (&mut src.rm, 1)] {
        if let Some(s) = slot.as_mut()
            && s.poll()
            && let Some((_, bytes)) = &s.latest
            && let Some(v) = status_value(topic, bytes)
        {
            if topic == 0 {
                st.supervisor = Latest::Json(v);
            } else {
                st.rm = Latest::Json(v);
            }
            st.mark("status");
        }
    }
    if let Some(e) = src.events.as_mut() {
        while let Ok(Some(ev)) = e.sub.receive() {
            let what = match ev.kind() {
                Some(EventKind::Started) => "started",
                Some(EventKind::Died) => "died",
                Some(EventKind::Deactivated) => "deactivated",
                Some(EventKind::Stopped) => "stopped",
                None => continue,
            };
            let text = if ev.pid != 0 {
                format!("{} {what} (pid {})", ev.module(), ev.pid)
            } else {
                format!("{} {what}", ev.module())
            };
            st.event(what, text);
        }
    }
    if let Some(t) = src.tables.as_mut() {
        let now = Instant::now();
        let mut got = false;
        while let Ok(Some(table)) = t.sub.receive() {
            st.tables.insert(table.module_id, (now, *table));
            got = true;
        }
        let before = st.tables.len();
        st.tables
            .retain(|_, (at, _)| now.saturating_duration_since(*at) < TABLE_TTL);
        if got || st.tables.len() != before {
            contract_switches(st);
            st.mark("contracts");
        }
    }
}

/// Records a switch when a (client, service) pair changes provider.
fn contract_switches(st: &mut State) {
    let name = |tables: &BTreeMap<u32, (Instant, ContractTable)>, id: u32| {
        tables
            .get(&id)
            .map(|(_, t)| t.module().to_owned())
            .unwrap_or_else(|| format!("m{id}"))
    };
    let mut now = BTreeMap::new();
    for (_, t) in st.tables.values() {
        for e in t
            .entries()
            .iter()
            .filter(|e| e.role() == Some(ContractRole::Client))
        {
            now.insert(
                (t.module().to_owned(), e.service().to_owned()),
                name(&st.tables, e.peer),
            );
        }
    }
    let mut switches = Vec::new();
    for (k, p) in &now {
        if let Some(old) = st.holders.get(k)
            && old != p
        {
            switches.push(format!("{} {}: {old} -> {p}", k.0, k.1));
        }
    }
    st.holders = now;
    for s in switches {
        st.event("switch", format!("contract switch: {s}"));
    }
}

/// A status document as the page gets it: the supervisor's (`topic` 0) through its typed
/// schema ([`hng_runtime::system::status::StatusDoc`]: a document of another shape is
/// dropped), the resource manager's (1) as it is.
fn status_value(topic: u8, bytes: &[u8]) -> Option<Value> {
    if topic == 0 {
        let doc: hng_runtime::system::status::StatusDoc = serde_json::from_slice(bytes)
            .map_err(|e| tracing::debug!("a supervisor status that does not parse: {e}"))
            .ok()?;
        serde_json::to_value(doc).ok()
    } else {
        serde_json::from_slice(bytes).ok()
    }
}

fn grid(g: &Option<Sliced<GridInfo>>) -> Option<(Value, Cow<'_, [u8]>, u64)> {
    let (info, cells) = g.as_ref()?.latest.as_ref()?;
    Some((
        json!({
            "resolution": info.resolution,
            "width": info.width,
            "height": info.height,
            "origin": info.origin,
            "stamp_ns": info.header.stamp_ns,
        }),
        // Occupancy as bytes: -1 (unknown) is 255.
        Cow::Owned(cells.iter().map(|c| *c as u8).collect()),
        info.header.stamp_ns,
    ))
}

/// The topics sent as binary frames (a JSON description, then the raw bytes: no base64):
/// the grids and the camera image.
fn encode_bulk<'a>(topic: &str, src: &'a Sources) -> Option<(Value, Cow<'a, [u8]>, u64)> {
    match topic {
        "map" => grid(&src.map),
        "slam_map" => grid(&src.slam_map),
        "image" => {
            let (info, data) = src.image.as_ref()?.latest.as_ref()?;
            Some((
                json!({
                    "width": info.width, "height": info.height, "step": info.step,
                    "encoding": info.encoding, "stamp_ns": info.header.stamp_ns,
                    "hfov": (info.hfov.is_finite() && info.hfov > 0.0).then_some(info.hfov),
                }),
                Cow::Borrowed(data.as_slice()),
                info.header.stamp_ns,
            ))
        }
        _ => None,
    }
}

/// The channel of the Localization provider Planning (else Servo) holds a contract with.
fn contracted_pose(st: &State) -> Option<String> {
    for client in ["planning", "servo"] {
        for (_, t) in st.tables.values() {
            if t.module() != client {
                continue;
            }
            if let Some(e) = t.entries().iter().find(|e| {
                e.role() == Some(ContractRole::Client)
                    && e.service() == "Localization"
                    && !e.channel().is_empty()
            }) {
                return Some(e.channel().to_owned());
            }
        }
    }
    None
}

fn contracts(st: &State) -> Value {
    let name = |id: u32| {
        st.tables
            .get(&id)
            .map(|(_, t)| t.module().to_owned())
            .unwrap_or_else(|| format!("m{id}"))
    };
    let modules: Vec<Value> = st
        .tables
        .values()
        .map(|(_, t)| {
            json!({
                "name": t.module(),
                "active": t.active != 0,
                "priority": if t.active != 0 { hng_runtime::contract::dotted(t.priority()) } else { "-".into() },
                "value": t.value.is_finite().then_some(t.value),
                "root": t.active != 0 && t.priority().is_empty(),
            })
        })
        .collect();
    let mut contracts = Vec::new();
    for (_, t) in st.tables.values() {
        for e in t
            .entries()
            .iter()
            .filter(|e| e.role() == Some(ContractRole::Client))
        {
            contracts.push(json!({
                "client": t.module(),
                "provider": name(e.peer),
                "service": e.service(),
                "priority": hng_runtime::contract::dotted(e.priority()),
                "value": e.value,
                "channel": e.channel(),
            }));
        }
    }
    json!({ "modules": modules, "contracts": contracts })
}

fn encode(topic: &str, src: &Sources, st: &State) -> Option<(Value, u64)> {
    fn latest<T: Message>(f: &Option<Fixed<T>>) -> Option<&T> {
        f.as_ref()?.latest.as_ref()
    }
    fn plain<T: Message>(f: &Option<Fixed<T>>) -> Option<(Value, u64)> {
        let m = latest(f)?;
        Some((serde_json::to_value(m).ok()?, m.header().stamp_ns))
    }
    match topic {
        "clock" => {
            let c = latest(&src.clock)?;
            Some((json!({ "sim_s": c.sim_time_ns as f64 / 1e9 }), 0))
        }
        "scan" => {
            let s = latest(&src.scan)?;
            let ranges: Vec<Value> = s
                .ranges()
                .iter()
                .map(|r| {
                    if r.is_finite() && *r >= s.range_min && *r <= s.range_max {
                        json!((r * 1000.0).round() / 1000.0)
                    } else {
                        Value::Null
                    }
                })
                .collect();
            Some((
                json!({
                    "stamp_ns": s.header.stamp_ns,
                    "frame": s.header.frame_id,
                    "angle_min": s.angle_min,
                    "angle_increment": s.angle_increment,
                    "ranges": ranges,
                }),
                s.header.stamp_ns,
            ))
        }
        "pose" => {
            let chosen = contracted_pose(st);
            let (ch, f) = src
                .poses
                .iter()
                .find(|(c, f)| Some(c) == chosen.as_ref() && f.latest.is_some())
                .or_else(|| src.poses.iter().find(|(_, f)| f.latest.is_some()))?;
            let p = f.latest.as_ref()?;
            Some((
                json!({ "channel": ch, "contracted": chosen.as_ref() == Some(ch),
                        "pose": p.pose, "covariance": p.covariance }),
                p.header.stamp_ns,
            ))
        }
        "truth" => plain(&src.truth),
        "odom" => {
            let o = latest(&src.odom)?;
            Some((
                json!({ "vx": o.twist.vx, "wz": o.twist.wz }),
                o.header.stamp_ns,
            ))
        }
        "waypoint" => plain(&src.waypoint),
        "path" => {
            let (info, poses) = src.path.as_ref()?.latest.as_ref()?;
            let points: Vec<[f64; 2]> = poses.iter().map(|p| [p.x, p.y]).collect();
            Some((
                json!({ "goal_id": info.goal_id, "length_m": info.length_m, "points": points }),
                info.header.stamp_ns,
            ))
        }
        "goal" => plain(&src.goal),
        "beacons" => plain(&src.beacons),
        "tracks" => Some((tracks(&src.tracks, st), 0)),
        "behaviours" => plain(&src.behaviours),
        "designation" => plain(&src.designation),
        "order_status" => {
            let (mut v, stamp) = plain(&src.order_status)?;
            if let Some(o) = latest(&src.order_status)
                && let Some(obj) = v.as_object_mut()
            {
                obj.insert(
                    "in_force".into(),
                    json!(
                        (o.active != 0)
                            .then(|| OrderKind::from_u32(o.in_force).map(OrderKind::name))
                            .flatten()
                    ),
                );
            }
            Some((v, stamp))
        }
        "mission" => {
            let (_, bytes) = src.mission.as_ref()?.latest.as_ref()?;
            Some((serde_json::from_slice(bytes).ok()?, 0))
        }
        "status" => {
            let doc = |l: &Latest| match l {
                Latest::Json(v) => v.clone(),
                Latest::None => Value::Null,
            };
            Some((
                json!({ "supervisor": doc(&st.supervisor), "rm": doc(&st.rm),
                        "stream": st.hub.stats() }),
                0,
            ))
        }
        "contracts" => Some((contracts(st), 0)),
        "events" => Some((Value::Array(st.events.iter().cloned().collect()), 0)),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The send times (ms) of a topic whose frames arrive at `arrivals` (ms, ascending), as
    /// the bus loop sends them: the latest frame, once allowed, checked every millisecond.
    fn sends(topic: &str, arrivals: &[u64]) -> Vec<u64> {
        let t0 = Instant::now();
        let mut pace = Pace::default();
        let mut dirty = false;
        let mut next = arrivals.iter().peekable();
        let mut out = Vec::new();
        for ms in 0..=arrivals.last().copied().unwrap_or(0) + 200 {
            let now = t0 + Duration::from_millis(ms);
            while next.next_if(|&&a| a <= ms).is_some() {
                dirty = true;
            }
            if dirty && pace.due(now) <= now {
                dirty = false;
                pace.sent(now, topic);
                out.push(ms);
            }
        }
        out
    }

    #[test]
    fn a_ten_hertz_scan_with_jitter_is_never_held_back_and_a_fast_pose_is_thinned() {
        // 10 Hz with one frame 40 ms late and one 5 ms early: each goes when it arrives.
        let arrivals = [0, 100, 240, 300, 395, 500, 600];
        assert_eq!(sends("scan", &arrivals), arrivals);
        // 100 Hz for 2 s: after a first pair, frames 90 ms apart or more, about 11 a second.
        let fast: Vec<u64> = (0..200).map(|k| k * 10).collect();
        let sent = sends("pose", &fast);
        assert!((22..=25).contains(&sent.len()), "{sent:?}");
        for w in sent.windows(2).skip(2) {
            assert!(w[1] - w[0] >= 90, "{sent:?}");
        }
    }
}
