//! `hng top`: a live view of every module of a running system: state, CPU %, memory,
//! caps, restarts, value V, contracts served, plus degraded mode and C_R.
//!
//! It reads the supervisor's status (`hng/supervisor/status`), the resource manager's
//! status and costs (`hng/rm/status`, `hng/rm/costs`) and the contract tables
//! (`hng/contracts`), merges them by module name once per interval, and shows the result
//! with ratatui when stdout is a terminal, as text snapshots otherwise, or as one JSON
//! document per interval with `--json`. Every source is optional: what is missing shows
//! as `-` (a system without RM, an RM without supervisor, modules without contracts).

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_runtime::clock::monotonic_ns;
use hng_runtime::msg::module_id;
use hng_runtime::system::{
    CONTRACTS, ContractRole, ContractTable, JsonInfo, RM_COSTS, RM_STATUS, ResourceCosts,
    SUPERVISOR_STATUS,
};
use hng_runtime::{Node, NodeOptions, SliceSubscriber, Subscriber};
use serde_json::{Value, json};

/// Options of `hng top`.
#[derive(Debug, Args)]
pub struct TopArgs {
    /// Print one JSON document per interval instead of the live view (the default when
    /// stdout is not a terminal).
    #[arg(long, conflicts_with = "text")]
    pub json: bool,
    /// Print text snapshots instead of the live view or JSON.
    #[arg(long)]
    pub text: bool,
    /// Print one snapshot and exit.
    #[arg(long)]
    pub once: bool,
    /// Seconds between refreshes.
    #[arg(long, default_value_t = 1.0)]
    pub interval: f64,
    /// Stop after this many snapshots (text and JSON output).
    #[arg(long)]
    pub count: Option<u64>,
}

/// The inputs of `hng top`, kept open between snapshots.
struct Sources {
    supervisor: SliceSubscriber<JsonInfo>,
    rm_status: SliceSubscriber<JsonInfo>,
    costs: Subscriber<ResourceCosts>,
    contracts: Subscriber<ContractTable>,
    last_supervisor: Option<(u64, Value)>,
    last_rm: Option<(u64, Value)>,
    last_costs: Option<ResourceCosts>,
    tables: BTreeMap<u32, (Instant, ContractTable)>,
}

impl Sources {
    fn open(node: &Node) -> Result<Sources> {
        Ok(Sources {
            supervisor: node
                .slice_subscriber(SUPERVISOR_STATUS)
                .with_context(|| format!("subscribing to {SUPERVISOR_STATUS}"))?,
            rm_status: node
                .slice_subscriber(RM_STATUS)
                .with_context(|| format!("subscribing to {RM_STATUS}"))?,
            costs: node
                .subscriber(RM_COSTS)
                .with_context(|| format!("subscribing to {RM_COSTS}"))?,
            contracts: node
                .subscriber(CONTRACTS)
                .with_context(|| format!("subscribing to {CONTRACTS}"))?,
            last_supervisor: None,
            last_rm: None,
            last_costs: None,
            tables: BTreeMap::new(),
        })
    }

    /// Takes in what arrived. Malformed documents are skipped.
    ///
    /// A document's age is measured from when it arrived here, on this process's monotonic
    /// clock: its header stamp is on the publisher's clock, which is the simulated one under
    /// `clock = "sim"` (comparing it with the wall clock gave "RM status 1616 s old" on a
    /// system started seconds ago). A late joiner's first document (kept for it by the
    /// channel) counts as new; the ages are right from the next one on.
    fn poll(&mut self) -> Result<()> {
        if let Some(s) = self.supervisor.latest()?
            && let Ok(v) = serde_json::from_slice::<Value>(s.data())
        {
            self.last_supervisor = Some((monotonic_ns(), v));
        }
        if let Some(s) = self.rm_status.latest()?
            && let Ok(v) = serde_json::from_slice::<Value>(s.data())
        {
            self.last_rm = Some((monotonic_ns(), v));
        }
        if let Some(c) = self.costs.latest()? {
            self.last_costs = Some(*c);
        }
        let now = Instant::now();
        while let Some(t) = self.contracts.receive()? {
            let id = if t.module_id != 0 {
                t.module_id
            } else {
                module_id(t.module())
            };
            self.tables.insert(id, (now, *t));
        }
        self.tables
            .retain(|_, (at, _)| now.saturating_duration_since(*at) < Duration::from_secs(3));
        Ok(())
    }

