//! `hng topic list | echo | hz | pub`: look at the channels of any running system, and
//! publish on one by hand (`hng topic pub hng/teleop '{"linear_x": 0.2}' --rate 10`).
//!
//! Output goes through `outln!`: a reader that goes away (`hng topic list | head -2`) ends
//! the command quietly with exit code 0.

use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Subcommand;
use hng_recorder::codec::{FixedCodec, SliceCodec};
use hng_recorder::registry::{KnownTypes, type_name, visit_known_types};
use hng_runtime::channel::{Kind, Node, Receiver, iceoryx_config};
use hng_runtime::msg::{self, Message, SliceMessage};
use hng_runtime::wait::{WaitMode, Waiter, Wake};
use serde::Serialize;

#[derive(Debug, Subcommand)]
pub enum TopicCommand {
    /// List the channels (publish-subscribe services) of the system.
    List {
        /// One JSON object per channel.
        #[arg(long)]
        json: bool,
    },
    /// Print the messages of a channel as they arrive.
    Echo {
        /// Channel name, e.g. `sim/scan`.
        name: String,
        /// Stop after this many messages.
        #[arg(long)]
        count: Option<u64>,
        /// Stop after this many seconds.
        #[arg(long)]
        timeout: Option<f64>,
        /// One JSON object per message (default: the same, pretty-printed).
        #[arg(long)]
        json: bool,
    },
    /// Publish a message given as JSON on a channel of the running system (once, or at
    /// --rate HZ until Ctrl-C or --count). Known types: hng/Twist/v1 (linear_x, linear_y,
    /// angular_z) and hng/Goal/v1 (id, x, y, theta, tolerance_m, use_theta). A number may
    /// also be written "NaN", "inf", "-inf" (or bare NaN, Infinity, -Infinity).
    Pub {
        /// Channel name, e.g. `hng/teleop`.
        name: String,
        /// The message as a JSON object; fields left out are 0.
        json: String,
        /// Publish at this rate (Hz) until Ctrl-C or --count.
        #[arg(long)]
        rate: Option<f64>,
        /// Stop after this many messages (default: 1 without --rate).
        #[arg(long)]
        count: Option<u64>,
    },
    /// Measure the publishing rate of a channel.
    Hz {
        /// Channel name.
        name: String,
        /// Seconds per report.
        #[arg(long, default_value_t = 1.0)]
        window: f64,
        /// Stop after this many reports.
        #[arg(long)]
        count: Option<u64>,
        /// One JSON object per report.
        #[arg(long)]
        json: bool,
    },
}

pub(crate) use hng_runtime::channel::ChannelListing as ChannelInfo;

pub(crate) fn channels(prefix: &str) -> Result<Vec<ChannelInfo>> {
    Ok(hng_runtime::channel::list_channels(prefix)?)
}

pub fn run(prefix: &str, cmd: TopicCommand) -> Result<()> {
    match cmd {
        TopicCommand::List { json } => {
            let list = channels(prefix)?;
            if json {
                for c in &list {
                    outln!("{}", serde_json::to_string(c)?)?;
                }
            } else if list.is_empty() {
                outln!("no channels under prefix {prefix:?}")?;
            } else {
                let w = list.iter().map(|c| c.name.len()).max().unwrap_or(4).max(4);
                outln!("{:w$}  {:28}  nodes  history", "name", "type")?;
                for c in &list {
                    let n = c.nodes.map_or("-".to_string(), |v| v.to_string());
                    outln!(
                        "{:w$}  {:28}  {:>5}  {:>7}",
                        c.name,
                        c.type_name,
                        n,
                        c.history
                    )?;
                }
            }
            Ok(())
        }
        TopicCommand::Echo {
            name,
            count,
            timeout,
            json,
        } => {
            let mode = Mode::Echo {
                count,
                timeout: timeout.map(Duration::from_secs_f64),
                json,
            };
            dispatch(prefix, &name, mode)
        }
        TopicCommand::Pub {
            name,
            json,
            rate,
            count,
        } => crate::topic_pub::run(prefix, &name, &json, rate, count),
        TopicCommand::Hz {
            name,
            window,
            count,
            json,
        } => {
            if !window.is_finite() || window <= 0.0 {
                bail!("--window must be a positive number of seconds");
            }
            dispatch(
                prefix,
                &name,
                Mode::Hz {
                    window: Duration::from_secs_f64(window),
                    count,
                    json,
                },
            )
        }
    }
}

