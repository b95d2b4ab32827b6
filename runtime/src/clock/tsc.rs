//! `CLOCK_MONOTONIC` from the TSC, without a system call or the vDSO's serialising read.
//!
//! Linux itself derives `CLOCK_MONOTONIC` from the TSC when its clocksource is `tsc` (the
//! kernel then trusts the TSC to be invariant and synchronised across CPUs), as
//! `ns = base + (tsc - anchor) * mult`. The vDSO does that with an ordered TSC read
//! (`lfence; rdtsc` or `rdtscp`), which waits for every earlier load to complete; on a
//! publish that follows a receive from another core, those are shared-memory cache misses.
//! This module keeps such a line itself, per process:
//!
//! - It starts from a pairing of the TSC with `clock_gettime` (`origin`); until 2 ms later
//!   every read is the OS clock, then the rate comes from the two pairings.
//! - Every millisecond the line is re-anchored on a fresh pairing. The new line starts where
//!   the old one is (no step, so the clock never goes back) and is steered to meet the OS
//!   clock one period later, as NTP slews; after that period (a process that read no time
//!   for a while) it goes on at the rate measured from the origin, so the longer the process
//!   runs the closer it is. The distance to the OS clock stays within the pairing's
//!   uncertainty: half the best of three brackets of TSC reads around `clock_gettime`,
//!   discarded when wider than 250 ns (an interrupt came between). On this project's machine
//!   it measured -17 to +4 ns (p1 to p99). Distances over 1 ms (suspend, a migrated VM) reset
//!   the line.
//! - Readers take the line under a sequence lock, so any thread may read; one thread at a
//!   time re-anchors, the others go on with the current line.
//!
//! It is used only when `/sys/devices/system/clocksource/clocksource0/current_clocksource`
//! is `tsc` and `HNG_TSC` is not `off`. No crate did this: `quanta` and `minstant`
//! calibrate once per process, so two processes' stamps drift apart by the calibration
//! error (ppm) for as long as they run, which breaks latencies measured across processes.

use std::sync::atomic::{AtomicU8, AtomicU32, AtomicU64, Ordering, fence};

use super::os_monotonic_ns;

/// How often the line is re-anchored.
const PERIOD_NS: u64 = 1_000_000;
/// How long the first rate measurement runs.
const CALIBRATION_NS: u64 = 2_000_000;
/// A pairing whose bracket of TSC reads is wider than this was interrupted: discarded.
const MAX_PAIRING_NS: u64 = 250;
/// Farther than this from the OS clock, the line is reset instead of steered.
const MAX_OFFSET_NS: u64 = 1_000_000;

const UNKNOWN: u8 = 0;
const OFF: u8 = 1;
const ON: u8 = 2;

/// A line `ns = base_ns + (tsc - base_tsc) * mult / 2^32` for one period after its anchor,
/// at the measured `rate` after that.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Line {
    /// TSC at the anchor.
    pub base_tsc: u64,
    /// Nanoseconds at the anchor.
    pub base_ns: u64,
    /// Nanoseconds per tick over the period (the rate, steered), 32.32 fixed point.
    pub mult: u64,
    /// Nanoseconds per tick measured from the origin, 32.32 fixed point.
    pub rate: u64,
    /// The period in ticks.
    pub period_ticks: u64,
}

/// `ticks` at `mult` (32.32 ns per tick), in nanoseconds.
fn scale(ticks: u64, mult: u64) -> u64 {
    ((u128::from(ticks) * u128::from(mult)) >> 32) as u64
}

/// Ticks in `ns` nanoseconds at `mult`.
fn ticks(ns: u64, mult: u64) -> u64 {
    ((u128::from(ns) << 32) / u128::from(mult.max(1))) as u64
}

impl Line {
    /// A line through `p` at `rate`, not steered.
    fn through(p: Pairing, rate: u64) -> Line {
        Line {
            base_tsc: p.tsc,
            base_ns: p.ns,
            mult: rate,
            rate,
            period_ticks: ticks(PERIOD_NS, rate),
        }
    }

    /// The line's time at `tsc` (never before its anchor).
    #[inline]
    pub fn at(&self, tsc: u64) -> u64 {
        let d = tsc.saturating_sub(self.base_tsc);
        if d <= self.period_ticks {
            self.base_ns.wrapping_add(scale(d, self.mult))
        } else {
            self.base_ns
                .wrapping_add(scale(self.period_ticks, self.mult))
                .wrapping_add(scale(d - self.period_ticks, self.rate))
        }
    }
}

