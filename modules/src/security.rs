//! Security: robot integrity (Table 1: provides "Robot integrity", needs "Robot control" and
//! "LIDAR data"; data in: lidar, data out: commands).
//!
//! Security answers the Manager's objective 1, so its "Robot control" contract with the Robot
//! driver has priority 1.1, the most important of the Robot's clients (paper 5.8): while it
//! commands, the Robot obeys only it. The other clients (the operator's Interface 2.1, the
//! Servo-controller 2.2.1.1) send their commands to the Robot's channel as well; Security
//! reads them there, takes the command of the most important live one (the priorities of the
//! Robot's contracts, from the Robot's contract table on `hng/contracts`), limits its speed to
//! what the lidar says is safe, and sends the result to the Robot at every scan and every
//! desired command. When no client commands, it commands a stop: the robot holds still.
//! Without a fresh scan it commands a stop too (it cannot vouch for anything it cannot see).
//! The lidar comes from its "LIDAR data" provider (the configured `scan` channel until one is
//! known).
//!
//! Without contracts (benches, systems without a Manager), `sources` wires the clients
//! statically with configured priorities, and the result goes to `cmd_out`.
//!
//! The speed limit ([`speed_limit`]): the free distance `d` along the robot's path (the swept
//! disc of radius `robot_radius + side_margin`, straight or along the arc of the commanded
//! curvature, [`free_distance`]) minus `safety_distance` must cover the reaction distance and
//! the braking distance: `v·t_r + v²/(2·a) ≤ d`, so `v_max = a·(√(t_r² + 2d/a) − t_r)`, with
//! `a` the braking deceleration and `t_r` the reaction time (scan period plus loop latency).
//! Below the safety distance `v_max` is 0. Turning in place is never limited (the robot is
//! a disc), and moving away from an obstacle is not limited by it.
//!
//! Quality Q: `1 − 2·(fraction of invalid (NaN) beams)` while scans arrive; -1 (aptitude 0)
//! when they stop.

use std::f64::consts::PI;

use hng_runtime::channel::InputId;
use hng_runtime::contract::{NeedSpec, ServiceOffer};
use hng_runtime::control::ProviderInfo;
use hng_runtime::msg::{LaserScan, Twist};
use hng_runtime::system::{CONTRACTS, ContractTable};
use hng_runtime::{Context, Module, ModuleResult, Publisher, Subscriber};
use serde::{Deserialize, Serialize};

use crate::common::{
    CommandMux, CommandSource, ContractHolders, ContractedInput, MuxAction, decode_state,
    encode_state, positive, seconds,
};
use crate::robot::ROBOT_CONTROL;

/// Rank of Security's "Robot control" need (contract priority `P(security).1`: 1.1).
pub const ROBOT_CONTROL_NEED: u16 = 1;
/// Rank of Security's "LIDAR data" need (1.2).
pub const LIDAR_NEED: u16 = 2;

/// Parameters of the safety envelope.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct SafetyConfig {
    /// Robot radius, m (default 0.2).
    pub robot_radius: f64,
    /// Extra width on each side of the swept path, m (default 0.05).
    pub side_margin: f64,
    /// Distance kept to obstacles when stopped, m (default 0.10).
    pub safety_distance: f64,
    /// Braking deceleration assumed, m/s² (default 1.5, below the base's 2.0).
    pub max_decel: f64,
    /// Reaction time: scan period plus loop latency, s (default 0.15).
    pub reaction_time_s: f64,
    /// Lidar position in the robot frame (x forward), m (default 0).
    pub laser_x: f64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        SafetyConfig {
            robot_radius: crate::footprint::ROBOT_RADIUS_M,
            side_margin: crate::footprint::FOOTPRINT_MARGIN_M,
            safety_distance: 0.10,
            max_decel: 1.5,
            reaction_time_s: 0.15,
            laser_x: 0.0,
        }
    }
}

