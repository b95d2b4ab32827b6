//! What `hng run` adds to every spawn and restart: the module's environment, its cgroup
//! (placement before exec, caps), the clean-up of a dead process's iceoryx2 resources, and
//! the OOM read-back.

use std::collections::HashMap;
use std::io;
use std::os::unix::process::CommandExt;
use std::process::Command;
use std::rc::Rc;

use hng_rm::cgroup::{CgroupRun, ModuleCgroup};
use hng_rm::limits::{AppliedLimits, ResourceLimits};
use hng_runtime::Node;
use hng_watchdog::{ModuleSpec, SupervisorHooks};

/// The hooks of `hng run`'s supervisor.
pub struct RunHooks {
    /// The supervisor's node: its iceoryx2 handle cleans dead nodes.
    pub node: Rc<Node>,
    /// The run's cgroups (`None`: not even the directories could be created).
    pub cgroup_run: Option<CgroupRun>,
    /// Module cgroups, created at first spawn; with the OOM-kill count seen at the last spawn.
    pub cgroups: HashMap<String, (ModuleCgroup, Option<u64>)>,
    /// Each module's caps and who enforces them (for the status document), set at its
    /// first spawn.
    pub caps: HashMap<String, Option<super::status::CapsRow>>,
    /// A resource manager runs: caps the kernel does not enforce are checked by it.
    pub software_enforcer: bool,
}

impl RunHooks {
    fn cgroup(&mut self, module: &ModuleSpec) -> Option<&mut (ModuleCgroup, Option<u64>)> {
        if !self.caps.contains_key(&module.name) {
            let cg = match self.cgroup_run.as_ref().map(|run| run.module(&module.name)) {
                Some(Ok(cg)) => Some(cg),
                Some(Err(e)) => {
                    tracing::warn!(module = %module.name, "no cgroup for the module: {e}");
                    None
                }
                None => None,
            };
            let r = &module.resources;
            let limits = ResourceLimits {
                cpu_percent: r.cpu_quota.map(|q| q * 100.0),
                memory_bytes: r.memory_max,
                memory_high_bytes: None,
                pids: r.pids_max,
            };
            // A cap the kernel refuses is a warning from the cgroup layer naming the
            // fallback; here it goes to the status, where the resource manager reads
            // it and checks it in software.
            let applied = match &cg {
                Some(cg) if limits != ResourceLimits::default() => cg.apply_limits(&limits),
                _ => AppliedLimits::all_software(&limits, "no cgroup for the module"),
            };
            let row = super::status::caps_row(r, &applied, self.software_enforcer);
            if let Some(row) = &row {
                for f in &row.fallback {
                    if self.software_enforcer {
                        tracing::info!(module = %module.name, "cap {f}");
                    } else {
                        tracing::warn!(module = %module.name, "cap {f}");
                    }
                }
            }
            self.caps.insert(module.name.clone(), row);
            if let Some(cg) = cg {
                self.cgroups.insert(module.name.clone(), (cg, None));
            }
        }
        self.cgroups.get_mut(&module.name)
    }

    /// Cleans the iceoryx2 resources of every dead process of the system (the dead module's
    /// node, its ports in every service), so a restarted module reopens its services at once
    /// and no publisher keeps a dead subscriber.
    pub fn clean_dead_nodes(&self) {
        let t0 = std::time::Instant::now();
        let state = self.node.iceoryx().try_cleanup_dead_nodes();
        if state.cleanups > 0 || state.failed_cleanups > 0 {
            tracing::debug!(
                cleaned = state.cleanups,
                failed = state.failed_cleanups,
                took = ?t0.elapsed(),
                "dead iceoryx2 nodes cleaned"
            );
        }
    }

    /// Kills what is left in the module cgroups and removes them, then the run's cgroup.
    pub fn remove_cgroups(&mut self) {
        for (name, (cg, _)) in self.cgroups.drain() {
            if cg.is_real() {
                if let Err(e) = cg.kill_all() {
                    tracing::warn!(module = %name, "killing the cgroup's processes: {e}");
                }
                if let Err(e) = cg.remove() {
                    tracing::warn!(module = %name, "removing the module's cgroup: {e}");
                }
            }
        }
        if let Some(run) = self.cgroup_run.take()
            && let Err(e) = run.remove()
        {
            tracing::warn!("removing the run's cgroup: {e}");
        }
    }
}

impl SupervisorHooks for RunHooks {
    fn before_spawn(&mut self, module: &ModuleSpec, command: &mut Command) -> io::Result<()> {
        if !module.config.is_empty() {
            command.env("HNG_MODULE_CONFIG", &module.config);
        }
        if let Some(hb) = module.heartbeat {
            // The runtime's report period is the heartbeat.
            command.env(
                "HNG_REPORT_PERIOD_MS",
                hb.period.as_millis().max(1).to_string(),
            );
        }
        if let Some((cg, oom_before)) = self.cgroup(module) {
            *oom_before = cg.oom_kills().ok().flatten();
            if cg.is_real() {
                let placement = cg.placement().map_err(io::Error::other)?;
                // SAFETY: place_self is async-signal-safe (getpid and write on descriptors
                // opened before the fork, no allocation).
                unsafe {
                    command.pre_exec(move || placement.place_self());
                }
            }
        }
        Ok(())
    }

    fn before_restart(&mut self, _module: &ModuleSpec, _dead_pid: u32) {
        self.clean_dead_nodes();
    }

    fn oom_killed(&mut self, module: &ModuleSpec, _pid: u32) -> bool {
        let Some((cg, before)) = self.cgroups.get(&module.name) else {
            return false;
        };
        match cg.oom_kills() {
            Ok(Some(now)) => now > before.unwrap_or(0),
            _ => false,
        }
    }
}
