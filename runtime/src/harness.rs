//! An in-process harness: one module's own loop ([`crate::run_module_with`]) on a thread of the
//! test, fed scripted samples, with what it publishes collected and time-stamped. The base for
//! golden tests and, later, replay; a module test with it takes milliseconds, where a
//! process-level test starts a system.
//!
//! ```no_run
//! # use std::time::Duration;
//! # use hng_runtime::harness::Harness;
//! # use hng_runtime::msg::{LaserScan, Twist};
//! # fn demo<M: hng_runtime::Module + 'static>() -> Result<(), hng_runtime::harness::HarnessError> {
//! let mut h = Harness::new("follower")?;               // its own unique prefix
//! let scan = h.input::<LaserScan>("sim/scan")?;      // the test publishes here
//! let mut cmd = h.output::<Twist>("follower/cmd_vel")?; // and collects what comes here
//! h.provider(1, "sim/scan");                          // need 1's provider: the harness
//! h.start::<M>("distance_m = 0.5")?;                  // configure, start: the module's loop
//! scan.publish(LaserScan::default())?;
//! let first = h.wait_for(&mut cmd, Duration::from_secs(5), |t| t.linear_x < 0.0)?;
//! h.finish()?;                                        // stop, join: the run's result
//! # Ok(()) }
//! ```
//!
//! - **Contracts.** The module runs without the contract plane. [`Harness::provider`] answers a
//!   need as a scripted provider: the module's `on_provider_changed(need, provider)` is called
//!   once it has started, with the harness's own node as the provider (so what the harness
//!   publishes passes the provider filter of a [`crate::control::ProviderInput`]).
//!   [`Harness::activate`] calls `on_activation(true)` (a module selected by a client).
//! - **Time.** Wall clock; outputs are stamped with the time since [`Harness::start`]
//!   ([`Collected::at`]) beside the header's own stamp.
//! - **Clean-up.** [`Harness::finish`] stops the loop (the module's `stop` runs) and joins
//!   the thread; it fails if the module's run failed or panicked. Dropping the harness does
//!   the same and removes the prefix's files. The prefix lives in `/dev/shm` like a system's: iceoryx2's
//!   process-local service would need the runtime to be generic over the service type.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::channel::{Node, NodeOptions, Publisher, Subscriber};
use crate::contract::ModuleId;
use crate::control::ProviderInfo;
use crate::error::Error;
use crate::module::{Context, Module, REPORT_CHANNEL, RunOptions};
use crate::msg::{Message, ModuleReport, SliceMessage};
use crate::shm;
use crate::wait::{WaitMode, Waiter};

/// Why the harness failed.
#[derive(Debug, thiserror::Error)]
pub enum HarnessError {
    /// The runtime failed (a channel could not be opened, ...).
    #[error(transparent)]
    Runtime(#[from] Error),
    /// The module's run ended with an error (configuration, `configure`, `start`) or panicked.
    #[error("module {module:?}: {detail}")]
    Module {
        /// The module.
        module: String,
        /// What happened.
        detail: String,
    },
    /// Nothing came in time.
    #[error("{what}: nothing within {timeout:?}")]
    Timeout {
        /// What was awaited.
        what: String,
        /// How long.
        timeout: Duration,
    },
}

/// What the executor does for the harness (set in [`RunOptions::harness`]).
#[derive(Debug, Clone, Default)]
pub struct Hooks {
    providers: Vec<(u16, ProviderInfo)>,
    activate: bool,
    stop: Arc<AtomicBool>,
}

impl Hooks {
    /// The scripted contract events, after `start`.
    pub(crate) fn serve<M: Module>(&self, module: &mut M, ctx: &mut Context) {
        for (need, info) in &self.providers {
            if let Err(e) = module.on_provider_changed(ctx, *need, Some(info)) {
                tracing::warn!(module = ctx.name(), need, "on_provider_changed: {e}");
            }
        }
        if self.activate
            && let Err(e) = module.on_activation(ctx, true)
        {
            tracing::warn!(module = ctx.name(), "on_activation: {e}");
        }
    }

    /// True once the harness asked the loop to stop.
    pub(crate) fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }
}

/// A sample the module published, and when the harness received it.
#[derive(Debug, Clone, Copy)]
pub struct Collected<T> {
    /// Time since [`Harness::start`].
    pub at: Duration,
    /// The message (its header carries the module's own stamp and sequence number).
    pub msg: T,
}

