//! Status documents: the supervisor's, read (which modules run, their pids and states), and
//! the resource manager's own, written (JSON, `hng top`).

use hng_runtime::system::status::StatusDoc;

use super::*;

impl ResourceManager {
    /// The supervisor's status document (SUPERVISOR_STATUS, the runtime's typed
    /// [`StatusDoc`]): learns module names, pids, restarts and caps. A document that does not
    /// parse is ignored (one warning).
    pub fn on_supervisor_status(&mut self, doc: &[u8], now: Instant) {
        let doc: StatusDoc = match serde_json::from_slice(doc) {
            Ok(d) => d,
            Err(e) => {
                self.warn_once("bad-sup-status".into(), || {
                    format!("ignoring a supervisor status that does not parse: {e}")
                });
                return;
            }
        };
        let mut changed = Vec::new();
        for m in &doc.modules {
            let name = m.name.as_str();
            if name.is_empty() || name.len() > 200 {
                continue;
            }
            let caps = m.caps.as_ref();
            let limits = ResourceLimits {
                cpu_percent: caps
                    .and_then(|c| c.cpu_quota)
                    .map(|q| q * 100.0)
                    .filter(|c| c.is_finite() && *c > 0.0),
                memory_bytes: caps.and_then(|c| c.memory_max),
                ..Default::default()
            };
            if self.supervisor_limits.get(name) != Some(&limits) {
                self.supervisor_limits.insert(name.to_owned(), limits);
                changed.push(name.to_owned());
            }
            let t = self
                .modules
                .entry(name.to_owned())
                .or_insert_with(|| Tracked::new(name));
            t.restarts = Some(u64::from(m.restarts));
            t.supervisor_state = Some(m.state.clone());
            if let Some(pid) = m.pid.and_then(|p| i32::try_from(p).ok())
                && t.pid.is_none()
                && t.refused_pid != u32::try_from(pid).ok()
            {
                // Not reported yet: sample the supervisor's pid (checked by start time
                // from now on).
                let name = name.to_owned();
                self.adopt(&name, pid, None, now);
            }
        }
        for name in changed {
            if self.modules.get(&name).is_some_and(|t| t.pid.is_some()) {
                let req = self.requested_limits(&name);
                self.apply_limits(&name, req);
            }
        }
    }

    pub(super) fn status_json(
        &self,
        own: &BTreeMap<u32, (String, ResourceVec)>,
        eff: &HashMap<u32, ResourceVec>,
        decision: &crate::degraded::RmDecision<Priority>,
        obs: &ResourceObservation,
        waiting_reports: u64,
        active: &[Priority],
    ) -> Value {
        let mut modules = Vec::with_capacity(self.modules.len());
        for (name, t) in &self.modules {
            let s = self.sampler.get(name).filter(|_| t.pid.is_some());
            let r = own.get(&t.id).map_or(ResourceVec::ZERO, |(_, r)| *r);
            let e = eff.get(&t.id).copied().unwrap_or(r);
            let cap = |requested: Option<f64>, kernel: Option<f64>, enf: Option<Enforced>| {
                json!({
                    "limit": requested,
                    "kernel": kernel,
                    "enforced": enf.map(Enforced::as_str),
                })
            };
            modules.push(json!({
                "name": name,
                "id": t.id,
                "pid": t.pid,
                "alive": s.is_some_and(|s| s.liveness == Liveness::Alive),
                "state": t.state.map(state_text),
                "supervisor_state": t.supervisor_state,
                "restarts": t.restarts,
                "quality": t.quality,
                "waiting_for_resources": t.waiting,
                "cpu_percent": s.and_then(|s| s.cpu_percent),
                "cpu_source": s.map(|s| match s.cpu_source {
                    CpuSource::ProcStat => "proc",
                    CpuSource::Cgroup => "cgroup",
                }),
                "rss_bytes": s.map(|s| s.rss_bytes),
                "pss_bytes": s.and_then(|s| s.pss_bytes),
                "memory_bytes": s.map(ModuleSample::memory_bytes),
                "minor_faults": s.map(|s| s.minor_faults),
                "major_faults": s.map(|s| s.major_faults),
                "major_faults_per_s": s.and_then(|s| s.major_faults_per_s),
                "msgs_per_s": t.msg_rate,
                "cgroup": t.cgroup.is_some(),
                "caps": {
                    "cpu_percent": cap(t.requested.cpu_percent, t.kernel.cpu_percent, t.cpu_enforced),
                    "memory_bytes": cap(t.requested.memory_bytes.map(|b| b as f64), t.kernel.memory_bytes.map(|b| b as f64), t.mem_enforced),
                    "pids": t.kernel.pids,
                },
                "over_limit": t.last_over.as_ref().map(|(_, _, r)| r),
                "R": [r.cpu, r.memory, r.comm],
                "R_eff": [e.cpu, e.memory, e.comm],
            }));
        }
        let sys = self.last_system;
        let u = &decision.cost_update;
        json!({
            "rate_hz": self.config.rate_hz,
            "passes": self.passes,
            "cgroups": self.cgroup_note,
            "cpus": sys.map(|s| s.cpus),
            "cpu_free": obs.cpu_free,
            "own_cpu_share": obs.own_cpu_share,
            "memory_free": obs.memory_free,
            "mem_available_bytes": sys.map(|s| s.mem_available_bytes),
            "mem_total_bytes": sys.map(|s| s.mem_total_bytes),
            "max_report_delay_ms": self.last_delay.map(|d| d.as_secs_f64() * 1e3),
            "waiting_reports": waiting_reports,
            "costs": {"cpu": u.costs.cpu, "memory": u.costs.memory, "comm": u.costs.comm},
            "scarce": {"cpu": u.scarce.cpu, "memory": u.scarce.memory, "comm": u.scarce.comm},
            "real_scarcity": u.hard_at_max,
            "degraded": decision.bar.is_degraded(),
            "serve_nothing": matches!(decision.bar, ServeBar::Nothing),
            "min_priority": match &decision.bar {
                ServeBar::AtMost(p) => Some(p.to_string()),
                _ => None,
            },
            "active_contracts": active.len(),
            "contract_tables": self.tables.len(),
            "modules": modules,
        })
    }
}

pub(super) fn state_text(s: ModuleState) -> &'static str {
    match s {
        ModuleState::Configured => "configured",
        ModuleState::Running => "running",
        ModuleState::Idle => "idle",
        ModuleState::Stopping => "stopping",
    }
}

/// The degraded-mode bar as text: "all", "nothing" or the minimum priority.
#[must_use]
pub fn bar_text(bar: &ServeBar<Priority>) -> String {
    match bar {
        ServeBar::All => "all".into(),
        ServeBar::Nothing => "nothing".into(),
        ServeBar::AtMost(p) => p.to_string(),
    }
}

/// A reason that fits the supervisor command's 64 bytes: "memory 80.0 MiB > 64.0 MiB",
/// "cpu 93% > 20%".
pub(super) fn short_reason(v: &crate::limits::OverLimit) -> String {
    match v.resource {
        crate::limits::LimitedResource::Memory => format!(
            "memory {:.1} MiB > {:.1} MiB",
            v.measured / 1048576.0,
            v.limit / 1048576.0
        ),
        crate::limits::LimitedResource::Cpu => {
            format!("cpu {:.0}% > {:.0}%", v.measured, v.limit)
        }
    }
}
