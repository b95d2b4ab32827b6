//! The module SDK: one trait, one entry point.
//!
//! A module is a struct implementing [`Module`]. [`Module::configure`] builds it from its typed
//! configuration and opens its ports through the [`Context`]; the runtime then calls
//! [`Module::on_input`] when a subscribed channel has data, [`Module::on_tick`] when a timer
//! fires, [`Module::on_deadline_missed`] when an input stays silent longer than its deadline,
//! and [`Module::checkpoint`] / [`Module::restore`] to save and recover state across crashes.
//! Its `main` is one line:
//!
//! ```ignore
//! fn main() -> std::process::ExitCode { hng_runtime::run_module::<MyModule>() }
//! ```
//!
//! [`run_module`] owns the process: it reads the [`RunOptions`] from the environment the
//! supervisor sets (`HNG_*` variables), silences iceoryx2's log, turns SIGINT/SIGTERM/SIGHUP
//! into a clean stop (iceoryx2's own signal handlers stay disabled), restores the last
//! checkpoint, publishes a [`ModuleReport`] on [`REPORT_CHANNEL`] every report period (the
//! heartbeat the watchdog watches), writes checkpoints periodically and on stop (keeping the
//! previous one beside the latest), and releases its shared memory on exit. On the simulation
//! clock it also acknowledges the simulator's lockstep rounds ([`crate::clock::lockstep`]).

use std::process::ExitCode;
use std::time::Duration;

use serde::de::DeserializeOwned;

use crate::channel::{
    InputId, Kind, Node, NodeOptions, Publisher, Receiver, SlicePublisher, SliceSubscriber,
    Subscriber,
};
use crate::clock::{Clock, ClockMode, monotonic_ns};
use crate::contract::{
    ContractAgent, DropCounters, ModuleId, NeedSpec, Priority, ServiceOffer, Timing, Verdict,
};
use crate::control::{ContractSpec, ControlPlane, PlaneEvent, ProviderInfo};
use crate::error::Error;
use crate::harness::Hooks;
use crate::msg::{self, Message, ModuleReport, ModuleState, SliceMessage};
use crate::wait::{WaitMode, Waiter, Wake};

mod beat;
mod checkpoints;
mod due;
mod logging;
mod options;
mod rounds;
mod run;
mod seconds;
mod state;

use beat::Beat;
use checkpoints::{Checkpoints, save_checkpoint};
pub use logging::init_tracing;
pub use options::{RunError, RunOptions};
use rounds::Rounds;
pub use run::{run_module, run_module_on_wall_clock, run_module_with};
pub use seconds::renamed_to_seconds;
pub use state::{decode_state, encode_state};

/// The well-known channel every module publishes its [`ModuleReport`] on.
pub const REPORT_CHANNEL: &str = "hng/report";

/// The error type module callbacks return: anything that is an error.
pub type ModuleError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// The result type module callbacks return.
pub type ModuleResult<T = ()> = Result<T, ModuleError>;

/// A module: one algorithm, run as its own process by [`run_module`].
pub trait Module: Sized {
    /// Typed configuration, read from the `config` table of the module's launch-file entry.
    type Config: DeserializeOwned + Default;

    /// Version of the checkpoint format; a checkpoint of another version is ignored (clean
    /// start with a warning).
    const STATE_VERSION: u32 = 1;

    /// Builds the module: open ports (publishers, subscribers, timers) through `ctx`.
    fn configure(ctx: &mut Context, config: Self::Config) -> ModuleResult<Self>;

    /// Called once after configure (and restore), before the first input.
    fn start(&mut self, _ctx: &mut Context) -> ModuleResult {
        Ok(())
    }

    /// A subscribed input has data: receive until it returns `None`.
    fn on_input(&mut self, _ctx: &mut Context, _input: InputId) -> ModuleResult {
        Ok(())
    }

    /// A timer fired.
    fn on_tick(&mut self, _ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        Ok(())
    }

