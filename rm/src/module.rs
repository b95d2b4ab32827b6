//! The resource manager as an hng module (`hng module rm`): one per computer, started and
//! watched by the supervisor like any module.
//!
//! Inputs: every module's report (`hng/report`, read as it arrives), the contract tables
//! (`hng/contracts`) and the supervisor's status (`hng/supervisor/status`), both polled:
//! read at each period (and with the reports), not woken for. Each period (`rate_hz`) it runs
//! [`ResourceManager::tick`] and publishes C_R(t) and the minimum priority on
//! [`RM_COSTS`], R and R_eff on [`RM_EFFECTIVE_COSTS`], its JSON status on [`RM_STATUS`],
//! and an [`CommandOp::OverLimit`] command on [`SUPERVISOR_COMMAND`] for a module over a
//! limit the kernel does not enforce. `HNG_CGROUP_RUN` names the cgroup run the
//! supervisor placed the modules in.

use std::time::Instant;

use hng_runtime::channel::InputId;
use hng_runtime::clock::monotonic_ns;
use hng_runtime::module::REPORT_CHANNEL;
use hng_runtime::msg::ModuleReport;
use hng_runtime::system::{
    CONTRACTS, CommandOp, ContractTable, EffectiveCosts, JsonInfo, RM_COSTS, RM_EFFECTIVE_COSTS,
    RM_STATUS, ResourceCosts, SUPERVISOR_COMMAND, SUPERVISOR_STATUS, SupervisorCommand,
};
use hng_runtime::{
    Context, Module, ModuleResult, Publisher, SlicePublisher, SliceSubscriber, Subscriber, TimerId,
};

use crate::manager::{ResourceManager, RmConfig};

/// Environment variable naming the cgroup run (`<system>-<run id>`) of the system.
pub const CGROUP_RUN_ENV: &str = "HNG_CGROUP_RUN";

/// The resource manager module.
pub struct RmModule {
    rm: ResourceManager,
    reports: Subscriber<ModuleReport>,
    tables: Subscriber<ContractTable>,
    supervisor: SliceSubscriber<JsonInfo>,
    costs: Publisher<ResourceCosts>,
    effective: Publisher<EffectiveCosts>,
    status: SlicePublisher<JsonInfo>,
    commands: Publisher<SupervisorCommand>,
    json: Vec<u8>,
}

impl std::fmt::Debug for RmModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RmModule").finish_non_exhaustive()
    }
}

impl RmModule {
    fn drain(&mut self) -> ModuleResult {
        let now = Instant::now();
        while let Some(r) = self.reports.receive()? {
            self.rm.on_report(&r, monotonic_ns(), now);
        }
        while let Some(t) = self.tables.receive()? {
            self.rm.on_contract_table(&t, now);
        }
        if let Some(s) = self.supervisor.latest()? {
            self.rm.on_supervisor_status(s.data(), now);
        }
        Ok(())
    }
}

impl Module for RmModule {
    type Config = RmConfig;

    fn configure(ctx: &mut Context, config: RmConfig) -> ModuleResult<Self> {
        let run = std::env::var(CGROUP_RUN_ENV).ok().filter(|s| !s.is_empty());
        let period = config.period();
        let rm = ResourceManager::new(config, run.as_deref())?;
        ctx.add_timer(period);
        Ok(RmModule {
            rm,
            // Every report is read when it arrives: its delay is the comm scarcity signal.
            reports: ctx.subscribe(REPORT_CHANNEL, None)?,
            // The contract tables (every module's, every 0.2 s) and the supervisor's status
            // only count at the next period: read then, without a wake-up each.
            tables: ctx.subscribe_polled(CONTRACTS)?,
            supervisor: ctx.subscribe_slice_polled(SUPERVISOR_STATUS)?,
            costs: ctx.publisher(RM_COSTS)?,
            effective: ctx.publisher(RM_EFFECTIVE_COSTS)?,
            status: ctx.slice_publisher(RM_STATUS, 16 * 1024)?,
            commands: ctx.publisher(SUPERVISOR_COMMAND)?,
            json: Vec::with_capacity(16 * 1024),
        })
    }

    fn on_input(&mut self, _ctx: &mut Context, _input: InputId) -> ModuleResult {
        self.drain()
    }

    fn on_tick(&mut self, _ctx: &mut Context, _timer: TimerId) -> ModuleResult {
        // Reports that arrived since the last callback count for this period.
        self.drain()?;
        let out = self.rm.tick(Instant::now());
        for c in &out.over_limit {
            let cmd =
                SupervisorCommand::new(CommandOp::OverLimit, &c.module).with_reason(&c.reason);
            self.commands.publish(cmd)?;
        }
        self.costs.publish(out.costs)?;
        let mut loan = self.effective.loan()?;
        *loan = out.effective;
        loan.publish()?;
        self.json.clear();
        serde_json::to_writer(&mut self.json, &out.status)?;
        self.status.publish_copy(JsonInfo::default(), &self.json)?;
        Ok(())
    }
}