/// A simultaneous reading of the TSC and the OS clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pairing {
    /// TSC.
    pub tsc: u64,
    /// `CLOCK_MONOTONIC`, nanoseconds.
    pub ns: u64,
}

/// The rate (32.32 ns per tick) between two pairings; `None` when they are not in order.
pub fn rate(from: Pairing, to: Pairing) -> Option<u64> {
    let ticks = to.tsc.checked_sub(from.tsc).filter(|&t| t > 0)?;
    let ns = to.ns.checked_sub(from.ns)?;
    u64::try_from((u128::from(ns) << 32) / u128::from(ticks)).ok()
}

/// The line that continues `line` from `now.tsc` and meets the OS clock one period later,
/// at the rate measured since `origin`; `None` when `line` is farther than
/// [`MAX_OFFSET_NS`] from the OS clock (or the pairings are out of order): start over.
pub fn steer(line: Line, origin: Pairing, now: Pairing) -> Option<Line> {
    let rate = rate(origin, now)?;
    let here = line.at(now.tsc);
    if here.abs_diff(now.ns) > MAX_OFFSET_NS {
        return None;
    }
    // Over the next period, cover the period plus the distance still to go.
    let period_ticks = ticks(PERIOD_NS, rate).max(1);
    let target = (now.ns + PERIOD_NS).saturating_sub(here);
    let steered = (u128::from(target) << 32) / u128::from(period_ticks);
    Some(Line {
        base_tsc: now.tsc,
        base_ns: here,
        // Never slower than half the measured rate: the clock keeps moving forward.
        mult: u64::try_from(steered).unwrap_or(u64::MAX).max(rate / 2),
        rate,
        period_ticks,
    })
}

/// The shared state, on one cache line that readers only read.
#[repr(align(64))]
struct State {
    /// Odd while a writer updates the line.
    seq: AtomicU32,
    enabled: AtomicU8,
    base_tsc: AtomicU64,
    base_ns: AtomicU64,
    /// 0 until calibrated.
    mult: AtomicU64,
    rate: AtomicU64,
    /// Re-anchor when the TSC passed the anchor by this many ticks.
    period_ticks: AtomicU64,
    origin_tsc: AtomicU64,
    origin_ns: AtomicU64,
}

static STATE: State = State {
    seq: AtomicU32::new(0),
    enabled: AtomicU8::new(UNKNOWN),
    base_tsc: AtomicU64::new(0),
    base_ns: AtomicU64::new(0),
    mult: AtomicU64::new(0),
    rate: AtomicU64::new(0),
    period_ticks: AtomicU64::new(u64::MAX),
    origin_tsc: AtomicU64::new(0),
    origin_ns: AtomicU64::new(0),
};

#[inline]
fn rdtsc() -> u64 {
    // SAFETY: RDTSC exists on every x86_64 CPU and only reads the time-stamp counter.
    unsafe { core::arch::x86_64::_rdtsc() }
}

/// A TSC read that neither starts before the instructions ahead of it nor lets those after
/// it start first (for pairings, where the order matters more than the cost).
fn ordered_rdtsc() -> u64 {
    // SAFETY: LFENCE (SSE2, part of x86_64) and RDTSC only order execution and read the
    // time-stamp counter.
    unsafe {
        core::arch::x86_64::_mm_lfence();
        let t = core::arch::x86_64::_rdtsc();
        core::arch::x86_64::_mm_lfence();
        t
    }
}

/// Now on the TSC line, or `None` when the TSC is not used (then read the OS clock).
#[inline]
pub fn now_ns() -> Option<u64> {
    let s = &STATE;
    if s.enabled.load(Ordering::Relaxed) != ON {
        return slow_path();
    }
    loop {
        let seq = s.seq.load(Ordering::Acquire);
        let line = Line {
            base_tsc: s.base_tsc.load(Ordering::Relaxed),
            base_ns: s.base_ns.load(Ordering::Relaxed),
            mult: s.mult.load(Ordering::Relaxed),
            rate: s.rate.load(Ordering::Relaxed),
            period_ticks: s.period_ticks.load(Ordering::Relaxed),
        };
        fence(Ordering::Acquire);
        if seq & 1 == 1 || s.seq.load(Ordering::Relaxed) != seq {
            std::hint::spin_loop();
            continue;
        }
        if line.mult == 0 {
            return slow_path();
        }
        let tsc = rdtsc();
        if tsc.saturating_sub(line.base_tsc) <= line.period_ticks {
            return Some(line.at(tsc));
        }
        if let Some(ns) = reanchor(seq, line) {
            return Some(ns);
        }
        // Another thread re-anchors: read its line.
    }
}