    fn has_any(&self) -> bool {
        self.last_supervisor.is_some() || self.last_rm.is_some() || !self.tables.is_empty()
    }

    /// The merged snapshot.
    fn snapshot(&self) -> Value {
        snapshot(
            self.last_supervisor.as_ref(),
            self.last_rm.as_ref(),
            self.last_costs.as_ref(),
            self.tables.values().map(|(_, t)| t),
            monotonic_ns(),
        )
    }
}

fn age_ms(stamp_ns: u64, now_ns: u64) -> f64 {
    now_ns.saturating_sub(stamp_ns) as f64 / 1e6
}

type Row = serde_json::Map<String, Value>;

/// The fields of a module's row taken from the supervisor's status.
const SUPERVISOR_FIELDS: &[&str] = &[
    "state",
    "pid",
    "restarts",
    "uptime_ms",
    "last_exit_text",
    "manager",
];

/// The fields of a module's row taken from the resource manager's status.
const RM_FIELDS: &[&str] = &[
    "cpu_percent",
    "memory_bytes",
    "rss_bytes",
    "pss_bytes",
    "major_faults",
    "caps",
    "over_limit",
    "waiting_for_resources",
    "R",
    "R_eff",
    "cgroup",
];

/// The `modules` list of a status document (empty without one).
fn modules(doc: Option<&(u64, Value)>) -> Vec<Value> {
    doc.and_then(|(_, v)| v.get("modules").and_then(Value::as_array).cloned())
        .unwrap_or_default()
}

/// The row of the module `m` names (`None`: `m` has no name).
fn row_of<'a>(rows: &'a mut BTreeMap<String, Row>, m: &Value) -> Option<&'a mut Row> {
    let name = m.get("name").and_then(Value::as_str)?;
    Some(rows.entry(name.to_owned()).or_default())
}

/// Copies the fields `keys` that `m` has into `row`.
fn copy_fields(row: &mut Row, m: &Value, keys: &[&str]) {
    for &k in keys {
        if let Some(v) = m.get(k) {
            row.insert(k.to_owned(), v.clone());
        }
    }
}

/// Merges the sources into one document: `{supervisor, rm, degraded, min_priority,
/// costs, modules: [...]}`, one row per module name seen anywhere.
fn snapshot<'a>(
    supervisor: Option<&(u64, Value)>,
    rm: Option<&(u64, Value)>,
    costs: Option<&ResourceCosts>,
    tables: impl Iterator<Item = &'a ContractTable>,
    now_ns: u64,
) -> Value {
    let mut rows: BTreeMap<String, Row> = BTreeMap::new();
    for m in modules(supervisor) {
        let Some(row) = row_of(&mut rows, &m) else {
            continue;
        };
        copy_fields(row, &m, SUPERVISOR_FIELDS);
        if let Some(r) = m.get("report").and_then(|r| r.get("state")) {
            row.insert("work".into(), r.clone());
        }
    }
    for m in modules(rm) {
        let Some(row) = row_of(&mut rows, &m) else {
            continue;
        };
        copy_fields(row, &m, RM_FIELDS);
        if !row.contains_key("pid")
            && let Some(p) = m.get("pid")
        {
            row.insert("pid".into(), p.clone());
        }
        if !row.contains_key("work")
            && let Some(s) = m.get("state")
        {
            row.insert("work".into(), s.clone());
        }
    }
    for t in tables {
        let name = t.module();
        if name.is_empty() {
            continue;
        }
        let row = rows.entry(name.to_owned()).or_default();
        let served: Vec<Value> = t
            .entries()
            .iter()
            .filter(|e| e.role() == Some(ContractRole::Provider))
            .map(|e| {
                json!({
                    "service": e.service(),
                    "priority": e.priority().iter().map(u16::to_string).collect::<Vec<_>>().join("."),
                })
            })
            .collect();
        let used = t
            .entries()
            .iter()
            .filter(|e| e.role() == Some(ContractRole::Client))
            .count();
        row.insert(
            "value".into(),
            if t.value.is_finite() {
                json!(t.value)
            } else {
                Value::Null
            },
        );
        row.insert("active".into(), json!(t.active != 0));
        row.insert("contracts_served".into(), json!(served.len()));
        row.insert("services".into(), Value::Array(served));
        row.insert("contracts_used".into(), json!(used));
    }
    let modules: Vec<Value> = rows
        .into_iter()
        .map(|(name, mut row)| {
            row.insert("name".into(), json!(name));
            Value::Object(row)
        })
        .collect();
    let rm_doc = rm.map(|(_, v)| v);
    let costs_json = match (costs, rm_doc.and_then(|v| v.get("costs"))) {
        (Some(c), _) => json!({"cpu": c.cpu, "memory": c.mem, "comm": c.comm}),
        (None, Some(c)) => c.clone(),
        (None, None) => Value::Null,
    };
    let min_priority = costs.and_then(|c| {
        c.min_priority()
            .map(|p| p.iter().map(u16::to_string).collect::<Vec<_>>().join("."))
    });
    json!({
        "supervisor": supervisor.map(|(stamp, v)| json!({
            "system": v.get("system"),
            "age_ms": age_ms(*stamp, now_ns),
        })),
        "rm": rm.map(|(stamp, v)| json!({
            "age_ms": age_ms(*stamp, now_ns),
            "cgroups": v.get("cgroups"),
            "cpu_free": v.get("cpu_free"),
            "memory_free": v.get("memory_free"),
            "max_report_delay_ms": v.get("max_report_delay_ms"),
        })),
        "costs": costs_json,
        "degraded": costs.map(|c| c.degraded != 0)
            .or_else(|| rm_doc.and_then(|v| v.get("degraded")).and_then(Value::as_bool)),
        "serve_nothing": costs.map(|c| c.serve_nothing != 0),
        "min_priority": min_priority,
        "modules": modules,
    })
}

