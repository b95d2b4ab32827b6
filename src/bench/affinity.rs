//! CPU lists for `hng bench loop --loop-cpus/--browser-cpus`: which cores the loop's processes
//! and the watching browsers may run on (`sched_setaffinity`, inherited by every thread and
//! process started afterwards).

use anyhow::{Context as _, Result, bail};
use nix::sched::CpuSet;
use nix::unistd::Pid;

/// A set of CPUs written as in `taskset -c` and cpuset files: `1`, `0-1`, `0,2-3`.
#[derive(Debug, Clone)]
pub struct CpuList {
    /// Boxed: a `CpuSet` is 128 bytes, too large to sit twice in the bench's arguments.
    set: Box<CpuSet>,
    text: String,
}

impl CpuList {
    /// Parses `list`; each CPU must exist on this machine.
    pub fn parse(list: &str) -> Result<CpuList> {
        // The CPUs this machine has, not those this process may use now
        // (`available_parallelism` follows the current affinity and would refuse the rest).
        // SAFETY: sysconf reads a system constant; no memory is passed.
        let n = unsafe { nix::libc::sysconf(nix::libc::_SC_NPROCESSORS_CONF) };
        let configured = usize::try_from(n).unwrap_or(1).max(1);
        let mut set = CpuSet::new();
        for part in list.split(',').map(str::trim) {
            let (lo, hi) = part.split_once('-').unwrap_or((part, part));
            let number = |s: &str| {
                s.trim()
                    .parse::<usize>()
                    .with_context(|| format!("`{s}` in CPU list `{list}` is not a CPU number"))
            };
            let (lo, hi) = (number(lo)?, number(hi)?);
            if lo > hi || hi >= configured {
                bail!(
                    "CPU list `{list}`: `{part}` is not within 0-{}",
                    configured - 1
                );
            }
            for cpu in lo..=hi {
                set.set(cpu).with_context(|| format!("CPU {cpu}"))?;
            }
        }
        Ok(CpuList {
            set: Box::new(set),
            text: list.to_owned(),
        })
    }

    /// Restricts the calling thread, and what it starts from now on, to these CPUs.
    pub fn apply_to_this_thread(&self) -> Result<()> {
        nix::sched::sched_setaffinity(Pid::from_raw(0), &self.set)
            .with_context(|| format!("restricting this process to CPUs {}", self.text))
    }

    /// The set, for a child's `pre_exec`.
    pub fn set(&self) -> CpuSet {
        *self.set
    }

    /// As written.
    pub fn as_str(&self) -> &str {
        &self.text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_parse_as_taskset_writes_them_and_bad_ones_say_why() {
        let l = CpuList::parse("0").expect("cpu 0 exists");
        assert!(l.set().is_set(0).expect("in range"));
        let e = CpuList::parse("x").expect_err("not a number").to_string();
        assert!(e.contains("`x`"), "{e}");
        let e = CpuList::parse("100000")
            .expect_err("no such CPU")
            .to_string();
        assert!(e.contains("not within"), "{e}");
        let e = CpuList::parse("1-0").expect_err("reversed").to_string();
        assert!(e.contains("not within"), "{e}");
    }
}