/// Not decided yet, off, or not calibrated yet.
#[cold]
#[inline(never)]
fn slow_path() -> Option<u64> {
    let s = &STATE;
    match s.enabled.load(Ordering::Relaxed) {
        OFF => return None,
        UNKNOWN => {
            let on = tsc_is_the_clocksource() && std::env::var("HNG_TSC").as_deref() != Ok("off");
            s.enabled
                .store(if on { ON } else { OFF }, Ordering::Relaxed);
            if !on {
                return None;
            }
        }
        _ => {}
    }
    let seq = s.seq.load(Ordering::Acquire);
    let Some(now) = pairing() else {
        return Some(os_monotonic_ns());
    };
    if !lock(seq) {
        return Some(now.ns);
    }
    let origin = origin();
    if s.mult.load(Ordering::Relaxed) != 0 {
        // Calibrated meanwhile by another thread.
    } else if origin.ns == 0 {
        set_origin(now);
    } else if now.ns.saturating_sub(origin.ns) >= CALIBRATION_NS
        && let Some(rate) = rate(origin, now)
    {
        store(Line::through(now, rate));
    }
    unlock(seq);
    Some(now.ns)
}

/// Re-anchors `line` (read under `seq`) and returns now on the new line; `None` when
/// another thread is at it. An interrupted pairing keeps the line for now.
#[cold]
#[inline(never)]
fn reanchor(seq: u32, line: Line) -> Option<u64> {
    let Some(now) = pairing() else {
        return Some(line.at(rdtsc()));
    };
    if !lock(seq) {
        return None;
    }
    let next = steer(line, origin(), now).unwrap_or_else(|| {
        // Out of step (suspend, a migrated VM): start over from here.
        set_origin(now);
        Line::through(now, line.rate)
    });
    store(next);
    unlock(seq);
    // The pairing may be the first of three: read the TSC again for now.
    Some(next.at(rdtsc()))
}

fn origin() -> Pairing {
    Pairing {
        tsc: STATE.origin_tsc.load(Ordering::Relaxed),
        ns: STATE.origin_ns.load(Ordering::Relaxed),
    }
}

fn set_origin(p: Pairing) {
    STATE.origin_tsc.store(p.tsc, Ordering::Relaxed);
    STATE.origin_ns.store(p.ns, Ordering::Relaxed);
}

/// Pairs the TSC with the OS clock: the TSC half-way between two reads around
/// `clock_gettime`, best of three; `None` when even the best bracket is too wide (an
/// interrupt or preemption came between the reads).
fn pairing() -> Option<Pairing> {
    let mult = STATE.mult.load(Ordering::Relaxed);
    // Before calibration: 1,000 ticks, at most 1 us for a TSC of at least 1 GHz.
    let max_width = if mult == 0 {
        1_000
    } else {
        ticks(MAX_PAIRING_NS, mult)
    };
    let mut best: Option<(u64, Pairing)> = None;
    for _ in 0..3 {
        let t0 = ordered_rdtsc();
        let ns = os_monotonic_ns();
        let t1 = ordered_rdtsc();
        let Some(width) = t1.checked_sub(t0) else {
            continue;
        };
        if best.is_none_or(|(w, _)| width < w) {
            best = Some((
                width,
                Pairing {
                    tsc: t0 + width / 2,
                    ns,
                },
            ));
        }
    }
    best.filter(|&(w, _)| w <= max_width).map(|(_, p)| p)
}

/// Takes the writer's side of the sequence lock if it is still at `seq` (even).
fn lock(seq: u32) -> bool {
    let taken = seq & 1 == 0
        && STATE
            .seq
            .compare_exchange(
                seq,
                seq.wrapping_add(1),
                Ordering::Acquire,
                Ordering::Relaxed,
            )
            .is_ok();
    if taken {
        // The line's stores must not be seen before the odd sequence number.
        fence(Ordering::Release);
    }
    taken
}