/// One of the module's output channels, collected ([`Harness::output`]).
#[derive(Debug)]
pub struct Output<T: Message> {
    sub: Subscriber<T>,
    /// Everything received so far, oldest first.
    pub samples: Vec<Collected<T>>,
}

impl<T: Message> Output<T> {
    /// The messages received so far.
    pub fn messages(&self) -> impl Iterator<Item = &T> {
        self.samples.iter().map(|c| &c.msg)
    }
}

/// Scripted samples for one of the module's inputs ([`Harness::input`]).
#[derive(Debug)]
pub struct Input<T: Message>(Publisher<T>);

impl<T: Message> Input<T> {
    /// Publishes `msg` to the module (and to any subscriber that joined since the last one:
    /// a publisher loans its next sample ahead, before the module may have subscribed).
    ///
    /// # Errors
    /// Publishing failed.
    pub fn publish(&self, msg: T) -> Result<(), HarnessError> {
        self.0.update_connections();
        Ok(self.0.publish(msg)?)
    }
}

/// One module run in the test process; see the module documentation.
#[derive(Debug)]
pub struct Harness {
    name: String,
    prefix: String,
    node: Option<Node>,
    reports: Option<Subscriber<ModuleReport>>,
    hooks: Hooks,
    started: Option<Instant>,
    thread: Option<JoinHandle<Result<(), String>>>,
}

/// How often the module's loop looks at the stop flag when idle (its report period).
const LOOP_PERIOD: Duration = Duration::from_millis(10);

impl Harness {
    /// A harness for a module to be called `name`, on a unique prefix.
    ///
    /// # Errors
    /// The harness's node cannot be created.
    pub fn new(name: &str) -> Result<Harness, HarnessError> {
        let prefix = shm::unique_prefix("harness");
        let node = Node::new(NodeOptions::new(&format!("{name}-harness")).prefix(&prefix))?;
        let reports = node.subscriber::<ModuleReport>(REPORT_CHANNEL)?;
        Ok(Harness {
            name: name.to_string(),
            prefix,
            node: Some(node),
            reports: Some(reports),
            hooks: Hooks::default(),
            started: None,
            thread: None,
        })
    }

    fn node(&self) -> &Node {
        self.node.as_ref().expect("the node lives until drop")
    }

    /// The prefix the module runs on.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// A publisher of scripted samples on one of the module's inputs.
    ///
    /// # Errors
    /// The channel cannot be opened (e.g. it carries another type).
    pub fn input<T: Message>(&self, channel: &str) -> Result<Input<T>, HarnessError> {
        Ok(Input(self.node().publisher(channel)?))
    }

    /// A publisher of scripted variable-size samples (maps, images).
    ///
    /// # Errors
    /// The channel cannot be opened.
    pub fn slice_input<H: SliceMessage>(
        &self,
        channel: &str,
        max_len: usize,
    ) -> Result<crate::SlicePublisher<H>, HarnessError> {
        Ok(self.node().slice_publisher(channel, max_len)?)
    }

    /// Collects what the module publishes on `channel` (open it before [`Harness::start`] to
    /// miss nothing).
    ///
    /// # Errors
    /// The channel cannot be opened.
    pub fn output<T: Message>(&self, channel: &str) -> Result<Output<T>, HarnessError> {
        Ok(Output {
            sub: self.node().subscriber(channel)?,
            samples: Vec::new(),
        })
    }

    /// Serves the module's need `need` as a scripted provider publishing on `channel`.
    pub fn provider(&mut self, need: u16, channel: &str) -> &mut Self {
        let info = ProviderInfo {
            module: ModuleId(self.node().id()),
            channel: channel.to_string(),
        };
        self.hooks.providers.push((need, info));
        self
    }

    /// Activates the module once it has started, as a client's contract would.
    pub fn activate(&mut self) -> &mut Self {
        self.hooks.activate = true;
        self
    }

