//! The executor: the process around a module ([`run_module`]), its loop of inputs, timers,
//! deadlines, reports, checkpoints and contract events, until a stop.

use super::*;

/// Runs module `M` as this process, configured from the environment; returns the exit code.
pub fn run_module<M: Module>() -> ExitCode {
    run_module_env::<M>(false)
}

/// [`run_module`] on the wall clock whatever `HNG_CLOCK` says (a simulated system sets it
/// for every module): for processes outside simulated time, such as the simulator (the
/// clock's source) and the resource manager (it measures wall-clock CPU, and following the
/// simulation clock would wake it for every clock sample).
pub fn run_module_on_wall_clock<M: Module>() -> ExitCode {
    run_module_env::<M>(true)
}

fn run_module_env<M: Module>(wall_clock: bool) -> ExitCode {
    init_tracing();
    if let Err(e) = crate::fatal::install() {
        tracing::warn!("fatal-signal handler not installed: {e}");
    }
    let default_name = std::env::args()
        .next()
        .and_then(|a| {
            std::path::Path::new(&a)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
        })
        .unwrap_or_else(|| "module".into());
    let mut opts = match RunOptions::from_env(&default_name) {
        Ok(o) => o,
        Err(e) => {
            tracing::error!("{e}");
            return ExitCode::from(2);
        }
    };
    if wall_clock {
        opts.clock = ClockMode::Wall;
    }
    let result = run_module_with::<M>(&opts);
    // Started without a supervisor, the module is the last of its prefix: its files go too.
    crate::shm::remove_system_files_if_alone(&opts.prefix);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!(module = %opts.name, "{e}");
            ExitCode::from(1)
        }
    }
}