/// The resource manager's per-module figures of the system under `prefix`, for
/// `hng ps --json`: `{name: {cpu_percent, memory_bytes, caps, R, R_eff, ...}}`, or
/// `None` when no RM status arrives within `timeout`.
#[allow(dead_code)] // Called by `hng ps` when the supervisor side wires it in.
pub fn rm_figures(prefix: &str, timeout: Duration) -> Result<Option<Value>> {
    if !channel_exists(prefix, RM_STATUS)? {
        return Ok(None);
    }
    let node = Node::new(NodeOptions::new("hng-ps-rm").prefix(prefix))?;
    let sub = node.slice_subscriber::<JsonInfo>(RM_STATUS)?;
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(s) = sub.latest()?
            && let Ok(v) = serde_json::from_slice::<Value>(s.data())
        {
            let mut out = serde_json::Map::new();
            for m in v
                .get("modules")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                if let Some(name) = m.get("name").and_then(Value::as_str) {
                    out.insert(name.to_owned(), m.clone());
                }
            }
            return Ok(Some(Value::Object(out)));
        }
        if Instant::now() >= deadline {
            return Ok(None);
        }
        // The RM publishes at its rate (10 Hz by default); the latest sample is kept for
        // late joiners and delivered on its next publish: poll at 10 ms intervals.
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn fmt_bytes(b: Option<f64>) -> String {
    match b {
        None => "-".into(),
        Some(b) if b >= 1024.0 * 1024.0 * 1024.0 => format!("{:.1}G", b / 1073741824.0),
        Some(b) if b >= 1024.0 * 1024.0 => format!("{:.1}M", b / 1048576.0),
        Some(b) => format!("{:.0}K", b / 1024.0),
    }
}

fn caps_text(row: &Value) -> String {
    let caps = &row["caps"];
    let mut parts = Vec::new();
    let enf = |c: &Value| match c["enforced"].as_str() {
        Some("kernel") => "k",
        Some("software") => "s",
        _ => "",
    };
    if let Some(c) = caps["cpu_percent"]["limit"]
        .as_f64()
        .or_else(|| caps["cpu_percent"]["kernel"].as_f64())
    {
        parts.push(format!("cpu {c:.0}%{}", enf(&caps["cpu_percent"])));
    }
    if let Some(m) = caps["memory_bytes"]["limit"]
        .as_f64()
        .or_else(|| caps["memory_bytes"]["kernel"].as_f64())
    {
        parts.push(format!(
            "mem {}{}",
            fmt_bytes(Some(m)),
            enf(&caps["memory_bytes"])
        ));
    }
    if let Some(p) = caps["pids"].as_u64() {
        parts.push(format!("pids {p}"));
    }
    if parts.is_empty() {
        "-".into()
    } else {
        parts.join(" ")
    }
}