    /// An input with a deadline stayed silent longer than it. Called once per silence; the
    /// miss is also counted in the module's report.
    fn on_deadline_missed(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), ?input, "input deadline missed");
        Ok(())
    }

    /// The state to save, or `None` for a stateless module: written, with [`Module::restore`],
    /// by [`crate::checkpoint_field!`] or [`crate::checkpoint_with!`] from a serde value.
    fn checkpoint(&self) -> Option<Vec<u8>> {
        None
    }

    /// A module whose latest checkpoint and the one kept before it are both unusable starts
    /// clean (true, the default) or refuses to start (false: for modules whose clean start
    /// in the middle of a run would be wrong, such as the simulator).
    const CLEAN_START_AFTER_BAD_CHECKPOINT: bool = true;

    /// Restores a state saved by [`Module::checkpoint`]. An error means the checkpoint before
    /// it is tried, then a clean start (see [`Module::CLEAN_START_AFTER_BAD_CHECKPOINT`]).
    fn restore(&mut self, _state: &[u8]) -> ModuleResult {
        Ok(())
    }

    /// Called once on a clean stop, before the final checkpoint.
    fn stop(&mut self, _ctx: &mut Context) {}

    /// Contracts: the module became active (it holds a client contract, or it is the
    /// Manager, called once at start) or inactive (its last client contract ended). A
    /// provider starts working on `true` and stops on `false` (paper 5.6: "a module provides
    /// its service only if it has been selected").
    fn on_activation(&mut self, _ctx: &mut Context, _active: bool) -> ModuleResult {
        Ok(())
    }

    /// Contracts: need `need` (its rank) is now served by `provider`, or by nobody. Follow the
    /// provider's data channel here, e.g. with [`crate::control::ProviderInput::follow`].
    fn on_provider_changed(
        &mut self,
        _ctx: &mut Context,
        _need: u16,
        _provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        Ok(())
    }

    /// Contracts: any contract of the module changed (a client came or went, a provider
    /// changed, the priority changed). Called after the more specific callbacks.
    fn on_contracts_changed(&mut self, _ctx: &mut Context) -> ModuleResult {
        Ok(())
    }
}

/// Identifies a timer created with [`Context::add_timer`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TimerId(pub usize);

struct Timer {
    period_ns: u64,
    next_ns: u64,
}

struct Deadline {
    input: InputId,
    deadline_ns: u64,
    last_ns: u64,
    missed: bool,
}

/// The module's handle on the runtime, passed to every callback.
pub struct Context {
    node: Node,
    waiter: Waiter,
    timers: Vec<Timer>,
    deadlines: Vec<Deadline>,
    aptitude: bool,
    quality: f32,
    waiting_for_resources: bool,
    state: ModuleState,
    stop_requested: bool,
    deadline_misses: u64,
    checkpoints: u64,
    contract_spec: ContractSpec,
    plane: Option<ControlPlane>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context")
            .field("node", &self.node)
            .finish_non_exhaustive()
    }
}

impl Context {
    /// A context on a fresh node (used by [`run_module`], and by tests that drive a module
    /// by hand).
    pub fn new(node: Node, wait: WaitMode) -> Result<Context, Error> {
        let mut waiter = Waiter::new(wait)?;
        if let Err(e) = waiter.share_cpus(&node) {
            tracing::warn!(module = %node.name(), "spinning without regard to other modules: {e}");
        }
        Ok(Context {
            node,
            waiter,
            timers: Vec::new(),
            deadlines: Vec::new(),
            aptitude: true,
            quality: 0.0,
            waiting_for_resources: false,
            state: ModuleState::Configured,
            stop_requested: false,
            deadline_misses: 0,
            checkpoints: 0,
            contract_spec: ContractSpec::default(),
            plane: None,
        })
    }

    /// The module's name.
    pub fn name(&self) -> &str {
        self.node.name()
    }

    /// The node (for direct channel access).
    pub fn node(&self) -> &Node {
        &self.node
    }

    /// The common clock.
    pub fn clock(&self) -> &Clock {
        self.node.clock()
    }

    /// Now, on the common clock.
    pub fn now(&self) -> Duration {
        self.node.clock().now()
    }

    /// Opens a publisher (channels can be opened at any time, not only in configure).
    pub fn publisher<T: Message>(&mut self, channel: &str) -> Result<Publisher<T>, Error> {
        self.node.publisher(channel)
    }

    /// Opens a variable-size publisher.
    pub fn slice_publisher<H: SliceMessage>(
        &mut self,
        channel: &str,
        max_len: usize,
    ) -> Result<SlicePublisher<H>, Error> {
        self.node.slice_publisher(channel, max_len)
    }

