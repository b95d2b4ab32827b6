//! Status documents: the supervisor's, read (which modules run, their pids and states), and
//! the resource manager's own, written (JSON, `hng top`).

use super::*;

impl ResourceManager {
    /// The supervisor's status document (SUPERVISOR_STATUS): learns module names, pids,
    /// restarts and caps. Unknown shapes are ignored (one warning).
    pub fn on_supervisor_status(&mut self, doc: &[u8], now: Instant) {
        let v: Value = match serde_json::from_slice(doc) {
            Ok(v) => v,
            Err(e) => {
                self.warn_once("bad-sup-status".into(), || {
                    format!("ignoring a supervisor status that is not JSON: {e}")
                });
                return;
            }
        };
        let list = v
            .get("modules")
            .and_then(Value::as_array)
            .or_else(|| v.as_array());
        let Some(list) = list else {
            return;
        };
        let mut changed = Vec::new();
        for m in list {
            let Some(name) = m.get("name").and_then(Value::as_str) else {
                continue;
            };
            if name.is_empty() || name.len() > 200 {
                continue;
            }
            let caps = ["caps", "resources", "limits"]
                .iter()
                .find_map(|k| m.get(*k))
                .unwrap_or(&Value::Null);
            let cpu = caps
                .get("cpu_percent")
                .and_then(Value::as_f64)
                .or_else(|| {
                    caps.get("cpu_quota")
                        .and_then(Value::as_f64)
                        .map(|q| q * 100.0)
                })
                .filter(|c| c.is_finite() && *c > 0.0);
            let mem = caps
                .get("memory_max")
                .or_else(|| caps.get("memory_bytes"))
                .and_then(Value::as_u64);
            let limits = ResourceLimits {
                cpu_percent: cpu,
                memory_bytes: mem,
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
            t.restarts = m.get("restarts").and_then(Value::as_u64);
            t.supervisor_state = m.get("state").and_then(Value::as_str).map(str::to_owned);
            let pid = m
                .get("pid")
                .and_then(Value::as_i64)
                .and_then(|p| i32::try_from(p).ok());
            if let Some(pid) = pid
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