/// `hng iox2-config`: iceoryx2's configuration with this prefix (see docs/data-plane.md).
pub fn iox2_config(prefix: &str) -> Result<()> {
    let config = iceoryx_config(prefix)?;
    let text = toml::to_string_pretty(&config).context("writing the configuration as TOML")?;
    out!(
        "# iceoryx2 configuration of the hng system under prefix {prefix:?}.\n\
         # iceoryx2's tools read ./config/iceoryx2.toml first, then\n\
         # ~/.config/iceoryx2/iceoryx2.toml, then /etc/iceoryx2/iceoryx2.toml.\n{text}"
    )?;
    Ok(())
}

#[derive(Clone, Copy)]
enum Mode {
    Echo {
        count: Option<u64>,
        timeout: Option<Duration>,
        json: bool,
    },
    Hz {
        window: Duration,
        count: Option<u64>,
        json: bool,
    },
}

fn dispatch(prefix: &str, name: &str, mode: Mode) -> Result<()> {
    let list = channels(prefix)?;
    let Some(info) = list.iter().find(|c| c.name == name) else {
        bail!("no channel {name:?} under prefix {prefix:?} (see `hng topic list`)");
    };
    let node = crate::tool::node(prefix, "topic")?;
    // A path's poses are printed too (an image's or a grid's bytes are not: only their
    // header and length).
    if info.type_name == type_name::<msg::PathInfo>() {
        return watch_path(&node, name, mode);
    }
    // The types the recorder knows are the ones printed.
    let mut watch = Watch {
        node: &node,
        name,
        type_name: &info.type_name,
        mode,
        done: None,
    };
    visit_known_types(&mut watch);
    if let Some(done) = watch.done {
        return done;
    }
    bail!(
        "channel {name:?} carries {}, which this hng does not know how to print",
        info.type_name
    )
}

/// Watches channel `name` if it carries the type visited (`done` holds how that ended).
struct Watch<'a> {
    node: &'a Node,
    name: &'a str,
    type_name: &'a str,
    mode: Mode,
    done: Option<Result<()>>,
}

impl KnownTypes for Watch<'_> {
    fn fixed<T: FixedCodec>(&mut self) {
        if self.done.is_none() && self.type_name == type_name::<T>() {
            self.done = Some(watch_fixed::<T>(self.node, self.name, self.mode));
        }
    }
    fn slice<H: SliceCodec>(&mut self) {
        if self.done.is_none() && self.type_name == type_name::<H>() {
            self.done = Some(watch_slice::<H>(self.node, self.name, self.mode));
        }
    }
}

struct Rate {
    start: Instant,
    last: Option<Instant>,
    n: u64,
    gaps: Vec<f64>,
    reports: u64,
}

impl Rate {
    fn new() -> Rate {
        Rate {
            start: Instant::now(),
            last: None,
            n: 0,
            gaps: Vec::new(),
            reports: 0,
        }
    }

    fn tick(&mut self) {
        let now = Instant::now();
        if let Some(l) = self.last {
            self.gaps.push((now - l).as_secs_f64());
        }
        self.last = Some(now);
        self.n += 1;
    }

