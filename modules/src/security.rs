//! Security: robot integrity (Table 1: provides "Robot integrity", needs "Robot control" and
//! "LIDAR data"; data in: lidar, data out: commands).
//!
//! Security answers the Manager's objective 1, so its "Robot control" contract with the Robot
//! driver has priority 1.1, the most important of the Robot's clients (paper 5.8: it may
//! invalidate the others' commands). It sends no command: at every scan it publishes a
//! speed-limit envelope ([`SpeedEnvelope`], [`envelope`]) on its Robot's
//! [`crate::robot::envelope_channel`] (`robot/cmd_vel/envelope`, a state channel), the largest
//! safe forward and backward speed for every curvature of motion, and the Robot limits the
//! command of the client it elected (the operator's Interface 2.1, the Servo-controller
//! 2.2.1.1) by it before it goes to the wheels. Security never reads the others' commands,
//! and knows nothing of their priorities; it is called once per scan. Without a fresh scan
//! (none for `scan_timeout_s`, or none yet when the Robot is contracted) it publishes the stop
//! envelope (it cannot vouch for anything it cannot see); an envelope is as old as its scan,
//! and the Robot stops on one older than its `freshness_s`. The lidar comes from its "LIDAR
//! data" provider (the configured `scan` channel until one is known); the latest scan is kept
//! as the loaned shared-memory sample, not copied.
//!
//! Without contracts (the `hng bench loop`), `cmd_in` names the channel of the desired
//! commands; Security limits each itself ([`decide`]) and sends it on `cmd_out`.
//!
//! The speed limit ([`speed_limit`]): the free distance `d` along the robot's path (the swept
//! disc of radius `robot_radius + side_margin`, straight or along the arc of the commanded
//! curvature, [`free_distance`]) minus `safety_distance` must cover the reaction distance and
//! the braking distance: `v·t_r + v²/(2·a) ≤ d`, so `v_max = a·(√(t_r² + 2d/a) − t_r)`, with
//! `a` the braking deceleration and `t_r` the reaction time (scan period plus loop latency).
//! Below the safety distance `v_max` is 0. Turning in place is never limited (the robot is
//! a disc), and moving away from an obstacle is not limited by it.
//!
//! Quality Q: the scan's ([`crate::scan::scan_quality`], as the Laser rates it) while scans
//! arrive; -1 (aptitude 0) when they stop.

use std::f64::consts::PI;
use std::time::Duration;

use hng_runtime::channel::{InputId, Sample};
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::{FollowProvider as _, ProviderInfo, ProviderInput};
use hng_runtime::msg::{ENVELOPE_BINS, LaserScan, SpeedEnvelope, Twist, envelope_bin_curvature};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

use crate::common::{check_fields, positive, seconds};
use crate::robot::{ROBOT_CONTROL, envelope_channel};
pub use crate::scan::ScanView;
use crate::scan::scan_quality;

/// Rank of Security's "Robot control" need (contract priority `P(security).1`: 1.1).
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of Security's "LIDAR data" need (1.2).
pub const LIDAR_NEED: u16 = 2;

/// Parameters of the safety envelope.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct SafetyConfig {
    /// Robot radius, m (default 0.2).
    #[default(crate::footprint::ROBOT_RADIUS_M)]
    pub robot_radius: f64,
    /// Extra width on each side of the swept path, m (default 0.05).
    #[default(crate::footprint::FOOTPRINT_MARGIN_M)]
    pub side_margin: f64,
    /// Distance kept to obstacles when stopped, m (default 0.10).
    #[default(0.10)]
    pub safety_distance: f64,
    /// Braking deceleration assumed, m/s² (default 1.5, below the base's 2.0).
    #[default(1.5)]
    pub max_decel: f64,
    /// Reaction time: scan period plus loop latency, s (default 0.15).
    #[default(0.15)]
    pub reaction_time_s: f64,
    /// Lidar position in the robot frame (x forward), m (default 0).
    #[default(0.0)]
    pub laser_x: f64,
    /// The envelope resolves speeds up to this, m/s, and reports this where more would be
    /// safe (default 2.0, twice the Robot's `max_linear_speed`).
    #[default(2.0)]
    pub envelope_max_speed: f64,
}

