//! Sharing the CPUs between the spinning waiters of one system.
//!
//! A waiter that spins before sleeping ([`crate::wait`]) reacts in well under a microsecond,
//! but only while it does not take a core that another process of the pipeline needs: three
//! spinners on two cores made the two-hop control loop three times slower than no spinning
//! at all (`hng bench loop`: 89 µs p50 against 31 µs), because the module that had work to do
//! waited for a spinner's core.
//!
//! The waiters of one system (one prefix) therefore keep a register in shared memory of which
//! of them exist and which are awake (working or spinning, as opposed to sleeping in
//! `epoll`): two bitmaps of 64 slots and the pid that owns each slot. The rule, with `cpus`
//! the CPUs this process may run on:
//!
//! - when the system's waiters all fit the CPUs (a two-process ping-pong on two cores), they
//!   may always spin: nobody can be kept from a core;
//! - otherwise a waiter spins only while it leaves a core free (awake ones, itself included,
//!   fewer than `cpus`), so that a sleeper woken by a notification finds an idle core at once
//!   instead of waiting for the scheduler to preempt a spinner;
//! - a spinner that sees more awake than CPUs (somebody woke and needs a core) gives its core
//!   up and sleeps. Only one spinner gives way per waking process: the bit is cleared by
//!   compare-and-swap on the whole bitmap.
//!
//! Measured on this project's 2-core VM (`hng bench loop`, three processes in a chain): the
//! 200 µs adaptive spin alone gave 55-90 µs p50; pure sleeping 31 µs; letting a waiter spin
//! whenever the awake ones fit the CPUs 41-50 µs (the wrong spinner gave way). The two-process
//! ping-pong keeps its sub-microsecond blocking-mode latency (`hng bench ipc`).
//!
//! A process woken from `epoll` can only mark itself awake once it runs, which is too late
//! when every core is held by a spinner. Its publisher knows sooner: the node counts the
//! publishes that had to notify a sleeper ([`crate::channel::Counters::wakeups`]), and the
//! publisher's next wait counts those processes as awake when deciding whether to spin.
//!
//! A process killed while awake leaves its bit set; every waiter that joins clears the bits
//! of slots whose process no longer exists, so a crash costs at most some spinning until the
//! next (re)start. Processes that do not join (tools, other programs) are not counted.

use std::num::NonZeroUsize;
use std::sync::atomic::{AtomicI32, AtomicU64, Ordering};

use nix::unistd::Pid;

use crate::error::Error;
use crate::shm::Segment;

/// Slots in the register: waiters beyond that many never spin.
pub const SLOTS: usize = 64;

/// File-name part of the register's segment.
pub(crate) const CPUS_TAG: &str = "hngcpus";

#[repr(C, align(64))]
struct Register {
    awake: AtomicU64,
    members: AtomicU64,
    _pad: [u64; 6],
    pids: [AtomicI32; SLOTS],
}

/// One waiter's place in its system's register (see the module documentation).
pub struct CpuShare {
    segment: Segment,
    /// The slot's bit, or 0 when every slot was taken (then this waiter never spins).
    bit: u64,
    slot: usize,
    cpus: u32,
}

impl std::fmt::Debug for CpuShare {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CpuShare")
            .field("slot", &(self.bit != 0).then_some(self.slot))
            .field("cpus", &self.cpus)
            .field("awake", &self.awake())
            .finish()
    }
}

fn alive(pid: i32) -> bool {
    // Signal 0 checks existence; EPERM means it exists but belongs to someone else.
    !matches!(
        nix::sys::signal::kill(Pid::from_raw(pid), None),
        Err(nix::errno::Errno::ESRCH)
    )
}

impl CpuShare {
    /// Joins the register of system `prefix`, counting the CPUs this process may run on.
    pub fn join(prefix: &str) -> Result<CpuShare, Error> {
        let cpus = std::thread::available_parallelism().map_or(1, NonZeroUsize::get);
        CpuShare::join_with(prefix, u32::try_from(cpus).unwrap_or(u32::MAX))
    }