/// One module row as text cells.
fn cells(m: &Value) -> [String; 10] {
    let s = |k: &str| m[k].as_str().map_or("-".to_owned(), str::to_owned);
    let state = match (m["state"].as_str(), m["work"].as_str()) {
        (Some(a), Some(b)) if a != b => format!("{a}/{b}"),
        (Some(a), _) => a.to_owned(),
        (None, Some(b)) => b.to_owned(),
        (None, None) => "-".to_owned(),
    };
    let services: Vec<String> = m["services"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|s| {
            Some(format!(
                "{}@{}",
                s["service"].as_str()?,
                s["priority"].as_str()?
            ))
        })
        .collect();
    let served = match m["contracts_served"].as_u64() {
        None => "-".to_owned(),
        Some(0) => "0".to_owned(),
        Some(n) => format!("{n} {}", services.join(",")),
    };
    let mut st = state;
    if m["waiting_for_resources"].as_bool() == Some(true) {
        st.push_str(" (waiting)");
    }
    [
        s("name"),
        st,
        m["pid"].as_u64().map_or("-".to_owned(), |p| p.to_string()),
        m["cpu_percent"]
            .as_f64()
            .map_or("-".to_owned(), |c| format!("{c:.1}")),
        fmt_bytes(m["memory_bytes"].as_f64()),
        caps_text(m),
        m["restarts"]
            .as_u64()
            .map_or("-".to_owned(), |r| r.to_string()),
        m["value"]
            .as_f64()
            .map_or("-".to_owned(), |v| format!("{v:.2}")),
        served,
        m["over_limit"]
            .as_str()
            .map_or(String::new(), str::to_owned),
    ]
}

const HEADERS: [&str; 10] = [
    "MODULE",
    "STATE",
    "PID",
    "CPU%",
    "MEM",
    "CAPS",
    "RESTARTS",
    "V",
    "SERVED",
    "OVER LIMIT",
];

fn summary(snap: &Value) -> String {
    let c = &snap["costs"];
    let costs = if c.is_null() {
        "C_R -".to_owned()
    } else {
        format!(
            "C_R cpu {:.2} mem {:.2} comm {:.2}",
            c["cpu"].as_f64().unwrap_or(f64::NAN),
            c["memory"].as_f64().unwrap_or(f64::NAN),
            c["comm"].as_f64().unwrap_or(f64::NAN)
        )
    };
    let degraded = match (
        snap["degraded"].as_bool(),
        snap["serve_nothing"].as_bool(),
        snap["min_priority"].as_str(),
    ) {
        (None, _, _) => "degraded -".to_owned(),
        (Some(false), _, _) => "normal mode".to_owned(),
        (Some(true), Some(true), _) => "DEGRADED: nothing served".to_owned(),
        (Some(true), _, Some(p)) => format!("DEGRADED: min priority {p}"),
        (Some(true), _, None) => "DEGRADED".to_owned(),
    };
    let system = snap["supervisor"]["system"]
        .as_str()
        .map_or("no supervisor status".to_owned(), |s| format!("system {s}"));
    let rm = match snap["rm"]["age_ms"].as_f64() {
        None => "no RM status".to_owned(),
        Some(a) if a > 3000.0 => format!("RM status {:.0} s old", a / 1000.0),
        Some(_) => {
            let free = snap["rm"]["cpu_free"]
                .as_f64()
                .map_or("-".to_owned(), |f| format!("{:.0}%", f * 100.0));
            format!("cpu free {free}")
        }
    };
    format!("{system} | {degraded} | {costs} | {rm}")
}