    /// Starts module `M` with `config_toml` (its `config` table) on a thread, and returns
    /// once it has configured, started, had its scripted providers served and published its
    /// first report: its inputs are open.
    ///
    /// # Errors
    /// The module failed to configure or start ([`HarnessError::Module`]), or did not report
    /// within 10 s.
    pub fn start<M: Module + 'static>(&mut self, config_toml: &str) -> Result<(), HarnessError> {
        let mut opts = RunOptions::new(&self.name);
        opts.prefix = self.prefix.clone();
        opts.config_toml = config_toml.to_string();
        opts.catch_signals = false;
        opts.wait = WaitMode::SLEEP;
        opts.report_period = LOOP_PERIOD;
        opts.idle_report_period = LOOP_PERIOD;
        opts.harness = Some(self.hooks.clone());
        let thread = std::thread::Builder::new()
            .name(format!("harness-{}", self.name))
            .spawn(move || crate::run_module_with::<M>(&opts).map_err(|e| e.to_string()))
            .map_err(|e| Error::io("starting the module's thread", e))?;
        self.thread = Some(thread);
        self.started = Some(Instant::now());
        let reports = self.reports.as_ref().expect("lives until drop");
        let mut waiter = Waiter::new(WaitMode::default())?;
        waiter.attach(reports)?;
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            while let Some(r) = reports.receive()? {
                if r.name() == self.name {
                    return Ok(());
                }
            }
            if self.thread.as_ref().is_some_and(JoinHandle::is_finished) {
                return Err(self.join().err().unwrap_or_else(|| HarnessError::Module {
                    module: self.name.clone(),
                    detail: "stopped before its first report".into(),
                }));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HarnessError::Timeout {
                    what: format!("{}'s first report", self.name),
                    timeout: Duration::from_secs(10),
                });
            }
            waiter.wait(Some(left.min(LOOP_PERIOD)))?;
        }
    }

    /// Moves what arrived on `out` into its [`Output::samples`]; returns how many came.
    ///
    /// # Errors
    /// The channel failed.
    pub fn collect<T: Message>(&self, out: &mut Output<T>) -> Result<usize, HarnessError> {
        let at = self.started.map(|s| s.elapsed()).unwrap_or_default();
        let mut n = 0;
        while let Some(s) = out.sub.receive()? {
            out.samples.push(Collected { at, msg: *s });
            n += 1;
        }
        Ok(n)
    }

    /// Collects `out` until a message satisfies `pred` (returned), for at most `timeout`.
    ///
    /// # Errors
    /// [`HarnessError::Timeout`] when none did in time; [`HarnessError::Module`] when the
    /// module's run ended meanwhile.
    pub fn wait_for<T: Message>(
        &self,
        out: &mut Output<T>,
        timeout: Duration,
        mut pred: impl FnMut(&T) -> bool,
    ) -> Result<T, HarnessError> {
        let mut waiter = Waiter::new(WaitMode::default())?;
        waiter.attach(&out.sub)?;
        let deadline = Instant::now() + timeout;
        let mut seen = out.samples.len();
        loop {
            self.collect(out)?;
            if let Some(c) = out.samples[seen..].iter().find(|c| pred(&c.msg)) {
                return Ok(c.msg);
            }
            seen = out.samples.len();
            if self.thread.as_ref().is_some_and(JoinHandle::is_finished) {
                return Err(HarnessError::Module {
                    module: self.name.clone(),
                    detail: format!("its loop ended while waiting on {}", out.sub.channel()),
                });
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HarnessError::Timeout {
                    what: format!("a matching sample on {}", out.sub.channel()),
                    timeout,
                });
            }
            waiter.wait(Some(left.min(LOOP_PERIOD)))?;
        }
    }

    /// Waits for a report of the module (its heartbeat: state, aptitude, quality, counters,
    /// every 10 ms here) that satisfies `pred`, for at most `timeout`.
    ///
    /// # Errors
    /// [`HarnessError::Timeout`] when none did in time.
    pub fn wait_for_report(
        &self,
        timeout: Duration,
        mut pred: impl FnMut(&ModuleReport) -> bool,
    ) -> Result<ModuleReport, HarnessError> {
        let reports = self.reports.as_ref().expect("lives until drop");
        let mut waiter = Waiter::new(WaitMode::default())?;
        waiter.attach(reports)?;
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(r) = reports.receive()? {
                if r.name() == self.name && pred(&r) {
                    return Ok(*r);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HarnessError::Timeout {
                    what: format!("a matching report of {}", self.name),
                    timeout,
                });
            }
            waiter.wait(Some(left.min(LOOP_PERIOD)))?;
        }
    }

    fn join(&mut self) -> Result<(), HarnessError> {
        self.hooks.stop.store(true, Ordering::Relaxed);
        let Some(t) = self.thread.take() else {
            return Ok(());
        };
        let detail = match t.join() {
            Ok(Ok(())) => return Ok(()),
            Ok(Err(e)) => e,
            Err(_) => "panicked".to_string(),
        };
        Err(HarnessError::Module {
            module: self.name.clone(),
            detail,
        })
    }

    /// Stops the module (its `stop` callback runs) and joins its thread. The prefix's files go
    /// when the harness is dropped: after the inputs and outputs opened from it, when they
    /// were declared after it.
    ///
    /// # Errors
    /// The module's run failed or panicked.
    pub fn finish(&mut self) -> Result<(), HarnessError> {
        self.join()
    }
}

