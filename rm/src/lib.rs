//! hng-rm: the resource manager's building blocks (paper section 5.3).
//!
//! * [`sampler`]: per-module CPU, memory (RSS, PSS) and page faults from procfs, or the
//!   module's cgroup, at low cost; machine-wide free CPU and memory.
//! * [`cgroup`]: one cgroup per module (v2 or v1), caps, async-signal-safe placement from
//!   a pre-exec hook, OOM read-back, group kill, teardown; software fallback.
//! * [`limits`]: resource limits, how each is enforced, and the software check.
//! * [`cost`]: effective cost R_eff (eq. 4), value V (eq. 3) and the cost vector C_R(t).
//! * [`degraded`]: the degraded mode (minimum priority) and [`degraded::RmCore`], the
//!   decision part of the RM, fed with observations.
//! * [`mod@bench`]: the `sample_N` benchmark.
//! * [`manager`]: [`manager::ResourceManager`], the RM's state fed with reports,
//!   contract tables and the supervisor's status, one `tick` per period.
//! * [`module`]: [`RmModule`], the RM process (`hng module rm`) on iceoryx2.

pub mod bench;
pub mod cgroup;
pub mod cost;
pub mod degraded;
pub mod error;
pub mod limits;
pub mod manager;
pub mod module;
pub mod sampler;

pub use error::{Result, RmError};
pub use module::RmModule;