/// The snapshot as a plain-text table.
fn text(snap: &Value) -> String {
    let rows: Vec<[String; 10]> = snap["modules"]
        .as_array()
        .into_iter()
        .flatten()
        .map(cells)
        .collect();
    let mut w: Vec<usize> = HEADERS.iter().map(|h| h.len()).collect();
    for r in &rows {
        for (i, c) in r.iter().enumerate() {
            w[i] = w[i].max(c.chars().count());
        }
    }
    let line = |r: &[String]| -> String {
        let mut s = String::new();
        for (i, c) in r.iter().enumerate() {
            if i > 0 {
                s.push_str("  ");
            }
            let pad = w[i].saturating_sub(c.chars().count());
            if (2..=4).contains(&i) || i == 6 || i == 7 {
                s.push_str(&" ".repeat(pad));
                s.push_str(c);
            } else {
                s.push_str(c);
                s.push_str(&" ".repeat(pad));
            }
        }
        s.trim_end().to_owned()
    };
    let mut out = summary(snap);
    out.push('\n');
    let head: Vec<String> = HEADERS.iter().map(|h| (*h).to_owned()).collect();
    out.push_str(&line(&head));
    out.push('\n');
    for r in &rows {
        out.push_str(&line(r));
        out.push('\n');
    }
    if rows.is_empty() {
        out.push_str("(no module seen yet)\n");
    }
    out
}

/// Whether a publish-subscribe channel exists under `prefix` (checked without creating
/// any file).
pub(crate) fn channel_exists(prefix: &str, channel: &str) -> Result<bool> {
    use hng_runtime::channel::{Service, iceoryx_config};
    let config = iceoryx_config(prefix)?;
    let name = iceoryx2::prelude::ServiceName::new(channel)
        .map_err(|e| anyhow::anyhow!("service name {channel}: {e:?}"))?;
    let details = <Service as iceoryx2::service::Service>::details(
        &name,
        &config,
        iceoryx2::service::messaging_pattern::MessagingPattern::PublishSubscribe,
    )
    .map_err(|e| anyhow::anyhow!("looking up {channel} under prefix {prefix:?}: {e:?}"))?;
    Ok(details.is_some())
}

/// `hng top`.
pub fn run(prefix: &str, args: &TopArgs) -> Result<()> {
    if !(args.interval.is_finite() && args.interval > 0.0) {
        bail!("--interval must be a positive number of seconds");
    }
    if !channel_exists(prefix, SUPERVISOR_STATUS)? && !channel_exists(prefix, RM_STATUS)? {
        bail!(
            "no hng system runs under prefix {prefix:?} (neither a supervisor nor a resource manager status channel); start one with `hng run` or pass --prefix"
        );
    }
    let interval = Duration::from_secs_f64(args.interval);
    let node = crate::tool::node(prefix, "top")?;
    let mut src = Sources::open(&node)?;
    let terminal = std::io::stdout().is_terminal();
    let live = !args.json && !args.text && !args.once && terminal;
    // JSON for programs (stdout a file or a pipe), text on a terminal or with --text.
    let json = args.json || (!args.text && !terminal);
    if live {
        return live_view(&mut src, interval);
    }
    let count = if args.once { Some(1) } else { args.count };
    let mut printed = 0u64;
    let mut first = true;
    loop {
        // The first snapshot waits until some source has spoken (at most one interval).
        let deadline = Instant::now() + interval;
        loop {
            src.poll()?;
            if Instant::now() >= deadline || (first && src.has_any() && src.last_rm.is_some()) {
                break;
            }
            std::thread::sleep(Duration::from_millis(20).min(interval));
        }
        first = false;
        let snap = src.snapshot();
        if json {
            outln!("{}", serde_json::to_string(&snap)?)?;
        } else {
            out!("{}", text(&snap))?;
            if count != Some(1) {
                outln!()?;
            }
        }
        printed += 1;
        if count.is_some_and(|c| printed >= c) {
            return Ok(());
        }
    }
}

