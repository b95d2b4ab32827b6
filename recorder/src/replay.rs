//! `hng replay FILE.mcap`: republishes a recording on the bus at its recorded pace (scaled by
//! `--speed`), each message with its recorded time stamp and source; the recorded
//! `hng/clock` drives the simulated clock of whoever listens, so downstream modules see the
//! time they saw then.
//!
//! With a module under test (`--module slam`), the replay starts that module alone on a fresh
//! prefix with its recorded configuration (metadata `hng.modules`), republishes everything it
//! did not publish itself, and records what it publishes now to a new file: the module
//! tested alone, its inputs and outputs controlled.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use hng_runtime::channel::{Node, NodeOptions};
use hng_runtime::clock::CLOCK_CHANNEL;
use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::{ModuleReport, module_id};
use serde::Serialize;

use crate::Error;
use crate::read::{load, scan};
use crate::record::{RecordOptions, RecordSummary, RecorderThread};
use crate::registry::{Outlet, lookup, registry};
use crate::replay_lockstep::Driver;

/// A participant of a replay's lockstep silent this long is not waited for (it died).
const LOCKSTEP_TIMEOUT: Duration = Duration::from_secs(5);

/// How fast to replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// A factor of the recorded pace (1: as recorded).
    Factor(f64),
    /// As fast as possible.
    Max,
}

impl std::str::FromStr for Speed {
    type Err = String;
    fn from_str(s: &str) -> Result<Speed, String> {
        if s == "max" {
            return Ok(Speed::Max);
        }
        match s.parse::<f64>() {
            Ok(f) if f.is_finite() && f > 0.0 => Ok(Speed::Factor(f)),
            _ => Err(format!(
                "speed {s:?}: expected a positive factor of the recorded pace or `max`"
            )),
        }
    }
}

/// A module to run alone against the recording.
#[derive(Debug, Clone)]
pub struct ModuleUnderTest {
    /// Its name (as in the recording: its messages are recognised by its module id).
    pub name: String,
    /// The program and arguments that run it (e.g. `hng module slam`).
    pub command: Vec<String>,
    /// Its configuration (TOML); `None`: the recorded one.
    pub config: Option<String>,
    /// Where to record its outputs.
    pub output: Option<PathBuf>,
}

/// What to replay.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// The recording.
    pub input: PathBuf,
    /// The prefix to publish on (a module under test gets a fresh one when `None`).
    pub prefix: Option<String>,
    /// Channels to replay (names, or prefixes ending in `*`); empty: all but hng's own
    /// system channels (`hng/...`, except the clock).
    pub channels: Vec<String>,
    /// Pace.
    pub speed: Speed,
    /// Start again at the end, until interrupted.
    pub looped: bool,
    /// Run one module alone against the recording.
    pub module: Option<ModuleUnderTest>,
}

/// What a replay did.
#[derive(Debug, Clone, Serialize)]
pub struct ReplaySummary {
    /// Messages published per channel.
    pub published: BTreeMap<String, u64>,
    /// Wall time, s.
    pub wall_s: f64,
    /// The damage that ended the input early, if any (everything before it was replayed).
    pub damage: Option<String>,
    /// What the module under test published, recorded.
    pub recorded: Option<RecordSummary>,
}

struct Item {
    chan: usize,
    log_time: u64,
    data: Vec<u8>,
}

struct Chan {
    topic: String,
    hng_type: String,
    /// Module id of the first message's publisher.
    source: Option<u32>,
}

fn wanted(filters: &[String], channel: &str) -> bool {
    if filters.is_empty() {
        return !channel.starts_with("hng/") || channel == CLOCK_CHANNEL;
    }
    filters.iter().any(|f| match f.strip_suffix('*') {
        Some(p) => channel.starts_with(p),
        None => f == channel,
    })
}