    /// Joins the register of system `prefix`, counting `cpus` CPUs.
    pub fn join_with(prefix: &str, cpus: u32) -> Result<CpuShare, Error> {
        let name = format!("/{prefix}{CPUS_TAG}");
        let segment = Segment::open(&name, std::mem::size_of::<Register>(), "CPU register")?;
        let mut share = CpuShare {
            segment,
            bit: 0,
            slot: 0,
            cpus: cpus.max(1),
        };
        share.repair();
        let me = std::process::id() as i32;
        for (i, pid) in share.reg().pids.iter().enumerate() {
            if pid
                .compare_exchange(0, me, Ordering::AcqRel, Ordering::Acquire)
                .is_ok()
            {
                share.slot = i;
                share.bit = 1 << i;
                share.reg().members.fetch_or(share.bit, Ordering::AcqRel);
                break;
            }
        }
        if share.bit == 0 {
            tracing::warn!(
                "CPU register {name}: all {SLOTS} slots are taken; this waiter will sleep \
                 without spinning"
            );
        }
        share.wake();
        Ok(share)
    }

    fn reg(&self) -> &Register {
        // SAFETY: the segment is a Register long, lives as long as self and is only accessed
        // through atomics (a new one is all zeros: no slot taken, nobody awake).
        unsafe { self.segment.get() }
    }

    /// Frees the slots of processes that no longer exist.
    fn repair(&self) {
        let reg = self.reg();
        for (i, pid) in reg.pids.iter().enumerate() {
            let p = pid.load(Ordering::Acquire);
            if p != 0 && !alive(p) {
                // Clear the bits before freeing the slot, so a new owner never inherits them.
                reg.awake.fetch_and(!(1u64 << i), Ordering::AcqRel);
                reg.members.fetch_and(!(1u64 << i), Ordering::AcqRel);
                let _ = pid.compare_exchange(p, 0, Ordering::AcqRel, Ordering::Relaxed);
            }
        }
    }

    /// How many waiters of the system are awake now.
    pub fn awake(&self) -> u32 {
        self.reg().awake.load(Ordering::Acquire).count_ones()
    }

    /// How many waiters the system has.
    pub fn members(&self) -> u32 {
        self.reg().members.load(Ordering::Acquire).count_ones()
    }

    /// True when this waiter may spin (see the module documentation): it has a slot, and
    /// either every waiter of the system fits the CPUs, or the awake ones with `woken`
    /// processes about to wake leave a core free.
    #[inline]
    pub fn may_spin(&self, woken: u32) -> bool {
        self.bit != 0
            && (self.members() <= self.cpus || self.awake().saturating_add(woken) < self.cpus)
    }

    /// A spinner's check: if the awake waiters outnumber the CPUs, this one gives its core up
    /// (its bit is cleared, as for sleeping) and returns true. Of several spinners that look
    /// at once, only as many give way as needed.
    #[inline]
    pub fn give_way(&self) -> bool {
        let awake = &self.reg().awake;
        let mut w = awake.load(Ordering::Acquire);
        loop {
            if w & self.bit == 0 || w.count_ones() <= self.cpus {
                return false;
            }
            match awake.compare_exchange_weak(w, w & !self.bit, Ordering::AcqRel, Ordering::Acquire)
            {
                Ok(_) => return true,
                Err(now) => w = now,
            }
        }
    }

    /// About to sleep in `epoll`.
    #[inline]
    pub fn sleep(&self) {
        if self.bit != 0 {
            self.reg().awake.fetch_and(!self.bit, Ordering::AcqRel);
        }
    }

    /// Awake again.
    #[inline]
    pub fn wake(&self) {
        if self.bit != 0 {
            self.reg().awake.fetch_or(self.bit, Ordering::AcqRel);
        }
    }
}

impl Drop for CpuShare {
    fn drop(&mut self) {
        if self.bit != 0 {
            let reg = self.reg();
            reg.awake.fetch_and(!self.bit, Ordering::AcqRel);
            reg.members.fetch_and(!self.bit, Ordering::AcqRel);
            reg.pids[self.slot].store(0, Ordering::Release);
        }
    }
}

