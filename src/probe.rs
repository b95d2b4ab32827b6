//! `hng module heartbeat-probe`: the smallest useful module. It counts, checkpoints its count,
//! and publishes it as `Goal.id` on its output at once after start (so the first message of a
//! restarted probe marks the end of its recovery) and then every period. `hng bench recovery`
//! kills it; the built-in default system runs it until the mission modules exist.

use hng_runtime::msg::Goal;
use hng_runtime::{Context, Module, ModuleResult, Publisher, TimerId};
use serde::Deserialize;

/// Configuration (the `config` table of its launch-file entry).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProbeConfig {
    /// Channel of the count.
    pub output: String,
    /// Publishing period, ms.
    pub period_s: f64,
}

impl Default for ProbeConfig {
    fn default() -> Self {
        ProbeConfig {
            output: "probe/count".into(),
            period_s: 0.1,
        }
    }
}

/// The probe module.
pub struct Probe {
    count: u32,
    output: Publisher<Goal>,
}

impl Probe {
    fn publish(&mut self) -> ModuleResult {
        self.count = self.count.wrapping_add(1);
        self.output.publish(Goal {
            id: self.count,
            ..Default::default()
        })?;
        Ok(())
    }
}

impl Module for Probe {
    type Config = ProbeConfig;

    fn configure(ctx: &mut Context, cfg: ProbeConfig) -> ModuleResult<Self> {
        ctx.add_timer(hng_modules::common::seconds("period_s", cfg.period_s)?);
        Ok(Probe {
            count: 0,
            output: ctx.publisher(&cfg.output)?,
        })
    }

    fn start(&mut self, _ctx: &mut Context) -> ModuleResult {
        self.publish()
    }

    fn on_tick(&mut self, _ctx: &mut Context, _t: TimerId) -> ModuleResult {
        self.publish()
    }

    hng_runtime::checkpoint_field!(count);
}