    /// Subscribes to a channel; [`Module::on_input`] is called when it has data. With a
    /// `deadline`, [`Module::on_deadline_missed`] is called when it stays silent longer.
    pub fn subscribe<T: Message>(
        &mut self,
        channel: &str,
        deadline: Option<Duration>,
    ) -> Result<Subscriber<T>, Error> {
        self.subscribe_kind(channel, deadline)
    }

    /// Subscribes to a variable-size channel.
    pub fn subscribe_slice<H: SliceMessage>(
        &mut self,
        channel: &str,
        deadline: Option<Duration>,
    ) -> Result<SliceSubscriber<H>, Error> {
        self.subscribe_kind(channel, deadline)
    }

    /// Subscribes to a channel as a **polled input** (ROS 2's subscription read by `take()`
    /// instead of a callback, Autoware's polling subscriber, Orocos' data port beside its event
    /// ports): the module reads its newest sample ([`Receiver::latest`]) when something else
    /// calls it (`None` when nothing came since the last read: keep the value you need). A
    /// sample on it calls no [`Module::on_input`], does not wake the executor, and
    /// in lockstep is not one of the inputs the module declares, so writing it opens no round
    /// for the module. What a read in lockstep round `r` sees is what was sent before `r`
    /// opened (the "two phases" of [`crate::clock::lockstep`]), so it stays deterministic. No
    /// deadline: a polled input's age is the module's to judge (its header's stamp). Samples
    /// overwritten between two reads count as no loss in the module's report.
    pub fn subscribe_polled<T: Message>(&mut self, channel: &str) -> Result<Subscriber<T>, Error> {
        let sub = self.node.subscriber::<T>(channel)?;
        sub.set_polled();
        Ok(sub)
    }

    /// [`Context::subscribe_polled`] for a variable-size channel.
    pub fn subscribe_slice_polled<H: SliceMessage>(
        &mut self,
        channel: &str,
    ) -> Result<SliceSubscriber<H>, Error> {
        let sub = self.node.slice_subscriber::<H>(channel)?;
        sub.set_polled();
        Ok(sub)
    }

    /// Subscribes to a channel of either kind (the provider inputs' one way in).
    pub(crate) fn subscribe_kind<K: Kind>(
        &mut self,
        channel: &str,
        deadline: Option<Duration>,
    ) -> Result<Receiver<K>, Error> {
        let sub = K::subscriber(&self.node, channel)?;
        self.waiter.attach(&sub)?;
        self.watch_deadline(sub.id(), deadline);
        Ok(sub)
    }

    /// Calls back again for a subscriber earlier passed to [`Context::unsubscribe`] and kept
    /// (a channel a [`crate::control::ProviderReceiver`] left): no channel is opened.
    pub(crate) fn resubscribe<K: Kind>(
        &mut self,
        sub: &Receiver<K>,
        deadline: Option<Duration>,
    ) -> Result<(), Error> {
        self.waiter.attach(sub)?;
        self.watch_deadline(sub.id(), deadline);
        Ok(())
    }

    /// Stops calling back for an input (drop the subscriber afterwards).
    pub fn unsubscribe(&mut self, input: InputId) -> Result<(), Error> {
        self.deadlines.retain(|d| d.input != input);
        self.waiter.detach(input)
    }

    fn watch_deadline(&mut self, input: InputId, deadline: Option<Duration>) {
        if let Some(d) = deadline {
            self.deadlines.push(Deadline {
                input,
                deadline_ns: d.as_nanos() as u64,
                last_ns: self.clock().now_ns(),
                missed: false,
            });
        }
    }

    /// Adds a periodic timer on the common clock; the first tick is one period from now.
    pub fn add_timer(&mut self, period: Duration) -> TimerId {
        let period_ns = (period.as_nanos() as u64).max(1);
        self.timers.push(Timer {
            period_ns,
            next_ns: self.clock().now_ns().saturating_add(period_ns),
        });
        TimerId(self.timers.len() - 1)
    }

    /// Sets the self-evaluation reported to the system: aptitude f and quality Q in [-1, 1]
    /// (clamped; NaN counts as 0).
    pub fn set_quality(&mut self, aptitude: bool, quality: f32) {
        self.aptitude = aptitude;
        self.quality = if quality.is_nan() {
            0.0
        } else {
            quality.clamp(-1.0, 1.0)
        };
    }

    /// The self-evaluation last set: (aptitude, quality).
    pub fn quality(&self) -> (bool, f32) {
        (self.aptitude, self.quality)
    }