/// Free distance, m, the robot can travel with velocity `v` (sign = direction) and turn rate
/// `w` before its disc (radius `robot_radius + side_margin`) touches an obstacle point; the
/// arc of curvature `w/v` is followed for at most half a turn. `f64::INFINITY` if nothing is
/// in the way; 0 if an obstacle already overlaps the disc ahead.
pub fn free_distance(scan: &ScanView<'_>, v: f64, w: f64, cfg: &SafetyConfig) -> f64 {
    free_distance_of(scan.points(cfg.laser_x), v, w, cfg)
}

/// [`free_distance`] among `points` (x, y in the robot frame, m).
fn free_distance_of(
    points: impl Iterator<Item = (f64, f64)>,
    v: f64,
    w: f64,
    cfg: &SafetyConfig,
) -> f64 {
    if v == 0.0 {
        return f64::INFINITY;
    }
    let r = cfg.robot_radius + cfg.side_margin;
    let dir = v.signum();
    let k = w / v;
    let mut best = f64::INFINITY;
    for (x, y) in points {
        // Mirror so the motion is forward (+x).
        let (x, y) = (x * dir, y);
        let d = if k.abs() < 1e-3 {
            // A point level with the centre or behind it only gets farther as the robot
            // moves (even one inside the margin: moving away is never limited, so a robot
            // that ended up too close to a wall can always leave it).
            if y.abs() >= r || x <= 0.0 {
                continue;
            }
            // Distance along x until the disc edge reaches the point.
            (x - (r * r - y * y).sqrt()).max(0.0)
        } else {
            // Forward motion with curvature k (mirrored motion keeps k = w/v: a robot backing
            // up with w > 0 curves the same way in the mirrored frame).
            let rad = 1.0 / k;
            let (cx, cy) = (0.0, rad);
            let rho = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt();
            let off = rho - rad.abs();
            if off.abs() >= r {
                continue;
            }
            // Angle travelled around the centre from the robot to the point's projection.
            let a0 = (0.0 - cy).atan2(0.0 - cx);
            let ap = (y - cy).atan2(x - cx);
            let mut da = (ap - a0) * rad.signum();
            da = da.rem_euclid(2.0 * PI);
            if da > PI {
                // Behind: only counts if it touches the disc now and is ahead of the centre.
                if x * x + y * y < r * r && x > 0.0 {
                    0.0
                } else {
                    continue;
                }
            } else {
                let arc = rad.abs() * da;
                (arc - (r * r - off * off).sqrt()).max(0.0)
            }
        };
        best = best.min(d);
    }
    best
}

/// Largest speed, m/s, that still stops within `free` metres minus the safety distance,
/// with the reaction time and braking deceleration of `cfg`.
pub fn speed_limit(free: f64, cfg: &SafetyConfig) -> f64 {
    let d = free - cfg.safety_distance;
    if d.is_nan() || d <= 0.0 {
        return 0.0;
    }
    if d.is_infinite() {
        return f64::INFINITY;
    }
    let (a, t) = (cfg.max_decel, cfg.reaction_time_s);
    a * ((t * t + 2.0 * d / a).sqrt() - t)
}

/// What Security did to a command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decision {
    /// The command to send.
    pub cmd: Twist,
    /// Free distance along the path, m.
    pub free_m: f64,
    /// True if the speed was reduced.
    pub limited: bool,
}

/// Limits `desired` to the safe speed given the scan.
pub fn decide(desired: &Twist, scan: &ScanView<'_>, cfg: &SafetyConfig) -> Decision {
    let v = desired.linear_x;
    let w = desired.angular_z;
    if !(v.is_finite() && w.is_finite()) {
        return Decision {
            cmd: Twist::default(),
            free_m: 0.0,
            limited: true,
        };
    }
    let free = free_distance(scan, v, w, cfg);
    let vmax = speed_limit(free, cfg);
    let limited = v.abs() > vmax;
    let v2 = if limited { v.signum() * vmax } else { v };
    // Keep the curvature when slowing down, so the robot stays on the path it was checked on;
    // a full stop still lets the robot turn in place.
    let w2 = if limited && v2 != 0.0 { w * v2 / v } else { w };
    Decision {
        cmd: Twist {
            linear_x: v2,
            linear_y: 0.0,
            angular_z: w2,
            ..Default::default()
        },
        free_m: free,
        limited,
    }
}