/// A scan as the geometry needs it.
#[derive(Debug, Clone, Copy)]
pub struct ScanView<'a> {
    /// Angle of beam 0, rad.
    pub angle_min: f64,
    /// Angle between beams, rad.
    pub angle_increment: f64,
    /// Smallest valid range (`-inf` readings are placed there), m.
    pub range_min: f64,
    /// Ranges, m (`+inf`: nothing hit, `-inf`: too close, NaN: invalid).
    pub ranges: &'a [f32],
}

impl<'a> ScanView<'a> {
    /// A view of a scan message.
    pub fn of(scan: &'a LaserScan) -> ScanView<'a> {
        ScanView {
            angle_min: f64::from(scan.angle_min),
            angle_increment: f64::from(scan.angle_increment),
            range_min: f64::from(scan.range_min),
            ranges: scan.ranges(),
        }
    }

    /// Obstacle points in the robot frame.
    pub fn points(&self, laser_x: f64) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.ranges.iter().enumerate().filter_map(move |(i, &r)| {
            let r = if r == f32::NEG_INFINITY {
                self.range_min.max(0.0)
            } else if r.is_finite() {
                f64::from(r)
            } else {
                return None;
            };
            let a = self.angle_min + self.angle_increment * i as f64;
            Some((laser_x + r * a.cos(), r * a.sin()))
        })
    }

    /// Fraction of NaN beams (0 for an empty scan).
    pub fn invalid_fraction(&self) -> f64 {
        if self.ranges.is_empty() {
            return 1.0;
        }
        self.ranges.iter().filter(|r| r.is_nan()).count() as f64 / self.ranges.len() as f64
    }
}