impl Drop for Harness {
    fn drop(&mut self) {
        let _ = self.join();
        self.reports = None;
        self.node = None;
        shm::remove_prefix_files(&self.prefix);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::channel::InputId;
    use crate::contract::NeedSpec;
    use crate::control::{ProviderInput, ProviderOutput};
    use crate::msg::Twist;
    use crate::{ModuleResult, follow_needs};

    /// Echoes `linear_x * 2` of its "Data" input (fallback `echo/in`) to its "Sink" output
    /// (fallback `echo/out`); the number of samples it skipped as foreign in `angular_z`.
    struct Echo {
        input: ProviderInput<Twist>,
        out: ProviderOutput<Twist>,
    }

    impl Module for Echo {
        type Config = ();
        fn configure(ctx: &mut Context, _: ()) -> ModuleResult<Self> {
            ctx.need(NeedSpec::required("Data", 1))
                .need(NeedSpec::required("Sink", 2));
            Ok(Echo {
                input: ProviderInput::new().with_fallback(ctx, "echo/in")?,
                out: ProviderOutput::new().with_fallback(ctx, "echo/out")?,
            })
        }
        fn on_input(&mut self, _: &mut Context, input: InputId) -> ModuleResult {
            if self.input.is(input) {
                while let Some(t) = self.input.receive()? {
                    self.out.publish(Twist {
                        linear_x: t.linear_x * 2.0,
                        angular_z: self.input.foreign() as f64,
                        ..Default::default()
                    })?;
                }
            }
            Ok(())
        }
        follow_needs!(1 => input, 2 => out);
    }

    #[test]
    fn without_providers_the_module_reads_and_writes_its_fallback_channels() {
        let prefix;
        {
            let mut h = Harness::new("echo").unwrap();
            prefix = h.prefix().to_string();
            let input = h.input::<Twist>("echo/in").unwrap();
            let mut out = h.output::<Twist>("echo/out").unwrap();
            h.start::<Echo>("").unwrap();
            let t0 = Instant::now();
            input.publish(Twist::new(1.5, 0.0)).unwrap();
            let got = h
                .wait_for(&mut out, Duration::from_secs(5), |_| true)
                .unwrap();
            assert_eq!(got.linear_x, 3.0);
            assert!(out.samples[0].at > Duration::ZERO && t0.elapsed() < Duration::from_secs(5));
            h.finish().unwrap();
        }
        assert!(
            shm::prefix_files(&prefix).is_empty(),
            "{prefix}: files left"
        );
    }

    #[test]
    fn a_scripted_provider_is_followed_and_other_publishers_are_skipped() {
        let mut h = Harness::new("echo").unwrap();
        let fallback = h.input::<Twist>("echo/in").unwrap();
        let data = h.input::<Twist>("prov/data").unwrap();
        let mut sink = h.output::<Twist>("prov/sink").unwrap();
        let mut old_out = h.output::<Twist>("echo/out").unwrap();
        let other = Node::new(NodeOptions::new("other").prefix(h.prefix())).unwrap();
        let foreign = other.publisher::<Twist>("prov/data").unwrap();
        h.provider(1, "prov/data").provider(2, "prov/sink");
        h.start::<Echo>("").unwrap();
        fallback.publish(Twist::new(100.0, 0.0)).unwrap(); // the fallback is left: not read
        data.publish(Twist::new(2.0, 0.0)).unwrap();
        let got = h
            .wait_for(&mut sink, Duration::from_secs(5), |_| true)
            .unwrap();
        assert_eq!((got.linear_x, got.angular_z), (4.0, 0.0));
        // The module reads the provider's channel now: a sample another publisher sends there
        // is skipped and counted. The module reads each publisher's samples in turn, so the
        // count shows on one of the provider's next echoes.
        foreign.update_connections();
        foreign.publish(Twist::new(7.0, 0.0)).unwrap();
        let deadline = Instant::now() + Duration::from_secs(5);
        let mut next = 3.0;
        let counted = loop {
            data.publish(Twist::new(next, 0.0)).unwrap();
            let got = h
                .wait_for(&mut sink, Duration::from_secs(5), |t| {
                    t.linear_x == next * 2.0
                })
                .unwrap();
            if got.angular_z > 0.0 || Instant::now() > deadline {
                break got.angular_z;
            }
            next += 1.0;
        };
        assert_eq!(counted, 1.0, "the foreign sample counted once");
        h.finish().unwrap();
        h.collect(&mut old_out).unwrap();
        h.collect(&mut sink).unwrap();
        assert!(old_out.samples.is_empty(), "nothing to the fallback output");
        assert_eq!(
            sink.samples.len(),
            usize::try_from(next as i64 - 1).unwrap_or(0),
            "one echo a sample: {:?}",
            sink.samples
        );
    }

    /// Reads `s/level` as a polled input and, at every `s/trigger`, publishes on `s/out` the
    /// newest level (`linear_x`, -1 without one) and its calls to `on_input` (`angular_z`).
    struct Sampler {
        trigger: Subscriber<Twist>,
        level: Subscriber<Twist>,
        out: Publisher<Twist>,
        calls: u32,
    }

    impl Module for Sampler {
        type Config = ();
        fn configure(ctx: &mut Context, _: ()) -> ModuleResult<Self> {
            Ok(Sampler {
                trigger: ctx.subscribe("s/trigger", None)?,
                level: ctx.subscribe_polled("s/level")?,
                out: ctx.publisher("s/out")?,
                calls: 0,
            })
        }
        fn on_input(&mut self, _: &mut Context, input: InputId) -> ModuleResult {
            self.calls += 1;
            if input == self.trigger.id() {
                while self.trigger.receive()?.is_some() {}
                let level = self.level.latest()?.map_or(-1.0, |l| l.linear_x);
                self.out.publish(Twist::new(level, f64::from(self.calls)))?;
            }
            Ok(())
        }
    }

    #[test]
    fn a_polled_input_calls_nothing_and_its_newest_sample_is_read_at_the_trigger() {
        let mut h = Harness::new("sampler").unwrap();
        let trigger = h.input::<Twist>("s/trigger").unwrap();
        let level = h.input::<Twist>("s/level").unwrap();
        let mut out = h.output::<Twist>("s/out").unwrap();
        h.start::<Sampler>("").unwrap();
        for (round, levels) in [(1.0, &[1.0, 2.0, 3.0][..]), (2.0, &[4.0][..])] {
            for l in levels {
                level.publish(Twist::new(*l, 0.0)).unwrap();
            }
            trigger.publish(Twist::default()).unwrap();
            let got = h
                .wait_for(&mut out, Duration::from_secs(5), |t| t.angular_z >= round)
                .unwrap();
            let newest = levels.last().copied().unwrap_or(-1.0);
            assert_eq!(
                (got.linear_x, got.angular_z),
                (newest, round),
                "the newest level, and one call per trigger (none for the levels)"
            );
        }
        trigger.publish(Twist::default()).unwrap();
        let got = h
            .wait_for(&mut out, Duration::from_secs(5), |t| t.angular_z >= 3.0)
            .unwrap();
        assert_eq!(got.linear_x, -1.0, "read once: nothing newer");
        h.finish().unwrap();
    }

    #[test]
    fn a_module_that_fails_to_configure_is_reported() {
        struct Bad;
        impl Module for Bad {
            type Config = ();
            fn configure(_: &mut Context, _: ()) -> ModuleResult<Self> {
                Err("no such device".into())
            }
        }
        let mut h = Harness::new("bad").unwrap();
        let e = h.start::<Bad>("").unwrap_err().to_string();
        assert!(e.contains("no such device"), "{e}");
    }
}
