//! `contract-probe`: a generic, configurable contract module (the Manager, a provider, a
//! client, a driver, or several at once). The integration tests (`hng-testmod
//! contract-probe`) and `hng bench contracts` (`hng module contract-probe`) build the paper's
//! scenarios from it; its whole behaviour is in its `HNG_MODULE_CONFIG`:
//!
//! ```toml
//! manager = ["Robot integrity", "Human control"]       # objectives, mission order
//! provides = ["Localization", "Mapping"]                # data channel: "<id>/<service>"
//! needs = ["Odometry", "LIDAR data"]                    # ranks 1, 2, ... in this order
//! optional = ["LIDAR data"]                             # needs that are not required
//! quality = 0.8                                         # self-evaluated Q
//! true_quality = 0.8                                    # what clients measure in the data
//! evaluate = true                                       # send clients' evaluations E
//! q_channel = "probe/slam/q"                            # Twist.linear_x sets Q at run time
//! drive = ["Robot control"]                             # driver services (commands arbitrated)
//! commands = ["Robot control"]                          # needs we send Twist commands to
//! announce = "probe/manager/active"                     # Twist on activation changes
//! period_s = 0.01                                       # data/command period while active
//! ```
//!
//! Data of a provided service is an `Odometry` on the service's channel with
//! `pose.x = true_quality`, published every `period_s` while a client holds a contract for
//! that service (and at once when one starts). A client follows its providers' channels with
//! [`ProviderInput`] and, with `evaluate`, sends `E = pose.x` as its evaluation.

use std::collections::BTreeMap;
use std::time::Duration;

use hng_modules::common::{ConfigError, seconds};
use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer, Timing, Verdict};
use hng_runtime::control::{FollowProvider as _, ProviderInfo, ProviderInput, ProviderOutput};
use hng_runtime::msg::{Odometry, Pose2D, Twist};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber, TimerId};
use serde::Deserialize;

/// Protocol timing overrides, in seconds (0: the default).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TimingConfig {
    /// Reply window.
    pub reply_window_s: f64,
    /// Refresh period.
    pub refresh_s: f64,
    /// Peer timeout.
    pub peer_timeout_s: f64,
    /// Retry period.
    pub retry_s: f64,
    /// Probe period.
    pub probe_s: f64,
}

impl TimingConfig {
    fn timing(&self) -> Result<Timing, ConfigError> {
        let mut t = Timing::default();
        let set = |field: &str, v: f64, slot: &mut Duration| -> Result<(), ConfigError> {
            if v != 0.0 {
                *slot = seconds(field, v)?;
            }
            Ok(())
        };
        set(
            "timing.reply_window_s",
            self.reply_window_s,
            &mut t.reply_window,
        )?;
        set("timing.refresh_s", self.refresh_s, &mut t.refresh_period)?;
        set(
            "timing.peer_timeout_s",
            self.peer_timeout_s,
            &mut t.peer_timeout,
        )?;
        set("timing.retry_s", self.retry_s, &mut t.retry_period)?;
        set("timing.probe_s", self.probe_s, &mut t.probe_period)?;
        Ok(t)
    }
}

/// The probe's configuration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProbeConfig {
    /// Objectives: this module is the Manager.
    pub manager: Option<Vec<String>>,
    /// Provided services.
    pub provides: Vec<String>,
    /// Needed services, rank 1 first.
    pub needs: Vec<String>,
    /// Needs that are optional (penalty 0.2).
    pub optional: Vec<String>,
    /// Self-evaluated quality Q.
    pub quality: f64,
    /// The quality clients measure in the data (defaults to `quality`).
    pub true_quality: Option<f64>,
    /// Send evaluations of providers from their data.
    pub evaluate: bool,
    /// Channel whose `Twist.linear_x` sets Q (and `linear_y` the true quality).
    pub q_channel: String,
    /// Services this module drives (commands arbitrated by priority).
    pub drive: Vec<String>,
    /// Needs to which this module sends commands (`Twist`) instead of reading data.
    pub commands: Vec<String>,
    /// Channel on which activation changes are announced (`Twist.linear_x` = 1 or 0).
    pub announce: String,
    /// Publication period, s.
    pub period_s: f64,
    /// Protocol timing.
    pub timing: TimingConfig,
    /// Re-negotiation threshold.
    pub hysteresis: Option<f64>,
    /// Feedback validity time tau, s (0: the default).
    pub tau_s: f64,
}

impl Default for ProbeConfig {
    fn default() -> Self {
        ProbeConfig {
            manager: None,
            provides: Vec::new(),
            needs: Vec::new(),
            optional: Vec::new(),
            quality: 0.5,
            true_quality: None,
            evaluate: false,
            q_channel: String::new(),
            drive: Vec::new(),
            commands: Vec::new(),
            announce: String::new(),
            period_s: 0.02,
            timing: TimingConfig::default(),
            hysteresis: None,
            tau_s: 0.0,
        }
    }
}

struct Output {
    service: String,
    data: Option<Publisher<Odometry>>,
    commands: Option<Subscriber<Twist>>,
}

struct NeedPort {
    rank: u16,
    input: ProviderInput<Odometry>,
    command: ProviderOutput<Twist>,
    sends_commands: bool,
}

/// The probe module.
pub struct Probe {
    cfg: ProbeConfig,
    outputs: Vec<Output>,
    needs: Vec<NeedPort>,
    q_input: Option<Subscriber<Twist>>,
    announce: Option<Publisher<Twist>>,
    quality: f64,
    true_quality: f64,
    received: BTreeMap<u16, u64>,
}