fn unlock(seq: u32) {
    STATE.seq.store(seq.wrapping_add(2), Ordering::Release);
}

fn store(line: Line) {
    let s = &STATE;
    s.base_tsc.store(line.base_tsc, Ordering::Relaxed);
    s.base_ns.store(line.base_ns, Ordering::Relaxed);
    s.mult.store(line.mult, Ordering::Relaxed);
    s.rate.store(line.rate, Ordering::Relaxed);
    s.period_ticks.store(line.period_ticks, Ordering::Relaxed);
}

fn tsc_is_the_clocksource() -> bool {
    std::fs::read_to_string("/sys/devices/system/clocksource/clocksource0/current_clocksource")
        .is_ok_and(|s| s.trim() == "tsc")
}

/// True when [`now_ns`] reads the TSC (decided at the first read).
pub fn in_use() -> bool {
    let _ = now_ns();
    STATE.enabled.load(Ordering::Relaxed) == ON
}

#[cfg(test)]
mod tests {
    use super::*;

    const GHZ3: u64 = (1u64 << 32) / 3; // 1/3 ns per tick

    #[test]
    fn a_steered_line_continues_the_old_one_and_meets_the_os_clock_a_period_later() {
        let origin = Pairing { tsc: 0, ns: 1_000 };
        // The old line runs 200 ns ahead of the OS clock at the re-anchor.
        let now = Pairing {
            tsc: 3_000_000_000,
            ns: 1_000_001_000,
        };
        let old = Line {
            base_ns: 999_001_200,
            ..Line::through(
                Pairing {
                    tsc: 2_997_000_000,
                    ns: 0,
                },
                GHZ3,
            )
        };
        let here = old.at(now.tsc);
        assert!(here.abs_diff(now.ns + 200) <= 1, "{here}");
        let new = steer(old, origin, now).expect("line");
        assert_eq!(new.base_ns, here, "no step at the anchor");
        let period_later = new.at(now.tsc + 3_000_000);
        assert!(
            period_later.abs_diff(now.ns + PERIOD_NS) <= 2,
            "meets the OS clock one period later: {period_later}"
        );
        assert!(new.mult < GHZ3, "slowed down to let the OS clock catch up");
        // Long after the period it runs at the measured rate, not the steered one.
        let second_later = new.at(now.tsc + 3_000_000_000);
        assert!(
            second_later.abs_diff(now.ns + 1_000_000_000) <= 2,
            "{second_later}"
        );
    }

    #[test]
    fn a_line_far_from_the_os_clock_starts_over() {
        let origin = Pairing { tsc: 0, ns: 0 };
        let now = Pairing {
            tsc: 3_000_000,
            ns: 1_000_000,
        };
        let old = Line {
            base_ns: 50_000_000,
            ..Line::through(origin, GHZ3)
        };
        assert_eq!(steer(old, origin, now), None);
        assert!(rate(now, origin).is_none(), "pairings out of order");
    }

    #[test]
    fn the_tsc_clock_stays_within_microseconds_of_the_os_clock_and_never_goes_back() {
        if !in_use() {
            eprintln!("skipped: the kernel's clocksource is not the TSC (or HNG_TSC=off)");
            return;
        }
        let check = || {
            let start = os_monotonic_ns();
            let mut last = 0;
            let mut worst = 0u64;
            // 30 ms: calibration (2 ms) and about 28 re-anchors.
            while os_monotonic_ns() - start < 30_000_000 {
                let before = os_monotonic_ns();
                let t = now_ns().expect("tsc clock");
                let after = os_monotonic_ns();
                assert!(t >= last, "went back: {last} -> {t}");
                last = t;
                let off = if t < before {
                    before - t
                } else {
                    t.saturating_sub(after)
                };
                worst = worst.max(off);
            }
            worst
        };
        let other = std::thread::spawn(check);
        let worst = check().max(other.join().expect("thread"));
        // Preemption between the reads widens the bracket, never the distance; the
        // line's own distance is tens of nanoseconds (see the module docs).
        assert!(worst < 5_000, "{worst} ns away from CLOCK_MONOTONIC");
    }
}