/// Lowers the calling thread's scheduling priority to nice value `nice` (1-19; higher is
/// lower): for work that must never take a core from the control loop, such as the operator
/// page's view. Linux keeps a nice value per thread (`setpriority(2)`, notes), so the rest of
/// the process keeps its priority; raising one's own nice value needs no privilege.
pub fn lower_thread_priority(nice: i32) -> std::io::Result<()> {
    // SAFETY: plain integers; with PRIO_PROCESS and who = 0, Linux changes the calling thread.
    let rc = unsafe { nix::libc::setpriority(nix::libc::PRIO_PROCESS, 0, nice) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shm;

    /// Field 19 of /proc/thread-self/stat: the calling thread's nice value.
    fn thread_nice() -> i32 {
        let stat = std::fs::read_to_string("/proc/thread-self/stat").expect("stat");
        let after_name = &stat[stat.rfind(')').expect("comm") + 2..];
        after_name
            .split(' ')
            .nth(16)
            .expect("nice")
            .parse()
            .expect("a number")
    }

    #[test]
    fn a_lowered_thread_alone_gets_the_new_nice_value() {
        let before = thread_nice();
        let lowered = std::thread::spawn(move || {
            lower_thread_priority(before + 7).expect("setpriority");
            thread_nice()
        })
        .join()
        .expect("thread");
        assert_eq!(lowered, before + 7);
        assert_eq!(thread_nice(), before, "the other threads keep theirs");
    }

    #[test]
    fn waiters_that_fit_the_cpus_spin_others_leave_a_core_free() {
        let prefix = shm::unique_prefix("cpus");
        let a = CpuShare::join_with(&prefix, 2).expect("join");
        let b = CpuShare::join_with(&prefix, 2).expect("join");
        assert_eq!((a.members(), a.awake()), (2, 2));
        assert!(
            a.may_spin(0) && b.may_spin(5),
            "two waiters on two CPUs always fit"
        );
        let c = CpuShare::join_with(&prefix, 2).expect("join");
        assert_eq!((c.members(), c.awake()), (3, 3));
        assert!(
            !a.may_spin(0),
            "three awake on two CPUs: nobody should start spinning"
        );
        // One of the two spinners gives way, not both.
        assert!(a.give_way());
        assert!(!b.give_way());
        assert_eq!(b.awake(), 2);
        assert!(
            !b.may_spin(0),
            "two awake of three on two CPUs: no core would be left free"
        );
        c.sleep();
        assert!(b.may_spin(0), "only b awake: one core stays free");
        assert!(
            !b.may_spin(1),
            "b woke somebody: that one needs the free core"
        );
        a.wake();
        c.wake();
        assert_eq!(a.awake(), 3);
        drop(c);
        drop(b);
        assert_eq!((a.members(), a.awake()), (1, 1));
        drop(a);
        shm::remove_prefix_files(&prefix);
    }

    #[test]
    fn a_dead_process_slot_is_freed_by_the_next_joiner() {
        let prefix = shm::unique_prefix("cpus");
        let a = CpuShare::join_with(&prefix, 1).expect("join");
        // Pretend a process that has exited holds slot 5 and was awake when it died.
        let mut child = std::process::Command::new("true")
            .spawn()
            .expect("spawn true");
        let dead = child.id() as i32;
        child.wait().expect("wait");
        a.reg().pids[5].store(dead, Ordering::Release);
        a.reg().awake.fetch_or(1 << 5, Ordering::AcqRel);
        a.reg().members.fetch_or(1 << 5, Ordering::AcqRel);
        assert_eq!((a.members(), a.awake()), (2, 2));
        assert!(!a.may_spin(0));
        let b = CpuShare::join_with(&prefix, 1).expect("join");
        assert_eq!(a.reg().pids[5].load(Ordering::Acquire), 0);
        assert_eq!(
            b.awake(),
            2,
            "the dead process's bit is gone, a and b are awake"
        );
        assert_eq!(b.members(), 2);
        drop(b);
        assert!(a.may_spin(0));
        drop(a);
        shm::remove_prefix_files(&prefix);
    }
}