/// Replays `opts.input`; `stop` ends it early (a signal).
pub fn replay(
    opts: &ReplayOptions,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<ReplaySummary, Error> {
    let reg = registry();
    let buf = load(&opts.input)?;
    let mut chans: Vec<Chan> = Vec::new();
    let mut by_id: BTreeMap<u16, usize> = BTreeMap::new();
    let mut items: Vec<Item> = Vec::new();
    let mut unknown: BTreeSet<String> = BTreeSet::new();
    let contents = scan(&opts.input, &buf, &mut |ch, h, data| {
        let idx = match by_id.get(&ch.id) {
            Some(i) => *i,
            None => {
                let i = chans.len();
                chans.push(Chan {
                    topic: ch.topic.clone(),
                    hng_type: ch.hng_type.clone().unwrap_or_default(),
                    source: None,
                });
                by_id.insert(ch.id, i);
                i
            }
        };
        let c = &mut chans[idx];
        if c.source.is_none() && !c.hng_type.is_empty() {
            match lookup(&reg, &c.hng_type) {
                Some(e) => c.source = (e.decode_header)(data).ok().map(|h| h.source),
                None => {
                    unknown.insert(format!("{} ({})", c.topic, c.hng_type));
                }
            }
        }
        items.push(Item {
            chan: idx,
            log_time: h.log_time,
            data: data.to_vec(),
        });
        Ok(())
    })?;
    // A recorder in lockstep reads a round's clock sample with the messages published before
    // it, in one pass (one log time): the clock goes out after them, as it did.
    items.sort_by_key(|it| (it.log_time, chans[it.chan].topic == CLOCK_CHANNEL));
    let damage = contents.damage.as_ref().map(|e| e.to_string());
    if let Some(d) = &damage {
        tracing::warn!("{d}; replaying the {} message(s) before it", items.len());
    }

    let module_id_ = opts.module.as_ref().map(|m| module_id(&m.name));
    let mut selected = vec![false; chans.len()];
    for (i, c) in chans.iter().enumerate() {
        let own = module_id_.is_some() && c.source == module_id_;
        // Channels without an hng type (the module logs) were never on the bus.
        selected[i] = wanted(&opts.channels, &c.topic) && !own && !c.hng_type.is_empty();
    }
    for (i, c) in chans.iter().enumerate() {
        if selected[i] && lookup(&reg, &c.hng_type).is_none() {
            return Err(Error::Other(format!(
                "channel {:?} carries {:?}, a type this hng cannot replay",
                c.topic, c.hng_type
            )));
        }
    }

    let owned_prefix = opts.prefix.is_none() && opts.module.is_some();
    let prefix = match (&opts.prefix, &opts.module) {
        (Some(p), _) => p.clone(),
        (None, Some(_)) => hng_runtime::shm::unique_prefix("replay"),
        (None, None) => hng_runtime::channel::DEFAULT_PREFIX.to_string(),
    };
    let result = run(
        opts, &prefix, &reg, &chans, &selected, &items, &contents, stop,
    );
    if owned_prefix {
        hng_runtime::shm::remove_prefix_files(&prefix);
    }
    let (published, recorded, wall_s) = result?;
    Ok(ReplaySummary {
        published,
        wall_s,
        damage,
        recorded,
    })
}

type RunResult = (BTreeMap<String, u64>, Option<RecordSummary>, f64);

#[allow(clippy::too_many_arguments)]
fn run(
    opts: &ReplayOptions,
    prefix: &str,
    reg: &[crate::registry::TypeEntry],
    chans: &[Chan],
    selected: &[bool],
    items: &[Item],
    contents: &crate::read::Contents,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<RunResult, Error> {
    use std::sync::atomic::Ordering;
    let node = Node::new(
        NodeOptions::new(&format!(
            "hng-replay-{}-{}",
            std::process::id(),
            crate::unique()
        ))
        .prefix(prefix),
    )?;
    // Open every publisher first: a channel of another type is refused before anything
    // is published.
    let mut outlets: Vec<Option<Box<dyn Outlet>>> = Vec::with_capacity(chans.len());
    for (i, c) in chans.iter().enumerate() {
        outlets.push(match (selected[i], lookup(reg, &c.hng_type)) {
            (true, Some(e)) => Some(
                (e.outlet)(&node, &c.topic)
                    .map_err(|e| Error::Other(format!("replay refused: {e}")))?,
            ),
            _ => None,
        });
    }

    let mut sut = None;
    let mut recorder = None;
    let mut driver: Option<Driver> = None;
    if let Some(m) = &opts.module {
        let config = match &m.config {
            Some(c) => c.clone(),
            None => contents
                .metadata("hng.modules")
                .and_then(|mm| mm.get(&m.name).cloned())
                .unwrap_or_default(),
        };
        let sim = chans.iter().any(|c| c.topic == CLOCK_CHANNEL);
        // Outputs: the data channels the module published on in the recording (not its
        // contract messages: alone, nobody answers them).
        let own = module_id(&m.name);
        let outputs: Vec<String> = chans
            .iter()
            .filter(|c| c.source == Some(own) && !c.topic.starts_with("hng/"))
            .map(|c| c.topic.clone())
            .collect();
        // In simulated time the replay drives a lockstep barrier of its own.
        let lockstep = sim
            && selected
                .iter()
                .zip(chans)
                .any(|(s, c)| *s && c.topic == CLOCK_CHANNEL);
        let mut participants = vec![m.name.clone()];
        if let Some(out) = &m.output {
            let mut ro = RecordOptions::new(prefix);
            if lockstep {
                ro.lockstep = Some(crate::lockstep::PARTICIPANT.to_string());
                participants.push(crate::lockstep::PARTICIPANT.to_string());
            }
            ro.output = Some(out.clone());
            ro.only_source = Some(own);
            ro.channels = outputs.clone();
            let mut meta = BTreeMap::new();
            meta.insert("input".to_string(), opts.input.display().to_string());
            meta.insert("module".to_string(), m.name.clone());
            ro.metadata.push(("hng.replay".to_string(), meta));
            let mut mods = BTreeMap::new();
            mods.insert(m.name.clone(), config.clone());
            ro.metadata.push(("hng.modules".to_string(), mods));
            recorder = Some(RecorderThread::spawn(ro)?);
        }
        let reports = node.subscriber::<ModuleReport>(REPORT_CHANNEL)?;
        let mut child = spawn_module(m, prefix, &config, sim)?;
        if let Err(e) = wait_up(&reports, &m.name, Some(&mut child)) {
            stop_module(&mut child);
            return Err(e);
        }
        sut = Some(child);
        if lockstep {
            driver = Some(Driver::new(&node, &participants, LOCKSTEP_TIMEOUT)?);
        }
        if let Some(r) = &recorder {
            let t0 = Instant::now();
            while !outputs.iter().all(|o| r.progress().has(o)) {
                if t0.elapsed() > Duration::from_secs(10) {
                    tracing::warn!(
                        "the recorder has not seen every output of {} after 10 s: {outputs:?}",
                        m.name
                    );
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }

    let mut published: BTreeMap<String, u64> = BTreeMap::new();
    let started = Instant::now();
    let result = (|| -> Result<(), Error> {
        loop {
            let w0 = Instant::now();
            let t0 = items.first().map_or(0, |i| i.log_time);
            for it in items {
                if stop.load(Ordering::Acquire) {
                    return Ok(());
                }
                let Some(out) = &outlets[it.chan] else {
                    continue;
                };
                if let Speed::Factor(f) = opts.speed {
                    let due = w0
                        + Duration::from_secs_f64(it.log_time.saturating_sub(t0) as f64 * 1e-9 / f);
                    let now = Instant::now();
                    if due > now {
                        std::thread::sleep(due - now);
                    }
                }
                match driver.as_mut() {
                    Some(d) if chans[it.chan].topic == CLOCK_CHANNEL => d.step(&it.data)?,
                    _ => {
                        out.publish(&it.data).map_err(|detail| Error::Codec {
                            channel: chans[it.chan].topic.clone(),
                            detail,
                        })?;
                    }
                }
                *published.entry(chans[it.chan].topic.clone()).or_insert(0) += 1;
            }
            if !opts.looped || stop.load(Ordering::Acquire) {
                return Ok(());
            }
        }
    })();

    let mut recorded = None;
    if let Some(mut child) = sut {
        if let Some(r) = &recorder {
            // The module's last outputs: wait until it has been quiet for a second.
            r.progress()
                .wait_quiet(Duration::from_secs(1), Duration::from_secs(15));
        }
        stop_module(&mut child);
    }
    if let Some(mut r) = recorder {
        recorded = Some(r.finish()?);
    }
    result?;
    Ok((published, recorded, started.elapsed().as_secs_f64()))
}

fn spawn_module(
    m: &ModuleUnderTest,
    prefix: &str,
    config: &str,
    sim: bool,
) -> Result<Child, Error> {
    let (program, args) = m
        .command
        .split_first()
        .ok_or_else(|| Error::Other("no command for the module under test".into()))?;
    let mut cmd = Command::new(program);
    cmd.args(args)
        .env("HNG_PREFIX", prefix)
        .env("HNG_MODULE_NAME", &m.name)
        .env("HNG_MODULE_CONFIG", config)
        .env_remove("HNG_CHECKPOINT_DIR")
        .env("HNG_CLOCK", if sim { "sim" } else { "wall" });
    cmd.spawn()
        .map_err(|e| Error::Other(format!("starting the module {} ({program}): {e}", m.name)))
}

/// Waits for the module's first report (it is configured and running).
fn wait_up(
    reports: &hng_runtime::Subscriber<ModuleReport>,
    name: &str,
    child: Option<&mut Child>,
) -> Result<(), Error> {
    let mut waiter = hng_runtime::wait::Waiter::new(hng_runtime::wait::WaitMode::SLEEP)?;
    waiter.attach(reports)?;
    let t0 = Instant::now();
    let mut child = child;
    while t0.elapsed() < Duration::from_secs(30) {
        waiter.wait(Some(Duration::from_millis(100)))?;
        while let Some(r) = reports.receive()? {
            if r.name() == name {
                return Ok(());
            }
        }
        if let Some(c) = child.as_mut()
            && let Ok(Some(status)) = c.try_wait()
        {
            return Err(Error::Other(format!(
                "the module {name} exited before it started: {status}"
            )));
        }
    }
    Err(Error::Other(format!(
        "the module {name} sent no report within 30 s"
    )))
}

fn stop_module(child: &mut Child) {
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(5) {
        if let Ok(Some(_)) = child.try_wait() {
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = child.kill();
    let _ = child.wait();
}