    /// Prints a report if the window is over; returns true when enough reports were printed.
    fn report(
        &mut self,
        name: &str,
        window: Duration,
        count: Option<u64>,
        json: bool,
    ) -> Result<bool> {
        let el = self.start.elapsed();
        if el < window {
            return Ok(false);
        }
        let rate = self.n as f64 / el.as_secs_f64();
        let (min, max) = self
            .gaps
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), g| (a.min(*g), b.max(*g)));
        let mean = if self.gaps.is_empty() {
            0.0
        } else {
            self.gaps.iter().sum::<f64>() / self.gaps.len() as f64
        };
        let sd = if self.gaps.is_empty() {
            0.0
        } else {
            (self.gaps.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / self.gaps.len() as f64)
                .sqrt()
        };
        let min = if min.is_finite() { min } else { 0.0 };
        if json {
            outln!(
                "{}",
                serde_json::json!({"channel": name, "rate_hz": rate, "messages": self.n,
                "window_s": el.as_secs_f64(), "min_gap_s": min, "max_gap_s": max, "std_dev_s": sd})
            )?;
        } else {
            outln!(
                "{name}: average rate {rate:.3} Hz ({} msgs in {:.2} s), min {min:.4} s, max {max:.4} s, std dev {sd:.5} s",
                self.n,
                el.as_secs_f64()
            )?;
        }
        self.reports += 1;
        self.start = Instant::now();
        self.n = 0;
        self.gaps.clear();
        Ok(count.is_some_and(|c| self.reports >= c))
    }
}

fn run_loop(
    mode: Mode,
    waiter: &mut Waiter,
    mut on_data: impl FnMut(&mut Rate) -> Result<u64>,
    name: &str,
) -> Result<()> {
    waiter.catch_termination_signals()?;
    let start = Instant::now();
    let mut rate = Rate::new();
    let mut seen = 0u64;
    loop {
        let step = Duration::from_millis(100);
        if let Wake::Signal(_) = waiter.wait(Some(step))? {
            return Ok(());
        }
        seen += on_data(&mut rate)?;
        match mode {
            Mode::Echo { count, timeout, .. } => {
                if count.is_some_and(|c| seen >= c) || timeout.is_some_and(|t| start.elapsed() >= t)
                {
                    return Ok(());
                }
            }
            Mode::Hz {
                window,
                count,
                json,
            } => {
                if rate.report(name, window, count, json)? {
                    return Ok(());
                }
            }
        }
    }
}

fn print_json<T: Serialize>(v: &T, json: bool) -> Result<()> {
    if json {
        outln!("{}", serde_json::to_string(v)?)?;
    } else {
        outln!("{}\n---", serde_json::to_string_pretty(v)?)?;
    }
    Ok(())
}

fn watch_fixed<T: Message>(node: &Node, name: &str, mode: Mode) -> Result<()> {
    let sub = node
        .subscriber::<T>(name)
        .with_context(|| format!("subscribing to {name}"))?;
    watch(&sub, name, mode, |s, json| print_json(&**s, json))
}

fn watch_path(node: &Node, name: &str, mode: Mode) -> Result<()> {
    let sub = node
        .slice_subscriber::<msg::PathInfo>(name)
        .with_context(|| format!("subscribing to {name}"))?;
    watch(&sub, name, mode, |s, json| {
        print_json(
            &serde_json::json!({"header": s.header(), "len": s.data().len(), "poses": s.data()}),
            json,
        )
    })
}

fn watch_slice<H: SliceMessage>(node: &Node, name: &str, mode: Mode) -> Result<()> {
    let sub = node
        .slice_subscriber::<H>(name)
        .with_context(|| format!("subscribing to {name}"))?;
    watch(&sub, name, mode, |s, json| {
        print_json(
            &serde_json::json!({"header": s.header(), "len": s.data().len()}),
            json,
        )
    })
}

/// Counts (and, for `echo`, prints with `echo`) every sample of `sub` until the mode ends.
fn watch<K: Kind>(
    sub: &Receiver<K>,
    name: &str,
    mode: Mode,
    echo: impl Fn(&K::Sample, bool) -> Result<()>,
) -> Result<()> {
    let mut waiter = Waiter::new(WaitMode::default())?;
    waiter.attach(sub)?;
    run_loop(
        mode,
        &mut waiter,
        |rate| {
            let mut n = 0;
            while let Some(s) = sub.receive()? {
                n += 1;
                rate.tick();
                if let Mode::Echo { json, .. } = mode {
                    echo(&s, json)?;
                }
            }
            Ok(n)
        },
        name,
    )
}