/// The speed-limit envelope of one scan ([`SpeedEnvelope`]): for the curvature of every bin,
/// forward and backward, the [`speed_limit`] of the [`free_distance`] along that arc, capped at
/// `cfg.envelope_max_speed`; and the free distance straight ahead, m. Only the points that can
/// matter below the cap are looked at (closer than the disc radius plus the distance needed
/// to stop from the cap): a farther point leaves more than that distance free on any arc, so
/// the capped limit is exact.
pub fn envelope(scan: &ScanView<'_>, cfg: &SafetyConfig) -> (SpeedEnvelope, f64) {
    let cap = cfg.envelope_max_speed;
    let stopping =
        cfg.safety_distance + cap * cfg.reaction_time_s + cap * cap / (2.0 * cfg.max_decel);
    let reach = cfg.robot_radius + cfg.side_margin + stopping;
    let near: Vec<(f64, f64)> = scan
        .points(cfg.laser_x)
        .filter(|(x, y)| x * x + y * y <= reach * reach)
        .collect();
    let mut env = SpeedEnvelope {
        stop: 0,
        turn_in_place: f64::INFINITY,
        ..Default::default()
    };
    for i in 0..ENVELOPE_BINS {
        let k = envelope_bin_curvature(i);
        let fwd = free_distance_of(near.iter().copied(), 1.0, k, cfg);
        let back = free_distance_of(near.iter().copied(), -1.0, -k, cfg);
        env.forward[i] = speed_limit(fwd, cfg).min(cap);
        env.backward[i] = speed_limit(back, cfg).min(cap);
    }
    let ahead = free_distance_of(near.iter().copied(), 1.0, 0.0, cfg);
    (env, ahead)
}

/// Configuration of `hng module security`.
#[derive(Debug, Clone, Deserialize, SmartDefault)]
#[serde(default, deny_unknown_fields)]
pub struct SecurityModuleConfig {
    /// Lidar input until a "LIDAR data" provider is known (default `laser/scan`).
    #[default("laser/scan".into())]
    pub scan: String,
    /// Static wiring, for systems without contracts (the `hng bench loop`): the channel of
    /// the desired commands, which Security limits itself and sends on `cmd_out` (default
    /// empty: contract mode, where Security publishes its envelope for the Robot).
    pub cmd_in: String,
    /// Static wiring: a desired command counts for this long, s (default 0.5).
    #[default(0.5)]
    pub freshness_s: f64,
    /// Output of the static wiring (with `cmd_in`; default `security/cmd_vel`).
    #[default("security/cmd_vel".into())]
    pub cmd_out: String,
    /// No scan for this long: stop and report inaptitude, s (default 0.5).
    #[default(0.5)]
    pub scan_timeout_s: f64,
    /// The safety envelope.
    #[default(SafetyConfig::default())]
    pub safety: SafetyConfig,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct SecurityState {
    /// Envelopes published (contracts) or commands decided (static wiring).
    decisions: u64,
    /// Of those, how many limited the speed straight ahead (envelopes) or the command.
    limited: u64,
    stops_no_scan: u64,
    /// Smallest free distance seen straight ahead (envelopes) or along a command, m.
    min_free_m: f64,
}

/// Where Security's verdict goes.
#[derive(Debug)]
enum Link {
    /// Contract mode: the Robot serving the "Robot control" need, and its envelope channel
    /// ([`envelope_channel`] of the Robot's channel).
    Robot {
        robot: ProviderInfo,
        out: Publisher<SpeedEnvelope>,
    },
    /// The static wiring: desired commands in, limited commands out.
    Static {
        desired: Subscriber<Twist>,
        out: Publisher<Twist>,
    },
}

/// The Security module.
#[derive(Debug)]
pub struct SecurityModule {
    scan: ProviderInput<LaserScan>,
    /// `None` until the Robot is contracted (contract mode).
    link: Option<Link>,
    freshness: Duration,
    /// Static wiring: the latest desired command and when it came.
    desired: Option<(Duration, Twist)>,
    /// The latest scan, still in shared memory (a loaned sample, not a copy).
    last_scan: Option<Sample<LaserScan>>,
    cfg: SafetyConfig,
    state: SecurityState,
    was_limited: bool,
}

impl SecurityModule {
    /// Publishes the verdict on the current scan: the envelope to the Robot (the stop
    /// envelope without a fresh scan), or, in the static wiring, the limited desired command.
    fn act(&mut self, ctx: &mut Context) -> ModuleResult {
        match &self.link {
            None => Ok(()),
            Some(Link::Robot { out, .. }) => {
                let Some(scan) = &self.last_scan else {
                    out.publish(SpeedEnvelope::stopped(ctx.now().as_nanos() as u64))?;
                    return Ok(());
                };
                let (mut env, ahead) = envelope(&ScanView::of(scan), &self.cfg);
                env.scan_stamp_ns = scan.header.stamp_ns;
                out.publish(env)?;
                let mid = ENVELOPE_BINS / 2;
                let limited = env.forward[mid] < self.cfg.envelope_max_speed;
                self.count(ctx, ahead, limited, env.forward[mid]);
                Ok(())
            }
            Some(Link::Static { out, .. }) => {
                let now = ctx.now();
                let desired = match self.desired {
                    Some((at, cmd)) if now.saturating_sub(at) < self.freshness => cmd,
                    _ => Twist::default(), // nobody commands: hold still
                };
                let Some(scan) = &self.last_scan else {
                    out.publish(Twist::default())?;
                    return Ok(());
                };
                let d = decide(&desired, &ScanView::of(scan), &self.cfg);
                out.publish(d.cmd)?;
                self.count(ctx, d.free_m, d.limited, d.cmd.linear_x);
                Ok(())
            }
        }
    }

