//! Helpers shared by the navigation modules: command sources arbitrated by priority (a
//! driver's static wiring), configuration checks, poses, angles. (Inputs and outputs that follow
//! a contracted provider are the runtime's: `hng_runtime::control::ProviderInput`.)

use std::time::Duration;

use hng_runtime::contract::{CommandArbiter, ModuleId, Priority, Verdict};
use hng_runtime::msg::{Pose2D, Twist};
use serde::{Deserialize, Serialize};

/// One client that may command a driver without contracts (static wiring for benches and
/// systems without a Manager): the channel it publishes on and the priority it is given
/// (paper 5.5: smaller is more important, `1.1` beats `2.1` beats `2.2.1.1`). With contracts
/// the clients and their priorities come from the contract tree instead.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CommandSource {
    /// Channel of `Twist` commands.
    pub channel: String,
    /// Dotted priority, e.g. `"1.1"`.
    pub priority: String,
}

impl CommandSource {
    /// A source.
    pub fn new(channel: &str, priority: &str) -> CommandSource {
        CommandSource {
            channel: channel.into(),
            priority: priority.into(),
        }
    }
}

/// Why a configuration is unusable.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// A field has an unusable value.
    #[error("field `{field}`: {msg}")]
    Field {
        /// The field, with its path (`sources[1].priority`).
        field: String,
        /// What is wrong.
        msg: String,
    },
}

/// Builds a field error.
pub fn field_error(field: impl Into<String>, msg: impl Into<String>) -> ConfigError {
    ConfigError::Field {
        field: field.into(),
        msg: msg.into(),
    }
}

/// Checks that `v` is finite and > 0.
pub fn positive(field: &str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(field_error(
            field,
            format!("must be finite and > 0, got {v}"),
        ))
    }
}

/// Checks each named field of a config struct with `check` ([`positive`], [`non_negative`]),
/// the error naming the field with its path: `check_fields!(positive, cfg.params, "params";
/// speed, comfort_m)` checks `params.speed` and `params.comfort_m`;
/// `check_fields!(positive, cfg; speed)` checks `speed`. An expression of type
/// `Result<(), ConfigError>`.
macro_rules! check_fields {
    ($check:path, $s:expr, $prefix:literal; $($f:ident),+ $(,)?) => {
        [$((concat!($prefix, ".", stringify!($f)), $s.$f)),+]
            .into_iter()
            .try_for_each(|(field, v)| $check(field, v).map(drop))
    };
    ($check:path, $s:expr; $($f:ident),+ $(,)?) => {
        [$((stringify!($f), $s.$f)),+]
            .into_iter()
            .try_for_each(|(field, v)| $check(field, v).map(drop))
    };
}
pub(crate) use check_fields;

/// Checks that `v` is finite and >= 0.
pub fn non_negative(field: &str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(field_error(
            field,
            format!("must be finite and >= 0, got {v}"),
        ))
    }
}

/// A duration from seconds, checked finite and > 0.
pub fn seconds(field: &str, v: f64) -> Result<Duration, ConfigError> {
    positive(field, v).map(Duration::from_secs_f64)
}

/// Which of several command sources is obeyed: the live source with the most important
/// priority; a source is live while its last command is younger than the freshness timeout
/// (like ROS `twist_mux`). Built on the runtime's [`CommandArbiter`], keyed by the source's
/// index in a configured list: a driver's static wiring, for systems without contracts (with
/// contracts the driver's own arbiter, `Context::command_verdict`, elects).
#[derive(Debug, Clone)]
pub struct CommandMux {
    arbiter: CommandArbiter,
    active: Option<ModuleId>,
}

/// What a driver does after a command arrived or time passed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MuxAction {
    /// Send this command.
    Send(Twist),
    /// Nothing to send.
    Nothing,
}

impl CommandMux {
    /// A mux over `sources`, in the order of their indices.
    pub fn new(sources: &[CommandSource], freshness: Duration) -> Result<CommandMux, ConfigError> {
        let mut arbiter = CommandArbiter::new(freshness);
        for (i, s) in sources.iter().enumerate() {
            let p: Priority = s
                .priority
                .parse()
                .map_err(|e| field_error(format!("sources[{i}].priority"), format!("{e}")))?;
            if s.channel.is_empty() {
                return Err(field_error(format!("sources[{i}].channel"), "is empty"));
            }
            arbiter.offer(ModuleId(i as u32), p, Duration::ZERO);
        }
        Ok(CommandMux {
            arbiter,
            active: None,
        })
    }