    /// Tells the resource manager the module waits for resources (paper 5.3).
    pub fn set_waiting_for_resources(&mut self, waiting: bool) {
        self.waiting_for_resources = waiting;
    }

    /// Sets the state shown in reports (`Running` or `Idle`).
    pub fn set_state(&mut self, state: ModuleState) {
        self.state = state;
    }

    /// Asks the runtime to stop the module cleanly after this callback.
    pub fn request_stop(&mut self) {
        self.stop_requested = true;
    }

    /// Input deadlines missed so far.
    pub fn deadline_misses(&self) -> u64 {
        self.deadline_misses
    }

    // ----- contracts (paper 4.2, 5.5, 5.6; see docs/contracts.md) -----

    /// Declares a service this module provides (in `configure`). The runtime then answers
    /// queries for it, and [`Module::on_activation`] tells the module when it is selected.
    pub fn provide(&mut self, offer: ServiceOffer) -> &mut Self {
        self.contract_spec.provides.push(offer);
        self
    }

    /// Declares a need (in `configure`): a service, its rank in the module (the contract gets
    /// priority `P(module).rank`) and whether it is required. The runtime finds the best
    /// provider while the module is active and calls [`Module::on_provider_changed`].
    pub fn need(&mut self, need: NeedSpec) -> &mut Self {
        self.contract_spec.needs.push(need);
        self
    }

    /// Declares this module the Manager (in `configure`): always active, priority root, its
    /// `objectives` are needs of ranks 1, 2, ... in mission order (1 is the most important).
    pub fn manager(&mut self, objectives: &[&str]) -> &mut Self {
        self.contract_spec.manager = Some(objectives.iter().map(|s| s.to_string()).collect());
        self
    }

    /// Switches optional need `need` off or on, in `configure` or at any time later (an
    /// order changes what the module asks for: see [`ContractAgent::set_need_enabled`]).
    /// Returns false for an unknown rank or a required need.
    pub fn set_need_enabled(&mut self, need: u16, enabled: bool) -> bool {
        if let Some(p) = self.plane.as_mut() {
            return p.agent_mut().set_need_enabled(need, enabled);
        }
        match self.contract_spec.needs.iter().find(|n| n.rank == need) {
            Some(n) if !n.is_required() => {
                self.contract_spec.disabled.retain(|&r| r != need);
                if !enabled {
                    self.contract_spec.disabled.push(need);
                }
                true
            }
            _ => false,
        }
    }

    /// Replaces the protocol timing (reply window, refresh period, peer timeout, ...).
    pub fn contract_timing(&mut self, timing: Timing) -> &mut Self {
        self.contract_spec.timing = Some(timing);
        self
    }

    /// Sets the re-negotiation threshold (default 0.1).
    pub fn contract_hysteresis(&mut self, hysteresis: f64) -> &mut Self {
        self.contract_spec.hysteresis = Some(hysteresis);
        self
    }

    /// Sets the validity time tau of the client feedback (default 5 s).
    pub fn feedback_tau(&mut self, tau: Duration) -> &mut Self {
        self.contract_spec.tau = Some(tau);
        self
    }

    /// Declares this module a driver of `service` (paper 5.6): commands for it are obeyed
    /// only from the live client with the most important contract; a client that sent no
    /// command for `freshness` loses control to the next. See [`Context::command_verdict`].
    pub fn drive(&mut self, service: &str, freshness: Duration) -> &mut Self {
        self.contract_spec
            .drives
            .push((service.to_string(), freshness));
        self
    }

    /// The module's contract agent, once the runtime started it (after `configure`).
    pub fn contracts(&self) -> Option<&ContractAgent> {
        self.plane.as_ref().map(ControlPlane::agent)
    }

    /// The module's priority, derived from its client contracts (`None`: inactive). There is
    /// deliberately no setter: priorities come from the contract tree only.
    pub fn priority(&self) -> Option<Priority> {
        self.contracts().and_then(ContractAgent::priority)
    }

    /// True when the module holds a client contract or is the Manager.
    pub fn is_active(&self) -> bool {
        self.contracts().is_some_and(ContractAgent::is_active)
    }

    /// The provider currently serving need `need`.
    pub fn provider(&self, need: u16) -> Option<ProviderInfo> {
        self.contracts()?.contract(need).map(|c| ProviderInfo {
            module: c.provider,
            channel: c.channel.to_string(),
        })
    }