    fn count(&mut self, ctx: &Context, free_m: f64, limited: bool, v: f64) {
        self.state.decisions += 1;
        if limited {
            self.state.limited += 1;
        }
        if free_m.is_finite() {
            self.state.min_free_m = self.state.min_free_m.min(free_m);
        }
        if limited != self.was_limited {
            tracing::debug!(module = ctx.name(), free_m, v, limited, "speed limit");
            self.was_limited = limited;
        }
    }

    /// Publishes the stop verdict (exit, lost lidar, a Robot left).
    fn stop_now(&self, now: Duration) -> ModuleResult {
        match &self.link {
            Some(Link::Robot { out, .. }) => {
                out.publish(SpeedEnvelope::stopped(now.as_nanos() as u64))?
            }
            Some(Link::Static { out, .. }) => out.publish(Twist::default())?,
            None => {}
        }
        Ok(())
    }
}

impl Module for SecurityModule {
    type Config = SecurityModuleConfig;

    fn configure(ctx: &mut Context, cfg: SecurityModuleConfig) -> ModuleResult<Self> {
        check_fields!(positive, cfg.safety, "safety"; robot_radius, max_decel, reaction_time_s, envelope_max_speed)?;
        crate::common::non_negative("safety.safety_distance", cfg.safety.safety_distance)?;
        let freshness = seconds("freshness_s", cfg.freshness_s)?;
        let scan_timeout = seconds("scan_timeout_s", cfg.scan_timeout_s)?;
        // Provides the Manager's objective "Robot integrity"; needs "Robot control" (1.1: the
        // Robot's most important client, whose envelope the Robot applies) and "LIDAR data"
        // (1.2).
        ctx.provide(ServiceOffer::new("Robot integrity", ""))
            .need(NeedSpec::required(ROBOT_CONTROL, ROBOT_CONTROL_NEED))
            .need(NeedSpec::required("LIDAR data", LIDAR_NEED));
        let link = if cfg.cmd_in.is_empty() {
            None
        } else {
            Some(Link::Static {
                desired: ctx.subscribe(&cfg.cmd_in, None)?,
                out: ctx.publisher(&cfg.cmd_out)?,
            })
        };
        ctx.set_quality(false, -1.0);
        Ok(SecurityModule {
            scan: ProviderInput::new()
                .with_deadline(Some(scan_timeout))
                .with_fallback(ctx, &cfg.scan)?,
            link,
            freshness,
            desired: None,
            last_scan: None,
            cfg: cfg.safety,
            state: SecurityState {
                min_free_m: f64::INFINITY,
                ..Default::default()
            },
            was_limited: false,
        })
    }