    /// A command from source `source` arrived at `now`: `Send` it if the source has control.
    /// Non-finite commands are refused (a stop is sent instead if the source had control).
    pub fn on_command(&mut self, source: u32, cmd: &Twist, now: Duration) -> MuxAction {
        let id = ModuleId(source);
        match self.arbiter.on_command(id, now) {
            Verdict::Accept => {
                self.active = Some(id);
                if cmd.linear_x.is_finite() && cmd.linear_y.is_finite() && cmd.angular_z.is_finite()
                {
                    MuxAction::Send(*cmd)
                } else {
                    MuxAction::Send(Twist::default())
                }
            }
            Verdict::Ignore(_) => MuxAction::Nothing,
        }
    }

    /// Time passed: if the source in control went silent and nobody took over, send one stop.
    pub fn on_tick(&mut self, now: Duration) -> MuxAction {
        let live = self.arbiter.active(now);
        if self.active.is_some() && live.is_none() {
            self.active = None;
            return MuxAction::Send(Twist::default());
        }
        MuxAction::Nothing
    }

    /// The source in control at `now`.
    pub fn active(&self, now: Duration) -> Option<u32> {
        self.arbiter.active(now).map(|m| m.0)
    }

    /// Commands ignored so far (preempted or from no contract holder).
    pub fn ignored(&self) -> u64 {
        self.arbiter.drops().total()
    }
}

pub use hng_runtime::msg::wrap_angle;

/// `a ⊕ b`: `b` (expressed in `a`'s frame) composed onto `a`.
pub fn compose(a: &Pose2D, b: &Pose2D) -> Pose2D {
    let (s, c) = a.theta.sin_cos();
    Pose2D::new(
        a.x + c * b.x - s * b.y,
        a.y + s * b.x + c * b.y,
        wrap_angle(a.theta + b.theta),
    )
}

/// `a⁻¹ ⊕ b`: `b` expressed in `a`'s frame.
pub fn relative(a: &Pose2D, b: &Pose2D) -> Pose2D {
    let (s, c) = a.theta.sin_cos();
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    Pose2D::new(
        c * dx + s * dy,
        -s * dx + c * dy,
        wrap_angle(b.theta - a.theta),
    )
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn t(v: f64) -> Twist {
        Twist {
            linear_x: v,
            ..Default::default()
        }
    }

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn mux_obeys_the_most_important_live_source_and_stops_when_it_goes_silent() {
        let sources = [
            CommandSource::new("security/cmd_vel", "1.1"),
            CommandSource::new("teleop/cmd_vel", "2.1"),
            CommandSource::new("servo/cmd_vel", "2.2.1.1"),
        ];
        let mut m = CommandMux::new(&sources, ms(300)).unwrap();
        assert_eq!(m.on_command(2, &t(0.5), ms(0)), MuxAction::Send(t(0.5)));
        assert_eq!(m.on_command(1, &t(0.2), ms(10)), MuxAction::Send(t(0.2)));
        assert_eq!(m.on_command(2, &t(0.5), ms(20)), MuxAction::Nothing);
        assert_eq!(m.on_command(0, &t(0.0), ms(30)), MuxAction::Send(t(0.0)));
        assert_eq!(m.active(ms(30)), Some(0));
        // Security silent: teleop (still live at 320? its last command was at 10) has gone
        // stale too; servo commanded at 20 and is stale at 400.
        assert_eq!(m.on_tick(ms(200)), MuxAction::Nothing);
        assert_eq!(m.on_tick(ms(400)), MuxAction::Send(Twist::default()));
        assert_eq!(m.on_tick(ms(500)), MuxAction::Nothing, "one stop only");
        assert_eq!(m.on_command(2, &t(0.4), ms(600)), MuxAction::Send(t(0.4)));
        assert!(m.ignored() >= 1);
    }

    #[test]
    fn mux_turns_non_finite_commands_into_a_stop_and_rejects_bad_priorities() {
        let mut m = CommandMux::new(&[CommandSource::new("a", "1")], ms(100)).unwrap();
        assert_eq!(
            m.on_command(0, &t(f64::NAN), ms(0)),
            MuxAction::Send(Twist::default())
        );
        let e = CommandMux::new(&[CommandSource::new("a", "1.x")], ms(100)).unwrap_err();
        assert!(e.to_string().contains("sources[0].priority"), "{e}");
    }

    #[test]
    fn poses_compose_and_invert() {
        let a = Pose2D::new(1.0, 2.0, 0.5);
        let b = Pose2D::new(-0.3, 0.7, -1.2);
        let r = relative(&a, &compose(&a, &b));
        assert!((r.x - b.x).abs() < 1e-12 && (r.y - b.y).abs() < 1e-12);
        assert!((r.theta - b.theta).abs() < 1e-12);
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
    }
}
