//! The module's heartbeat (its [`crate::msg::ModuleReport`]): when the next one is due, and
//! how an idle module stretches it.
//!
//! A module whose loop woke, during a whole report period, only to send its report has
//! nothing to do: its period doubles, up to the idle period. Each report announces the
//! period until the next one (`period_ns`), and the watchdog's hang deadline follows it
//! (`Supervisor::heartbeat_promising`). When work comes (an input, a timer, a round), a
//! module with a stretched period reports at once with the normal period, before handling
//! it: a callback that then hangs is detected within the configured timeout. The stretch
//! only ever covers time the module spends blocked in its wait.
//!
//! **Slack** ([`Beat::with_slack`]): a module called to lockstep rounds wakes often anyway,
//! so a report due between two rounds need not wake it on its own: it waits up to `slack`
//! past the due time and sends the report with the next round it handles. Each report then
//! announces its period plus the slack, so the watchdog's hang deadline moves with it
//! (the same margin as configured). Without slack (every other module) nothing changes.

/// See the [module documentation](self).
#[derive(Debug, Clone)]
pub(super) struct Beat {
    normal_ns: u64,
    idle_max_ns: u64,
    period_ns: u64,
    next_ns: u64,
    worked: bool,
    /// How late a report may go out, waiting for a wake-up that comes anyway.
    slack_ns: u64,
}

impl Beat {
    /// A heartbeat of `normal_ns`, stretched up to `idle_max_ns`, the first report sent at
    /// `now_ns`.
    pub(super) fn new(normal_ns: u64, idle_max_ns: u64, now_ns: u64) -> Beat {
        let normal_ns = normal_ns.max(1);
        Beat {
            normal_ns,
            idle_max_ns: idle_max_ns.max(normal_ns),
            period_ns: normal_ns,
            next_ns: now_ns.saturating_add(normal_ns),
            worked: false,
            slack_ns: 0,
        }
    }

    /// Reports may go out up to `slack_ns` late, with a wake-up that comes anyway.
    pub(super) fn with_slack(mut self, slack_ns: u64) -> Beat {
        self.slack_ns = slack_ns;
        self
    }

    /// When the loop must wake at the latest to send the next report (monotonic ns).
    pub(super) fn next_ns(&self) -> u64 {
        self.next_ns.saturating_add(self.slack_ns)
    }

    /// The normal period, as a report announces it (with the slack).
    pub(super) fn normal_ns(&self) -> u64 {
        self.normal_ns.saturating_add(self.slack_ns)
    }

    /// The loop woke for something else than the report: the module is not idle. Returns
    /// the period to report at once when the heartbeat was stretched (`None`: no report
    /// needed now).
    pub(super) fn work(&mut self, now_ns: u64) -> Option<u64> {
        self.worked = true;
        if self.period_ns > self.normal_ns {
            self.period_ns = self.normal_ns;
            self.next_ns = now_ns.saturating_add(self.normal_ns);
            Some(self.normal_ns())
        } else {
            None
        }
    }

    /// At `now_ns`: `Some(period)` when a report is due, the period it announces.
    pub(super) fn due(&mut self, now_ns: u64) -> Option<u64> {
        if now_ns < self.next_ns {
            return None;
        }
        self.period_ns = if self.worked {
            self.normal_ns
        } else {
            self.period_ns.saturating_mul(2).min(self.idle_max_ns)
        };
        self.worked = false;
        self.next_ns = now_ns.saturating_add(self.period_ns);
        Some(self.period_ns.saturating_add(self.slack_ns))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn an_idle_heartbeat_doubles_to_its_limit_and_work_brings_it_back_at_once() {
        let mut b = Beat::new(100 * MS, 1000 * MS, 0);
        assert_eq!(b.due(50 * MS), None);
        // Idle: 200, 400, 800, then the 1000 ms limit.
        let mut now = 100 * MS;
        let mut periods = Vec::new();
        for _ in 0..5 {
            let p = b.due(now).expect("due");
            periods.push(p / MS);
            now += p;
        }
        assert_eq!(periods, vec![200, 400, 800, 1000, 1000]);
        // Work while stretched: report now, at the normal period.
        assert_eq!(b.work(now + 10 * MS), Some(100 * MS));
        assert_eq!(b.next_ns(), now + 110 * MS);
        // More work before the next report: no extra report.
        assert_eq!(b.work(now + 20 * MS), None);
        // The period with work keeps the normal period.
        assert_eq!(b.due(now + 110 * MS), Some(100 * MS));
    }

    #[test]
    fn with_slack_a_report_may_wait_for_another_wake_up_and_announces_the_slack() {
        let mut b = Beat::new(200 * MS, 1000 * MS, 0).with_slack(100 * MS);
        // The loop need not wake before 300 ms, but a wake-up from 200 ms on reports.
        assert_eq!(b.next_ns(), 300 * MS);
        assert_eq!(b.due(199 * MS), None);
        b.work(150 * MS);
        assert_eq!(b.due(250 * MS), Some(300 * MS), "period + slack announced");
        assert_eq!(b.next_ns(), 550 * MS);
        assert_eq!(b.normal_ns(), 300 * MS);
    }

    #[test]
    fn a_busy_heartbeat_keeps_its_period_and_an_idle_limit_below_it_is_raised() {
        let mut b = Beat::new(100 * MS, 10 * MS, 0);
        assert_eq!(b.due(100 * MS), Some(100 * MS));
        let mut b = Beat::new(100 * MS, 1000 * MS, 0);
        for k in 1..5 {
            b.work(k * 100 * MS - 1);
            assert_eq!(b.due(k * 100 * MS), Some(100 * MS));
        }
        assert_eq!(b.normal_ns(), 100 * MS);
    }
}