fn live_view(src: &mut Sources, interval: Duration) -> Result<()> {
    use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
    use ratatui::layout::{Constraint, Layout};
    use ratatui::style::{Modifier, Style};
    use ratatui::widgets::{Block, Paragraph, Row, Table};

    let mut terminal = ratatui::try_init().context("initialising the terminal")?;
    let result = (|| -> Result<()> {
        let mut next = Instant::now();
        let mut snap = Value::Null;
        loop {
            if Instant::now() >= next {
                src.poll()?;
                snap = src.snapshot();
                next = Instant::now() + interval;
            }
            terminal.draw(|f| {
                let [top, body, help] = Layout::vertical([
                    Constraint::Length(3),
                    Constraint::Min(3),
                    Constraint::Length(1),
                ])
                .areas(f.area());
                f.render_widget(
                    Paragraph::new(summary(&snap)).block(Block::bordered().title(" hng top ")),
                    top,
                );
                let rows: Vec<Row> = snap["modules"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|m| Row::new(cells(m)))
                    .collect();
                let widths = [
                    Constraint::Length(16),
                    Constraint::Length(18),
                    Constraint::Length(8),
                    Constraint::Length(6),
                    Constraint::Length(8),
                    Constraint::Length(22),
                    Constraint::Length(8),
                    Constraint::Length(6),
                    Constraint::Min(10),
                    Constraint::Length(24),
                ];
                let table = Table::new(rows, widths)
                    .header(Row::new(HEADERS).style(Style::new().add_modifier(Modifier::BOLD)))
                    .block(Block::bordered().title(" modules "));
                f.render_widget(table, body);
                f.render_widget(
                    Paragraph::new(
                        "q: quit  (caps: k = kernel cgroup, s = software check by the RM)",
                    ),
                    help,
                );
            })?;
            let wait = next
                .saturating_duration_since(Instant::now())
                .min(Duration::from_millis(250));
            if event::poll(wait)?
                && let Event::Key(k) = event::read()?
                && k.kind == KeyEventKind::Press
            {
                let ctrl_c =
                    k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL);
                if ctrl_c || matches!(k.code, KeyCode::Char('q') | KeyCode::Esc) {
                    return Ok(());
                }
            }
        }
    })();
    ratatui::restore();
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merges_sources_by_module_name() {
        let sup = (
            0,
            json!({"system": "s", "modules": [
                {"name": "a", "state": "running", "pid": 10, "restarts": 2,
                 "report": {"state": "idle"}},
            ]}),
        );
        let rm = (
            0,
            json!({"modules": [
                {"name": "a", "pid": 10, "cpu_percent": 12.5, "memory_bytes": 3145728,
                 "caps": {"cpu_percent": {"limit": 20.0, "kernel": 20.0, "enforced": "kernel"},
                          "memory_bytes": {"limit": 67108864.0, "kernel": null, "enforced": "software"},
                          "pids": null}},
                {"name": "rm", "pid": 11, "cpu_percent": 0.5},
            ]}),
        );
        let mut costs = ResourceCosts {
            cpu: 2.0,
            mem: 1.0,
            comm: 1.0,
            degraded: 1,
            min_priority_len: 2,
            ..Default::default()
        };
        costs.min_priority[..2].copy_from_slice(&[2, 1]);
        let mut t = ContractTable {
            active: 1,
            value: 0.75,
            count: 1,
            ..Default::default()
        };
        t.set_module("a");
        t.entries[0].role = ContractRole::Provider as u8;
        t.entries[0].set_service("map");
        t.entries[0].set_priority(&[1, 2]);
        let snap = snapshot(Some(&sup), Some(&rm), Some(&costs), [&t].into_iter(), 0);
        assert_eq!(snap["min_priority"], "2.1");
        assert_eq!(snap["degraded"], true);
        let a = &snap["modules"][0];
        assert_eq!(a["name"], "a");
        assert_eq!(a["restarts"], 2);
        assert_eq!(a["contracts_served"], 1);
        let c = cells(a);
        assert_eq!(c[1], "running/idle");
        assert_eq!(c[3], "12.5");
        assert_eq!(c[4], "3.0M");
        assert_eq!(c[5], "cpu 20%k mem 64.0Ms");
        assert_eq!(c[7], "0.75");
        assert_eq!(c[8], "1 map@1.2");
        let txt = text(&snap);
        assert!(txt.contains("DEGRADED: min priority 2.1"), "{txt}");
        assert!(txt.lines().any(|l| l.starts_with("rm ")), "{txt}");
        // Nothing at all: still a document and a text.
        let empty = snapshot(None, None, None, std::iter::empty(), 0);
        assert!(text(&empty).contains("no module seen yet"));
    }
}
