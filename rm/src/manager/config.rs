//! The resource manager's configuration (`HNG_MODULE_CONFIG` of `hng module rm`).

use super::*;

/// A byte count in the configuration: an integer, or a string such as `"512MiB"`,
/// `"64M"`, `"1GB"` (K/M/G/T and KiB/MiB/GiB/TiB are powers of 1024, kB/MB/GB/TB of
/// 1000).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(try_from = "ByteText")]
pub struct Bytes(pub u64);

#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum ByteText {
    N(u64),
    S(String),
}

impl TryFrom<ByteText> for Bytes {
    type Error = String;
    fn try_from(v: ByteText) -> std::result::Result<Self, String> {
        match v {
            ByteText::N(n) => Ok(Bytes(n)),
            ByteText::S(s) => parse_bytes(&s).map(Bytes),
        }
    }
}

/// Parses `"512MiB"`, `"64M"`, `"1GB"`, `"4096"`.
pub fn parse_bytes(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let n: f64 = num
        .parse()
        .map_err(|_| format!("{s:?} is not a byte count (e.g. 4096, \"64MiB\", \"1GB\")"))?;
    let k: f64 = match unit.trim() {
        "" | "B" => 1.0,
        "K" | "KiB" => 1024.0,
        "M" | "MiB" => 1024.0 * 1024.0,
        "G" | "GiB" => 1024.0 * 1024.0 * 1024.0,
        "T" | "TiB" => 1024.0f64.powi(4),
        "kB" | "KB" => 1e3,
        "MB" => 1e6,
        "GB" => 1e9,
        "TB" => 1e12,
        u => {
            return Err(format!(
                "unknown unit {u:?} in {s:?} (K, M, G, T, KiB, MB, ...)"
            ));
        }
    };
    let v = n * k;
    if !(v.is_finite() && v >= 0.0 && v < u64::MAX as f64) {
        return Err(format!("{s:?} is out of range"));
    }
    Ok(v.round() as u64)
}

/// Limits of one module in the RM configuration.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LimitConfig {
    /// CPU in % of one core (100 = one core).
    pub cpu_percent: Option<f64>,
    /// Memory (PSS when known, else RSS).
    pub memory_max: Option<Bytes>,
}

impl LimitConfig {
    pub(super) fn to_limits(&self) -> ResourceLimits {
        ResourceLimits {
            cpu_percent: self.cpu_percent.filter(|c| c.is_finite() && *c > 0.0),
            memory_bytes: self.memory_max.map(|b| b.0),
            ..Default::default()
        }
    }
}

/// The RM's configuration (the `config` table of its launch-file entry). Every field has
/// a default; see each.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RmConfig {
    /// Sampling and publishing rate, Hz (default 10).
    pub rate_hz: f64,
    /// Refresh PSS every this many passes (default 50; 0 = RSS only).
    pub pss_every: u32,
    /// CPU is scarce under this free fraction of the machine (default 0.10) when the
    /// system's modules use at least `cpu_own_share_min` of the busy CPU.
    pub cpu_free_threshold: f64,
    /// See [`CostConfig::cpu_own_share_min`] (default 0.5; 0: any load counts).
    pub cpu_own_share_min: f64,
    /// Memory is scarce under this free fraction (default 0.10).
    pub memory_free_threshold: f64,
    /// Communication is scarce when a report took longer than this, s (default 0.02).
    pub comm_delay_threshold_s: f64,
    /// Lowest cost (default 0.1; see [`CostConfig`] for the scale).
    pub cost_min: f64,
    /// Highest cost (default 1.6).
    pub cost_max: f64,
    /// Raise factor per period while scarce (default 2).
    pub cost_raise_factor: f64,
    /// Decay factor per period otherwise (default 0.8).
    pub cost_lower_factor: f64,
    /// Periods under pressure at maximal cost before degraded mode (default 3).
    pub degraded_enter_after: u32,
    /// Periods still under pressure before cutting the next level (default 3).
    pub degraded_step_after: u32,
    /// Calm periods before restoring one level (default 10).
    pub degraded_recover_after: u32,
    /// Whether the most important work may be stopped too (default false).
    pub allow_full_stop: bool,
    /// Time constant of the CPU average the software CPU limit is checked on, s
    /// (default 2).
    pub cpu_window_s: f64,
    /// Message rate (in + out, per s) that counts as one whole "communication
    /// resource" in R (default 10000).
    pub comm_budget_msgs_per_s: f64,
    /// A module whose process is gone and that has not reported for this long is
    /// forgotten, s (default 5).
    pub forget_after_s: f64,
    /// A contract table older than this is ignored, s (default 3).
    pub table_timeout_s: f64,
    /// An over-limit command for the same process is repeated after this long if the
    /// module keeps running (no supervisor acted), s (default 2).
    pub over_limit_repeat_s: f64,
    /// Attach to the run's cgroups named by `HNG_CGROUP_RUN` (default true): CPU from
    /// the cgroup counters, caps read back from the kernel.
    pub cgroups: bool,
    /// Limits per module, checked in software where the kernel does not enforce them;
    /// they override the caps the supervisor's status lists.
    pub limits: BTreeMap<String, LimitConfig>,
}