    fn on_input(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult {
        if self.scan.is(input) {
            let mut got = false;
            while let Some(s) = self.scan.receive()? {
                // The previous sample goes back to its publisher: at most two are held.
                self.last_scan = Some(s);
                got = true;
            }
            if got {
                if let Some(s) = &self.last_scan {
                    let (ok, q) = scan_quality(s);
                    ctx.set_quality(ok, q);
                }
                self.act(ctx)?;
            }
            return Ok(());
        }
        let Some(Link::Static { desired, .. }) = &self.link else {
            return Ok(());
        };
        if desired.id() != input {
            return Ok(());
        }
        let mut got = false;
        while let Some(cmd) = desired.receive()? {
            self.desired = Some((ctx.now(), *cmd));
            got = true;
        }
        if got {
            self.act(ctx)?;
        }
        Ok(())
    }

    fn on_provider_changed(
        &mut self,
        ctx: &mut Context,
        need: u16,
        provider: Option<&ProviderInfo>,
    ) -> ModuleResult {
        if need == LIDAR_NEED {
            self.scan.follow(ctx, provider)?;
            return Ok(());
        }
        // The static wiring keeps its channels.
        if need != ROBOT_CONTROL_NEED || matches!(self.link, Some(Link::Static { .. })) {
            return Ok(());
        }
        let same = matches!((&self.link, provider), (Some(Link::Robot { robot, .. }), Some(b)) if robot == b);
        if same {
            return Ok(());
        }
        // Leave the old Robot stopped.
        let _ = self.stop_now(ctx.now());
        self.link = provider
            .filter(|p| !p.channel.is_empty())
            .map(|p| -> ModuleResult<Link> {
                Ok(Link::Robot {
                    robot: p.clone(),
                    out: ctx.publisher(&envelope_channel(&p.channel))?,
                })
            })
            .transpose()?;
        // The new Robot hears the verdict on the current scan at once (the stop envelope
        // without one): from now on it obeys it.
        self.act(ctx)
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no lidar scan: stopping the robot");
        self.last_scan = None;
        self.state.stops_no_scan += 1;
        ctx.set_quality(false, -1.0);
        self.stop_now(ctx.now())
    }

    hng_runtime::checkpoint_field!(state);

    fn stop(&mut self, ctx: &mut Context) {
        let _ = self.stop_now(ctx.now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 360-beam scan of a wall perpendicular to x at distance `wall` (nothing elsewhere).
    fn wall_scan(wall: f64) -> Vec<f32> {
        (0..360)
            .map(|i| {
                let a = -PI + (i as f64) * PI / 180.0;
                if a.cos() > 1e-6 {
                    let r = wall / a.cos();
                    if r < 10.0 { r as f32 } else { f32::INFINITY }
                } else {
                    f32::INFINITY
                }
            })
            .collect()
    }

    fn view(r: &[f32]) -> ScanView<'_> {
        ScanView {
            angle_min: -PI,
            angle_increment: PI / 180.0,
            range_min: 0.05,
            ranges: r,
        }
    }

    fn fwd(v: f64, w: f64) -> Twist {
        Twist {
            linear_x: v,
            angular_z: w,
            ..Default::default()
        }
    }

    /// The `LaserScan` message of [`wall_scan`].
    fn wall_msg(wall: f64) -> LaserScan {
        LaserScan::full_circle(&wall_scan(wall), 0.05, 10.0)
    }

    /// The module's own loop (in-process harness) under contracts served by the test: its
    /// Robot hears the stop envelope as soon as it is contracted (no scan yet), then one
    /// envelope per scan: far from walls nothing is limited; before a wall a command towards
    /// it is held (turning allowed) and one away from it is not; a silent lidar is one
    /// deadline miss, the stop envelope and inaptitude.
    #[test]
    fn the_module_publishes_an_envelope_per_scan_and_the_stop_envelope_without_scans() {
        use hng_runtime::harness::Harness;
        let mut h = Harness::new("security").unwrap();
        let scan = h.input::<LaserScan>("test/scan").unwrap();
        let mut out = h
            .output::<SpeedEnvelope>(&crate::robot::envelope_channel("test/cmd_vel"))
            .unwrap();
        h.provider(LIDAR_NEED, "test/scan")
            .provider(ROBOT_CONTROL_NEED, "test/cmd_vel");
        h.start::<SecurityModule>("scan_timeout_s = 0.3").unwrap();
        let wait = std::time::Duration::from_secs(5);
        let first = h.wait_for(&mut out, wait, |_| true).unwrap();
        assert_eq!(first.stop, 1, "no scan yet: stop");

        scan.publish(wall_msg(5.0)).unwrap();
        let far = h.wait_for(&mut out, wait, |e| e.stop == 0).unwrap();
        assert_eq!(far.limit(&fwd(1.0, 0.0)), (fwd(1.0, 0.0), false), "{far:?}");
        assert_eq!(far.limit(&fwd(0.8, -0.5)), (fwd(0.8, -0.5), false));

        scan.publish(wall_msg(0.32)).unwrap();
        let near = h
            .wait_for(&mut out, wait, |e| {
                e.stop == 0 && e.forward[ENVELOPE_BINS / 2] == 0.0
            })
            .unwrap();
        assert_eq!(
            near.limit(&fwd(0.5, 0.4)),
            (fwd(0.0, 0.4), true),
            "held, turning"
        );
        assert_eq!(near.limit(&fwd(-0.3, 0.0)), (fwd(-0.3, 0.0), false), "away");
        assert!(near.scan_stamp_ns > 0);

        // No more scans: after scan_timeout_s, one miss, the stop envelope, Q = -1.
        let n = out.samples.len();
        let report = h.wait_for_report(wait, |r| r.deadline_misses > 0).unwrap();
        assert_eq!(report.deadline_misses, 1, "one silence, one miss");
        assert_eq!((report.aptitude, report.quality), (0, -1.0));
        let stop = h.wait_for(&mut out, wait, |e| e.stop == 1).unwrap();
        assert_eq!(stop.limit(&fwd(0.0, 0.5)).0, Twist::default());
        assert!(out.samples[n..].iter().any(|c| c.msg.stop == 1));
        h.finish().unwrap();
    }

    /// The envelope agrees with the per-command decision it replaces: exactly at the bins'
    /// curvatures, and between them never faster than the decision by more than the
    /// `tolerance` (the lower neighbour holds).
    #[test]
    fn the_envelope_limits_as_the_per_command_decision_does() {
        let cfg = SafetyConfig::default();
        let mut worst: f64 = 0.0;
        for wall in [0.32, 0.45, 0.6, 1.0, 1.5] {
            // A wall ahead and a post to the left front.
            let mut r = wall_scan(wall);
            r[200] = 0.7;
            let (env, ahead) = envelope(&view(&r), &cfg);
            assert!((ahead - free_distance(&view(&r), 1.0, 0.0, &cfg)).abs() < 1e-9);
            for i in 0..ENVELOPE_BINS {
                let k = envelope_bin_curvature(i);
                for v in [1.0, -1.0] {
                    let exact = speed_limit(free_distance(&view(&r), v, v * k, &cfg), &cfg)
                        .min(cfg.envelope_max_speed);
                    let got = if v > 0.0 {
                        env.forward[i]
                    } else {
                        env.backward[i]
                    };
                    assert!(
                        (got - exact).abs() < 1e-9,
                        "bin {i}, v {v}: {got} vs {exact}"
                    );
                }
            }
            for n in 0..2000 {
                let k = -6.0 + 12.0 * n as f64 / 2000.0;
                for v in [1.0, -1.0] {
                    let exact = speed_limit(free_distance(&view(&r), v, v * k, &cfg), &cfg)
                        .min(cfg.envelope_max_speed);
                    worst = worst.max(env.max_speed(v > 0.0, k) - exact);
                }
            }
        }
        eprintln!("worst excess between bins: {worst} m/s");
        assert!(worst < 0.01, "{worst}");
    }

    #[test]
    fn free_distance_to_a_wall_ahead_is_its_distance_minus_the_radius() {
        let cfg = SafetyConfig::default();
        let r = wall_scan(2.0);
        let d = free_distance(&view(&r), 0.5, 0.0, &cfg);
        assert!((d - 1.75).abs() < 0.01, "{d}");
        assert_eq!(free_distance(&view(&r), -0.5, 0.0, &cfg), f64::INFINITY);
        assert_eq!(free_distance(&view(&r), 0.0, 1.0, &cfg), f64::INFINITY);
    }

    #[test]
    fn a_robot_inside_the_margin_of_a_wall_may_leave_it_but_not_approach_it() {
        let cfg = SafetyConfig::default();
        // The wall 0.22 m ahead: inside the 0.25 m disc of robot radius and side margin.
        let r = wall_scan(0.22);
        assert_eq!(free_distance(&view(&r), 0.5, 0.0, &cfg), 0.0, "towards it");
        assert_eq!(
            free_distance(&view(&r), 0.3, 0.6, &cfg),
            0.0,
            "arc towards it"
        );
        assert_eq!(
            free_distance(&view(&r), -0.3, 0.0, &cfg),
            f64::INFINITY,
            "away"
        );
        assert_eq!(
            free_distance(&view(&r), -0.3, 0.5, &cfg),
            f64::INFINITY,
            "arc away"
        );
        let d = decide(&fwd(-0.3, 0.0), &view(&r), &cfg);
        assert!(!d.limited && d.cmd.linear_x == -0.3, "{d:?}");
    }

    #[test]
    fn a_gentle_arc_sees_the_wall_a_sharp_one_turning_away_later() {
        let cfg = SafetyConfig::default();
        let r = wall_scan(2.0);
        let straight = free_distance(&view(&r), 0.5, 0.0, &cfg);
        let arc = free_distance(&view(&r), 0.5, 0.2, &cfg);
        assert!(
            arc.is_finite() && arc >= straight - 1e-9,
            "{arc} vs {straight}"
        );
        // Radius 0.5 m: the robot turns around before it reaches the wall.
        assert_eq!(free_distance(&view(&r), 0.5, 1.0, &cfg), f64::INFINITY);
    }

    #[test]
    fn braking_model_stops_within_the_free_distance() {
        let cfg = SafetyConfig::default();
        for free in [0.2, 0.5, 1.0, 3.0] {
            let v = speed_limit(free, &cfg);
            let needed = v * cfg.reaction_time_s + v * v / (2.0 * cfg.max_decel);
            assert!(
                (needed - (free - cfg.safety_distance).max(0.0)).abs() < 1e-9,
                "{free}"
            );
        }
        assert_eq!(speed_limit(0.05, &cfg), 0.0, "inside the safety distance");
        assert_eq!(speed_limit(f64::INFINITY, &cfg), f64::INFINITY);
    }

    #[test]
    fn security_slows_then_stops_before_a_wall_and_lets_the_robot_back_off() {
        let cfg = SafetyConfig::default();
        let far = wall_scan(5.0);
        assert!(!decide(&fwd(1.0, 0.0), &view(&far), &cfg).limited);
        let mid = wall_scan(0.6);
        let d = decide(&fwd(1.0, 0.3), &view(&mid), &cfg);
        assert!(
            d.limited && d.cmd.linear_x > 0.0 && d.cmd.linear_x < 1.0,
            "{d:?}"
        );
        assert!(
            (d.cmd.angular_z / d.cmd.linear_x - 0.3).abs() < 1e-9,
            "curvature kept"
        );
        let near = wall_scan(0.32);
        let d = decide(&fwd(0.5, 0.4), &view(&near), &cfg);
        assert_eq!(d.cmd.linear_x, 0.0, "{d:?}");
        assert_eq!(d.cmd.angular_z, 0.4, "turning in place stays allowed");
        let back = decide(&fwd(-0.3, 0.0), &view(&near), &cfg);
        assert_eq!(back.cmd.linear_x, -0.3, "backing away is not limited");
    }

    #[test]
    fn simulated_approach_at_full_speed_stops_short_of_the_wall() {
        // Kinematic robot with the base's acceleration limit, commanded 1 m/s at a wall 4 m
        // ahead, security deciding at 10 Hz on scans 0.05 s old.
        let cfg = SafetyConfig::default();
        let (dt, accel) = (0.01, 2.0);
        let (mut x, mut v, mut cmd) = (0.0_f64, 0.0_f64, 0.0_f64);
        let wall = 4.0;
        let mut pending: Option<(f64, f64)> = None;
        for step in 0..1000 {
            let t = step as f64 * dt;
            if step % 10 == 0 {
                let scan = wall_scan(wall - x);
                pending = Some((
                    t + 0.05,
                    decide(&fwd(1.0, 0.0), &view(&scan), &cfg).cmd.linear_x,
                ));
            }
            if let Some((at, c)) = pending
                && t >= at
            {
                cmd = c;
                pending = None;
            }
            let dv = (cmd - v).clamp(-accel * dt, accel * dt);
            v += dv;
            x += v * dt;
            assert!(x + cfg.robot_radius < wall, "contact at t={t}");
        }
        let gap = wall - x - cfg.robot_radius;
        assert!(v.abs() < 1e-6, "stopped");
        assert!(
            gap > 0.05 && gap < 0.4,
            "stops close but not touching: gap {gap}"
        );
    }

    #[test]
    fn quality_counts_invalid_beams() {
        let r = [1.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        assert_eq!(view(&r).invalid_fraction(), 0.25);
        assert_eq!(view(&[]).invalid_fraction(), 1.0);
    }
}