/// Runs module `M` with explicit options (tests, embedding); returns on a clean stop.
pub fn run_module_with<M: Module>(opts: &RunOptions) -> Result<(), RunError> {
    let mut phases = StartPhases::new();
    let config: M::Config = if opts.config_toml.trim().is_empty() {
        M::Config::default()
    } else {
        toml::from_str(&opts.config_toml).map_err(|e| RunError::Config {
            module: opts.name.clone(),
            detail: super::renamed_to_seconds(e.message()).unwrap_or_else(|| e.to_string()),
        })?
    };
    let clock = match opts.clock {
        ClockMode::Wall => Clock::wall(),
        ClockMode::Sim => Clock::sim(),
    };
    let node = Node::new(
        NodeOptions::new(&opts.name)
            .prefix(&opts.prefix)
            .clock(clock.clone()),
    )?;
    phases.mark("node");
    let mut ctx = Context::new(node, opts.wait)?;
    if opts.catch_signals {
        ctx.waiter.catch_termination_signals()?;
    }
    // The simulation clock, its rounds and our answers (see module/rounds.rs).
    let mut rounds = if clock.is_sim() {
        let r = Rounds::new(&ctx.node, opts.catch_signals)?;
        ctx.waiter.attach(&r.common)?;
        Some(r)
    } else {
        None
    };
    let reports = ctx.node.publisher::<ModuleReport>(REPORT_CHANNEL)?;
    phases.mark("clock_and_report");
    let store = opts
        .checkpoint_dir
        .as_deref()
        .and_then(|dir| Checkpoints::open(dir, &opts.name));

    let module_err = |stage, source| RunError::Module {
        module: opts.name.clone(),
        stage,
        source,
    };
    let mut module = M::configure(&mut ctx, config).map_err(|e| module_err("configure", e))?;
    phases.mark("configure");
    if let Some(store) = &store {
        store
            .restore(&mut module, &opts.name)
            .map_err(|e| module_err("restore", e))?;
    }
    phases.mark("restore");
    ctx.state = ModuleState::Running;
    module.start(&mut ctx).map_err(|e| module_err("start", e))?;
    phases.mark("start");
    if let Some(h) = &opts.harness {
        h.serve(&mut module, &mut ctx);
    } else if ctx.contract_spec.declared() {
        let plane = ControlPlane::new(&ctx.node, &mut ctx.waiter, &ctx.contract_spec)
            .map_err(|e| module_err("contracts", Box::new(e)))?;
        let manager = plane.agent().config().manager;
        ctx.plane = Some(plane);
        if manager && let Err(e) = module.on_activation(&mut ctx, true) {
            tracing::warn!(module = %opts.name, "on_activation: {e}");
        }
        if !clock.is_sim() || clock.now_ns() > 0 {
            poll_contracts(&mut module, &mut ctx, &opts.name);
        }
    }

    let report_ns = opts.report_period.as_nanos() as u64;
    let checkpoint_ns = opts.checkpoint_period.as_nanos() as u64;
    phases.mark("contracts");
    let _ = reports.publish(ctx.report(report_ns));
    phases.done(&opts.name);
    // The heartbeat, stretched while the module has nothing to do (module/beat.rs). A
    // module on the simulation clock is woken by rounds (or clock samples) anyway: its
    // report and its checkpoint wait up to half their period for one of those wake-ups
    // instead of waking it on their own.
    let slack = |period_ns: u64| if clock.is_sim() { period_ns / 2 } else { 0 };
    let mut beat = Beat::new(
        report_ns,
        opts.idle_report_period.as_nanos() as u64,
        monotonic_ns(),
    )
    .with_slack(slack(report_ns));
    let checkpoint_slack_ns = slack(checkpoint_ns);
    let mut next_checkpoint = monotonic_ns().saturating_add(checkpoint_ns);
    // A module's state changes only in its callbacks: while none ran since the last
    // checkpoint, the next one would be the same (and is not written: module/checkpoints.rs),
    // so the module is not woken for it.
    let mut worked = true;
    let clock_id = rounds.as_ref().map(|r| r.common.id());
    while !ctx.stop_requested && !opts.harness.as_ref().is_some_and(Hooks::stopped) {
        // Wall-clock wake-ups: report and checkpoint; clock-time ones: timers and deadlines
        // (in simulation they are checked at every clock sample instead).
        let wall_now = monotonic_ns();
        let mut wake_at = beat.next_ns();
        if store.is_some() && worked {
            wake_at = wake_at.min(next_checkpoint.saturating_add(checkpoint_slack_ns));
        }
        // When a timer or an input deadline is due (wall clock): work, not idleness.
        let mut work_at = u64::MAX;
        if !clock.is_sim() {
            let in_ns = ctx.next_due_ns().saturating_sub(clock.now_ns());
            work_at = wall_now.saturating_add(in_ns);
            wake_at = wake_at.min(work_at);
        }
        let timeout = Duration::from_nanos(wake_at.saturating_sub(wall_now));
        // Between answering a round and being called to the next one, inputs wait: they
        // belong to the next round (that waiter watches only the clock, and the signals).
        let waiter = match rounds.as_mut() {
            Some(r) if r.holds() => &mut r.waiter,
            _ => &mut ctx.waiter,
        };
        let woke = waiter.wait(Some(timeout))?;
        let mut reported = 0;
        if let Wake::Signal(sig) = woke {
            tracing::info!(module = %opts.name, signal = sig, "stopping on signal");
            break;
        }
        // Woken by an input (a round in simulation) or a timer: the module is not idle, and
        // a stretched heartbeat goes back to its period before the work (module/beat.rs).
        let woke_at = monotonic_ns();
        if (woke == Wake::Data || woke_at >= work_at)
            && let Some(period) = beat.work(woke_at)
        {
            match reports.publish(ctx.report(period)) {
                Ok(()) => reported += 1,
                Err(e) => tracing::warn!(module = %opts.name, "report: {e}"),
            }
        }

        ctx.node.update_connections();
        if let Some(r) = rounds.as_mut()
            && r.read(&ctx.node)?
        {
            // Called on its own channel from now on: the common one wakes it no more.
            ctx.waiter.detach(r.common.id())?;
        }
        let now = clock.now_ns();
        if !rounds.as_ref().is_some_and(Rounds::holds) {
            worked = true;
            let ready: Vec<InputId> = ctx
                .waiter
                .ready()
                .filter(|id| Some(*id) != clock_id)
                .filter(|id| !ctx.plane.as_ref().is_some_and(|p| p.owns(*id)))
                .collect();
            // In simulated time, contracts are negotiated from the first simulated instant on (a
            // paused start negotiates nothing), so the order in which processes came up does not
            // shape the contract tree.
            if !clock.is_sim() || now > 0 {
                poll_contracts(&mut module, &mut ctx, &opts.name);
            }
            for id in ready {
                for d in ctx.deadlines.iter_mut().filter(|d| d.input == id) {
                    d.last_ns = now;
                    d.missed = false;
                }
                if let Err(e) = module.on_input(&mut ctx, id) {
                    tracing::warn!(module = %opts.name, "on_input: {e}");
                }
            }
            for i in 0..ctx.timers.len() {
                let t = &mut ctx.timers[i];
                if now >= t.next_ns {
                    // Skip missed periods rather than firing a burst.
                    let behind = (now - t.next_ns) / t.period_ns;
                    t.next_ns = t.next_ns.saturating_add((behind + 1) * t.period_ns);
                    if let Err(e) = module.on_tick(&mut ctx, TimerId(i)) {
                        tracing::warn!(module = %opts.name, "on_tick: {e}");
                    }
                }
            }
            let mut missed = Vec::new();
            for d in ctx.deadlines.iter_mut() {
                if !d.missed && now.saturating_sub(d.last_ns) > d.deadline_ns {
                    d.missed = true;
                    missed.push(d.input);
                }
            }
            for id in missed {
                ctx.deadline_misses += 1;
                if let Err(e) = module.on_deadline_missed(&mut ctx, id) {
                    tracing::warn!(module = %opts.name, "on_deadline_missed: {e}");
                }
            }
        }
        let wall_now = monotonic_ns();
        if let Some(store) = &store
            && worked
            && wall_now >= next_checkpoint
        {
            worked = false;
            next_checkpoint = wall_now.saturating_add(checkpoint_ns);
            save_checkpoint(&module, store, &mut ctx, &opts.name);
        }
        if let Some(period) = beat.due(wall_now) {
            match reports.publish(ctx.report(period)) {
                Ok(()) => reported += 1,
                Err(e) => tracing::warn!(module = %opts.name, "report: {e}"),
            }
        }
        // Lockstep: the round's answer. Only what the module published can give another one
        // work; handling an input or a timer without publishing leaves nothing in flight.
        if let Some(r) = rounds.as_mut() {
            let due = ctx.next_due_ns();
            r.answer(&ctx.node, &ctx.waiter, reported, due)?;
        }
    }

    ctx.state = ModuleState::Stopping;
    tracing::debug!(module = %opts.name, stats = ?ctx.waiter.stats(), "waiter");
    module.stop(&mut ctx);
    if let Some(p) = ctx.plane.as_mut() {
        let now = ctx.node.clock().now();
        p.shutdown(&ctx.node, now);
    }
    if let Some(store) = &store {
        save_checkpoint(&module, store, &mut ctx, &opts.name);
    }
    let _ = reports.publish(ctx.report(beat.normal_ns()));
    Ok(())
}