    /// The module's evaluation `e` in [-1, 1] of the provider currently serving need `need`
    /// (paper 4.2): sent to it once, as feedback with the next refresh, it enters its value V. Without
    /// one, the module forwards the feedback it receives from its own clients.
    pub fn evaluate_provider(&mut self, need: u16, e: f64) {
        let Some(provider) = self.provider(need) else {
            return;
        };
        if let Some(p) = self.plane.as_mut() {
            p.agent_mut().evaluate_provider(need, provider.module, e);
        }
    }

    /// A driver's decision on a command for `service` whose header is `header`:
    /// [`Verdict::Accept`] only for the live contract holder with the most important
    /// priority. Commands from publishers holding no contract, or preempted ones, are
    /// ignored and counted (in the module's contract table).
    pub fn command_verdict(&mut self, service: &str, header: &msg::Header) -> Verdict {
        let now = self.now();
        match self.plane.as_mut() {
            Some(p) => p.command_verdict(service, header, now),
            None => Verdict::Ignore(crate::contract::DropReason::NoContract),
        }
    }

    /// Control messages dropped so far by the transport (undecodable, spoofed).
    pub fn control_drops(&self) -> DropCounters {
        self.plane
            .as_ref()
            .map(|p| p.drops().clone())
            .unwrap_or_default()
    }

    /// This module's id in contracts (the `source` of its messages' headers).
    pub fn module_id(&self) -> ModuleId {
        ModuleId(self.node.id())
    }

    fn report(&self, period_ns: u64) -> ModuleReport {
        let c = self.node.counters();
        let mut r = ModuleReport {
            pid: std::process::id(),
            state: self.state as u8,
            aptitude: u8::from(self.aptitude),
            waiting_for_resources: u8::from(self.waiting_for_resources),
            quality: self.quality,
            period_ns,
            msgs_in: c.msgs_in.get(),
            msgs_out: c.msgs_out.get(),
            msgs_dropped: c.msgs_dropped.get(),
            deadline_misses: self.deadline_misses,
            checkpoints: self.checkpoints,
            ..Default::default()
        };
        r.set_name(self.name());
        r
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::channel::channel_key;
    use crate::msg::Twist;
    use crate::shm;

    #[test]
    fn a_polled_input_wakes_no_waiter_and_is_no_declared_input() {
        let prefix = shm::unique_prefix("polled");
        let node = Node::new(NodeOptions::new("m").prefix(&prefix)).unwrap();
        let peer = Node::new(NodeOptions::new("peer").prefix(&prefix)).unwrap();
        let mut ctx = Context::new(node, WaitMode::SLEEP).unwrap();
        let trigger = ctx.subscribe::<Twist>("p/trigger", None).unwrap();
        let polled = ctx.subscribe_polled::<Twist>("p/polled").unwrap();
        let keys: Vec<u64> = ctx.waiter.input_keys().collect();
        assert_eq!(
            keys,
            [channel_key("p/trigger")],
            "a lockstep answer declares the trigger only"
        );
        let to_polled = peer.publisher::<Twist>("p/polled").unwrap();
        let to_trigger = peer.publisher::<Twist>("p/trigger").unwrap();
        // More samples than the subscriber's buffer holds (twice: the first read only learns
        // the sequence).
        let burst = |from: u32| {
            for i in from..from + 10 {
                to_polled.publish(Twist::new(f64::from(i), 0.0)).unwrap();
            }
        };
        burst(0);
        assert_eq!(polled.latest().unwrap().unwrap().linear_x, 9.0);
        burst(10);
        assert_eq!(
            ctx.waiter.wait(Some(Duration::from_millis(20))).unwrap(),
            Wake::Timeout,
            "a sample on a polled input wakes nobody"
        );
        to_trigger.publish(Twist::default()).unwrap();
        assert_eq!(
            ctx.waiter.wait(Some(Duration::from_secs(5))).unwrap(),
            Wake::Data
        );
        assert_eq!(ctx.waiter.ready().collect::<Vec<_>>(), [trigger.id()]);
        assert_eq!(polled.latest().unwrap().unwrap().linear_x, 19.0);
        assert_eq!(polled.stats().dropped, 0, "overwritten samples are no loss");
        drop((trigger, polled, to_polled, to_trigger, ctx, peer));
        shm::remove_prefix_files(&prefix);
    }
}