impl Probe {
    fn publish_data(&mut self, ctx: &Context) -> ModuleResult {
        let Some(agent) = ctx.contracts() else {
            return Ok(());
        };
        for o in &self.outputs {
            let Some(p) = &o.data else { continue };
            if agent.client_contracts().any(|c| c.service == o.service) {
                p.publish(Odometry {
                    pose: Pose2D {
                        x: self.true_quality,
                        ..Default::default()
                    },
                    ..Default::default()
                })?;
            }
        }
        for n in &self.needs {
            if let Some(p) = n.command.publisher() {
                p.publish(Twist {
                    linear_x: 0.1,
                    ..Default::default()
                })?;
            }
        }
        Ok(())
    }
}

impl Module for Probe {
    type Config = ProbeConfig;

    fn configure(ctx: &mut Context, cfg: ProbeConfig) -> ModuleResult<Self> {
        let id = ctx.module_id();
        if let Some(objectives) = &cfg.manager {
            let o: Vec<&str> = objectives.iter().map(String::as_str).collect();
            ctx.manager(&o);
        }
        let mut outputs = Vec::new();
        for s in &cfg.provides {
            let offer = ServiceOffer::new(s.as_str(), "hng/Odometry/v1");
            let channel = offer.channel_for(id);
            ctx.provide(offer);
            let (data, commands) = if cfg.drive.contains(s) {
                ctx.drive(s, Duration::from_millis(300));
                (None, Some(ctx.subscribe::<Twist>(&channel, None)?))
            } else {
                (Some(ctx.publisher::<Odometry>(&channel)?), None)
            };
            outputs.push(Output {
                service: s.clone(),
                data,
                commands,
            });
        }
        let mut needs = Vec::new();
        for (s, rank) in cfg.needs.iter().zip(1u16..) {
            let spec = if cfg.optional.contains(s) {
                NeedSpec::optional(s.as_str(), rank, 0.2)
            } else {
                NeedSpec::required(s.as_str(), rank)
            };
            ctx.need(spec);
            needs.push(NeedPort {
                rank,
                input: ProviderInput::new(),
                command: ProviderOutput::new(),
                sends_commands: cfg.commands.contains(s),
            });
        }
        ctx.contract_timing(cfg.timing.timing()?);
        if let Some(h) = cfg.hysteresis {
            ctx.contract_hysteresis(h);
        }
        if cfg.tau_s != 0.0 {
            ctx.feedback_tau(seconds("tau_s", cfg.tau_s)?);
        }
        // Only a module with something to publish ticks: an empty configuration is the idle
        // module of `hng bench idle`.
        if outputs.iter().any(|o| o.data.is_some()) || needs.iter().any(|n| n.sends_commands) {
            ctx.add_timer(seconds("period_s", cfg.period_s)?);
        }
        ctx.set_quality(true, cfg.quality as f32);
        let q_input = if cfg.q_channel.is_empty() {
            None
        } else {
            Some(ctx.subscribe::<Twist>(&cfg.q_channel, None)?)
        };
        let announce = if cfg.announce.is_empty() {
            None
        } else {
            Some(ctx.publisher::<Twist>(&cfg.announce)?)
        };
        Ok(Probe {
            quality: cfg.quality,
            true_quality: cfg.true_quality.unwrap_or(cfg.quality),
            cfg,
            outputs,
            needs,
            q_input,
            announce,
            received: BTreeMap::new(),
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if let Some(q) = &self.q_input
            && q.id() == input
        {
            while let Some(t) = q.receive()? {
                self.quality = t.linear_x;
                if t.linear_y.is_finite() && t.linear_y != 0.0 {
                    self.true_quality = t.linear_y;
                }
            }
            ctx.set_quality(true, self.quality as f32);
            return Ok(());
        }
        for o in &self.outputs {
            if let Some(sub) = &o.commands
                && sub.id() == input
            {
                while let Some(cmd) = sub.receive()? {
                    // Only the most important live client moves the robot.
                    if ctx.command_verdict(&o.service, &cmd.header) == Verdict::Accept {
                        tracing::trace!(module = ctx.name(), v = cmd.linear_x, "command obeyed");
                    }
                }
                return Ok(());
            }
        }
        for n in &mut self.needs {
            if n.input.is(input) {
                let mut last = None;
                while let Some(s) = n.input.receive()? {
                    last = Some(s.pose.x);
                    *self.received.entry(n.rank).or_default() += 1;
                }
                if self.cfg.evaluate
                    && let Some(e) = last
                {
                    ctx.evaluate_provider(n.rank, e);
                }
            }
        }
        Ok(())
    }

    fn on_tick(&mut self, ctx: &mut Context, _t: TimerId) -> ModuleResult {
        self.publish_data(ctx)
    }

    fn on_activation(&mut self, ctx: &mut Context, active: bool) -> ModuleResult {
        tracing::debug!(module = ctx.name(), active, "activation");
        if let Some(a) = &self.announce {
            a.publish(Twist {
                linear_x: if active { 1.0 } else { 0.0 },
                ..Default::default()
            })?;
        }
        Ok(())
    }

    fn on_provider_changed(
        &mut self,
        ctx: &mut Context,
        need: u16,
        provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        tracing::debug!(module = ctx.name(), need, ?provider, "provider");
        let Some(n) = self.needs.iter_mut().find(|n| n.rank == need) else {
            return Ok(());
        };
        if n.sends_commands {
            // The publishers left are kept: going back to a driver opens no channel.
            n.command.follow(ctx, provider)?;
        } else {
            n.input.follow(ctx, provider)?;
        }
        Ok(())
    }

    fn on_contracts_changed(&mut self, ctx: &mut Context) -> ModuleResult {
        // A new client gets data at once, not one period later.
        self.publish_data(ctx)
    }
}