/// Runs the contract plane once and hands its events to the module's callbacks.
fn poll_contracts<M: Module>(module: &mut M, ctx: &mut Context, name: &str) {
    let Some(plane) = ctx.plane.as_mut() else {
        return;
    };
    let now = ctx.node.clock().now();
    plane.poll(&ctx.node, ctx.aptitude, f64::from(ctx.quality), now);
    let events = plane.take_events(now);
    for ev in events {
        let r = match &ev {
            PlaneEvent::Activation(active) => module.on_activation(ctx, *active),
            PlaneEvent::Provider(need, info) => {
                module.on_provider_changed(ctx, *need, info.as_ref())
            }
            PlaneEvent::ContractsChanged => module.on_contracts_changed(ctx),
        };
        if let Err(e) = r {
            tracing::warn!(module = %name, event = ?ev, "contract callback: {e}");
        }
    }
}

/// Wall time of each stage of a module's start, up to its first report (the supervisor's
/// "running"), logged at debug level: where a system's start-up goes (docs/navigation.md).
struct StartPhases {
    at: std::time::Instant,
    marks: Vec<(&'static str, Duration)>,
}

impl StartPhases {
    fn new() -> Self {
        Self {
            at: std::time::Instant::now(),
            marks: Vec::new(),
        }
    }

    fn mark(&mut self, stage: &'static str) {
        let now = std::time::Instant::now();
        self.marks.push((stage, now - self.at));
        self.at = now;
    }

    fn done(&self, module: &str) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let total: Duration = self.marks.iter().map(|(_, d)| *d).sum();
        // The process's own CPU time so far (the stages' wall times include waiting for a
        // core on a loaded machine; this does not).
        let cpu_ms = nix::sys::resource::getrusage(nix::sys::resource::UsageWho::RUSAGE_SELF)
            .map(|u| {
                let t = |v: nix::sys::time::TimeVal| {
                    v.tv_sec() as f64 * 1e3 + v.tv_usec() as f64 * 1e-3
                };
                t(u.user_time()) + t(u.system_time())
            })
            .unwrap_or(f64::NAN);
        let stages: Vec<String> = self
            .marks
            .iter()
            .map(|(s, d)| format!("{s} {:.1}", d.as_secs_f64() * 1e3))
            .collect();
        tracing::debug!(
            module,
            total_ms = total.as_secs_f64() * 1e3,
            cpu_ms,
            "start-up stages (ms): {}",
            stages.join(", ")
        );
    }
}