/// Free distance, m, the robot can travel with velocity `v` (sign = direction) and turn rate
/// `w` before its disc (radius `robot_radius + side_margin`) touches an obstacle point; the
/// arc of curvature `w/v` is followed for at most half a turn. `f64::INFINITY` if nothing is
/// in the way; 0 if an obstacle already overlaps the disc ahead.
pub fn free_distance(scan: &ScanView<'_>, v: f64, w: f64, cfg: &SafetyConfig) -> f64 {
    if v == 0.0 {
        return f64::INFINITY;
    }
    let r = cfg.robot_radius + cfg.side_margin;
    let dir = v.signum();
    let k = w / v;
    let mut best = f64::INFINITY;
    for (x, y) in scan.points(cfg.laser_x) {
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

/// Configuration of `hng module security`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SecurityModuleConfig {
    /// Lidar input until a "LIDAR data" provider is known (default `laser/scan`).
    pub scan: String,
    /// Static clients whose commands are made safe, with configured priorities, for systems
    /// without contracts (default none: the clients are the Robot's contract holders).
    pub sources: Vec<CommandSource>,
    /// A client's command counts for this long, s (default 0.5).
    pub freshness_s: f64,
    /// Output of the static mode (with `sources`; default `security/cmd_vel`). With contracts
    /// the output is the Robot's "Robot control" channel.
    pub cmd_out: String,
    /// No scan for this long: stop and report inaptitude, s (default 0.5).
    pub scan_timeout_s: f64,
    /// The safety envelope.
    pub safety: SafetyConfig,
}

impl Default for SecurityModuleConfig {
    fn default() -> Self {
        SecurityModuleConfig {
            scan: "laser/scan".into(),
            sources: Vec::new(),
            freshness_s: 0.5,
            cmd_out: "security/cmd_vel".into(),
            scan_timeout_s: 0.5,
            safety: SafetyConfig::default(),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
struct SecurityState {
    decisions: u64,
    limited: u64,
    stops_no_scan: u64,
    min_free_m: f64,
}

/// Where Security's commands go and where the desired ones come from.
#[derive(Debug)]
enum Wiring {
    /// `sources` configured: a mux keyed by source index, output on `cmd_out`.
    Static {
        sources: Vec<Subscriber<Twist>>,
        cmd_out: Publisher<Twist>,
    },
    /// The Robot's "Robot control" channel, once contracted: its other clients' commands in,
    /// Security's out; the mux is keyed by module id with the priorities of the Robot's
    /// contracts.
    Contract {
        robot: Option<(ProviderInfo, Subscriber<Twist>, Publisher<Twist>)>,
        tables: Subscriber<ContractTable>,
        holders: ContractHolders,
    },
}

/// The Security module.
#[derive(Debug)]
pub struct SecurityModule {
    scan: ContractedInput<LaserScan>,
    wiring: Wiring,
    mux: CommandMux,
    desired: Option<(u32, Twist)>,
    last_scan: Option<LaserScan>,
    cfg: SafetyConfig,
    state: SecurityState,
    was_limited: bool,
}

impl SecurityModule {
    /// Sends a command to the Robot (nothing before a "Robot control" contract).
    fn send(&self, cmd: Twist) -> ModuleResult {
        match &self.wiring {
            Wiring::Static { cmd_out, .. } => cmd_out.publish(cmd)?,
            Wiring::Contract {
                robot: Some((_, _, out)),
                ..
            } => out.publish(cmd)?,
            Wiring::Contract { robot: None, .. } => {}
        }
        Ok(())
    }

    /// Decides and publishes the command for the current scan and desired command.
    fn act(&mut self, ctx: &mut Context) -> ModuleResult {
        let now = ctx.now();
        let active = self.mux.active(now);
        let desired = match (self.desired, active) {
            (Some((src, cmd)), Some(a)) if src == a => cmd,
            _ => Twist::default(), // nobody commands: hold still
        };
        let Some(scan) = &self.last_scan else {
            self.send(Twist::default())?;
            return Ok(());
        };
        let d = decide(&desired, &ScanView::of(scan), &self.cfg);
        self.state.decisions += 1;
        if d.limited {
            self.state.limited += 1;
        }
        if d.free_m.is_finite() {
            self.state.min_free_m = self.state.min_free_m.min(d.free_m);
        }
        if d.limited != self.was_limited {
            tracing::debug!(
                module = ctx.name(),
                free_m = d.free_m,
                v = d.cmd.linear_x,
                limited = d.limited,
                "speed limit"
            );
            self.was_limited = d.limited;
        }
        self.send(d.cmd)?;
        Ok(())
    }

    /// Reads the desired commands of the clients on `input`; true if one was taken.
    fn read_commands(&mut self, ctx: &mut Context, input: InputId) -> ModuleResult<bool> {
        let now = ctx.now();
        let own = ctx.module_id().0;
        let mut got = false;
        match &self.wiring {
            Wiring::Static { sources, .. } => {
                let Some(i) = sources.iter().position(|s| s.id() == input) else {
                    return Ok(false);
                };
                while let Some(cmd) = sources[i].receive()? {
                    if let MuxAction::Send(c) = self.mux.on_command(i as u32, &cmd, now) {
                        self.desired = Some((i as u32, c));
                        got = true;
                    }
                }
            }
            Wiring::Contract {
                robot: Some((_, sub, _)),
                ..
            } if sub.id() == input => {
                while let Some(cmd) = sub.receive()? {
                    let from = cmd.header.source;
                    if from == own {
                        continue; // our own commands to the Robot
                    }
                    if let MuxAction::Send(c) = self.mux.on_command(from, &cmd, now) {
                        self.desired = Some((from, c));
                        got = true;
                    }
                }
            }
            Wiring::Contract { .. } => {}
        }
        Ok(got)
    }

    /// Reads the contract tables: the Robot's tells who may command and with what priority.
    fn read_tables(&mut self, ctx: &mut Context) -> ModuleResult {
        let own = ctx.module_id();
        let Wiring::Contract {
            robot,
            tables,
            holders,
        } = &mut self.wiring
        else {
            return Ok(());
        };
        let provider = robot.as_ref().map(|(p, _, _)| p.module);
        let mut changed = false;
        while let Some(t) = tables.receive()? {
            if let Some(p) = provider {
                changed |= holders.update(&t, p, ROBOT_CONTROL, own);
            }
        }
        if changed {
            tracing::debug!(module = ctx.name(), holders = ?holders.holders(), "Robot control clients");
            self.mux.sync(holders.holders().iter().copied());
        }
        Ok(())
    }
}

impl Module for SecurityModule {
    type Config = SecurityModuleConfig;

    fn configure(ctx: &mut Context, cfg: SecurityModuleConfig) -> ModuleResult<Self> {
        let s = &cfg.safety;
        positive("safety.robot_radius", s.robot_radius)?;
        positive("safety.max_decel", s.max_decel)?;
        positive("safety.reaction_time_s", s.reaction_time_s)?;
        if !(s.safety_distance.is_finite() && s.safety_distance >= 0.0) {
            return Err(
                crate::common::field_error("safety.safety_distance", "must be >= 0").into(),
            );
        }
        let freshness = seconds("freshness_s", cfg.freshness_s)?;
        let scan_timeout = seconds("scan_timeout_s", cfg.scan_timeout_s)?;
        // Provides the Manager's objective "Robot integrity"; needs "Robot control" (1.1: the
        // Robot's most important client) and "LIDAR data" (1.2).
        ctx.provide(ServiceOffer::new("Robot integrity", ""))
            .need(NeedSpec::required(ROBOT_CONTROL, ROBOT_CONTROL_NEED))
            .need(NeedSpec::required("LIDAR data", LIDAR_NEED));
        let (wiring, mux) = if cfg.sources.is_empty() {
            let wiring = Wiring::Contract {
                robot: None,
                tables: ctx.subscribe(CONTRACTS, None)?,
                holders: ContractHolders::default(),
            };
            (wiring, CommandMux::contracted(freshness))
        } else {
            let mux = CommandMux::new(&cfg.sources, freshness)?;
            let mut sources = Vec::new();
            for src in &cfg.sources {
                sources.push(ctx.subscribe::<Twist>(&src.channel, None)?);
            }
            let cmd_out = ctx.publisher(&cfg.cmd_out)?;
            (Wiring::Static { sources, cmd_out }, mux)
        };
        ctx.set_quality(false, -1.0);
        Ok(SecurityModule {
            scan: ContractedInput::new(ctx, &cfg.scan, Some(scan_timeout))?,
            wiring,
            mux,
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
                self.last_scan = Some(*s);
                got = true;
            }
            if got {
                if let Some(s) = &self.last_scan {
                    let bad = ScanView::of(s).invalid_fraction();
                    ctx.set_quality(bad < 0.5, (1.0 - 2.0 * bad) as f32);
                }
                self.act(ctx)?;
            }
            return Ok(());
        }
        if let Wiring::Contract { tables, .. } = &self.wiring
            && tables.id() == input
        {
            return self.read_tables(ctx);
        }
        if self.read_commands(ctx, input)? {
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
        if need != ROBOT_CONTROL_NEED {
            return Ok(());
        }
        let Wiring::Contract { robot, holders, .. } = &mut self.wiring else {
            return Ok(());
        };
        let same = matches!((robot.as_ref(), provider), (Some((a, _, _)), Some(b)) if a == b);
        if same {
            return Ok(());
        }
        if let Some((_, sub, out)) = robot.take() {
            // Leave the old Robot stopped.
            let _ = out.publish(Twist::default());
            ctx.unsubscribe(sub.id())?;
        }
        holders.clear();
        self.mux.sync(std::iter::empty());
        self.desired = None;
        if let Some(p) = provider.filter(|p| !p.channel.is_empty()) {
            let sub = ctx.subscribe::<Twist>(&p.channel, None)?;
            let out = ctx.publisher::<Twist>(&p.channel)?;
            *robot = Some((p.clone(), sub, out));
        }
        Ok(())
    }

    fn on_deadline_missed(&mut self, ctx: &mut Context, _input: InputId) -> ModuleResult {
        tracing::warn!(module = ctx.name(), "no lidar scan: stopping the robot");
        self.last_scan = None;
        self.state.stops_no_scan += 1;
        ctx.set_quality(false, -1.0);
        self.send(Twist::default())?;
        Ok(())
    }

    fn checkpoint(&self) -> Option<Vec<u8>> {
        encode_state(&self.state)
    }

    fn restore(&mut self, state: &[u8]) -> ModuleResult {
        self.state = decode_state(state)?;
        Ok(())
    }

    fn stop(&mut self, _ctx: &mut Context) {
        let _ = self.send(Twist::default());
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