impl Default for RmConfig {
    fn default() -> Self {
        let c = CostConfig::default();
        let d = DegradedConfig::default();
        RmConfig {
            rate_hz: 10.0,
            pss_every: SamplerConfig::default().pss_every,
            cpu_free_threshold: c.cpu_free_threshold,
            cpu_own_share_min: c.cpu_own_share_min,
            memory_free_threshold: c.memory_free_threshold,
            comm_delay_threshold_s: c.comm_delay_threshold.as_secs_f64(),
            cost_min: c.min,
            cost_max: c.max,
            cost_raise_factor: c.raise_factor,
            cost_lower_factor: c.lower_factor,
            degraded_enter_after: d.enter_after,
            degraded_step_after: d.step_after,
            degraded_recover_after: d.recover_after,
            allow_full_stop: d.allow_full_stop,
            cpu_window_s: 2.0,
            comm_budget_msgs_per_s: 10_000.0,
            forget_after_s: 5.0,
            table_timeout_s: 3.0,
            over_limit_repeat_s: 2.0,
            cgroups: true,
            limits: BTreeMap::new(),
        }
    }
}

impl RmConfig {
    /// The cost configuration; also checks every duration of the configuration (seconds, as
    /// every duration in hng's module configurations).
    pub(super) fn cost_config(&self) -> Result<CostConfig> {
        for (name, v, zero_ok) in [
            ("comm_delay_threshold_s", self.comm_delay_threshold_s, true),
            ("cpu_window_s", self.cpu_window_s, false),
            ("forget_after_s", self.forget_after_s, false),
            ("table_timeout_s", self.table_timeout_s, false),
            ("over_limit_repeat_s", self.over_limit_repeat_s, false),
        ] {
            let ok = v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0)) && v < 1e9;
            if !ok {
                let bound = if zero_ok { ">= 0" } else { "> 0" };
                return Err(RmError::Config(format!(
                    "{name} must be a number of seconds {bound}, got {v}"
                )));
            }
        }
        Ok(CostConfig {
            min: self.cost_min,
            max: self.cost_max,
            raise_factor: self.cost_raise_factor,
            lower_factor: self.cost_lower_factor,
            cpu_free_threshold: self.cpu_free_threshold,
            cpu_own_share_min: self.cpu_own_share_min,
            memory_free_threshold: self.memory_free_threshold,
            comm_delay_threshold: Duration::from_secs_f64(self.comm_delay_threshold_s),
        })
    }

    /// The sampling period.
    #[must_use]
    pub fn period(&self) -> Duration {
        Duration::try_from_secs_f64(1.0 / self.rate_hz).unwrap_or(Duration::from_millis(100))
    }
}
