//! Helpers shared by the navigation modules: inputs that follow a contracted provider, command
//! sources arbitrated by priority (a driver's static wiring), poses, angles.

use std::time::Duration;

use hng_runtime::Context;
use hng_runtime::channel::{InputId, Sample};
use hng_runtime::contract::{CommandArbiter, ModuleId, Priority, Verdict};
use hng_runtime::control::ProviderInfo;
use hng_runtime::msg::{Message, Pose2D, Twist};
use hng_runtime::{Error, Publisher, Subscriber};
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

/// A data input that follows the provider of a need (paper 5.6, "Consumer"): its samples are
/// read from the channel the provider named in its proposal, and only those the provider
/// published (by `Header::source`), so a contract decides where the data comes from. Until a
/// provider is known (the module is not yet, or not, selected), the configured channel is the
/// fallback and any publisher on it is accepted. When the provider's channel is the configured
/// one, the one subscription serves both.
#[derive(Debug)]
pub struct ContractedInput<T: Message> {
    configured: Subscriber<T>,
    followed: Option<Subscriber<T>>,
    provider: Option<ProviderInfo>,
    deadline: Option<Duration>,
    foreign: u64,
}

impl<T: Message> ContractedInput<T> {
    /// Subscribes to the fallback `channel`; `deadline` watches whichever channel is read.
    ///
    /// # Errors
    /// The channel cannot be opened.
    pub fn new(
        ctx: &mut Context,
        channel: &str,
        deadline: Option<Duration>,
    ) -> Result<ContractedInput<T>, Error> {
        Ok(ContractedInput {
            configured: ctx.subscribe(channel, deadline)?,
            followed: None,
            provider: None,
            deadline,
            foreign: 0,
        })
    }

    /// Follows `provider` (or none, back to the fallback), from `on_provider_changed`.
    ///
    /// # Errors
    /// The provider's channel cannot be opened (e.g. it carries another type).
    pub fn follow(
        &mut self,
        ctx: &mut Context,
        provider: Option<&ProviderInfo>,
    ) -> Result<(), Error> {
        let want = provider
            .map(|p| p.channel.as_str())
            .filter(|c| !c.is_empty() && *c != self.configured.channel());
        let have = self.followed.as_ref().map(|s| s.channel().to_string());
        if want != have.as_deref() {
            if let Some(old) = self.followed.take() {
                ctx.unsubscribe(old.id())?;
            }
            if let Some(c) = want {
                self.followed = Some(ctx.subscribe(c, self.deadline)?);
            }
        }
        self.provider = provider.cloned();
        Ok(())
    }

    /// The provider followed (`None`: the fallback channel is read).
    pub fn provider(&self) -> Option<&ProviderInfo> {
        self.provider.as_ref()
    }

    /// True when `input` is one of this input's subscriptions.
    pub fn is(&self, input: InputId) -> bool {
        self.configured.id() == input || self.followed.as_ref().is_some_and(|s| s.id() == input)
    }

    /// The channel read now.
    pub fn channel(&self) -> &str {
        self.followed
            .as_ref()
            .map_or(self.configured.channel(), |s| s.channel())
    }

    /// The next sample of the provider (or of the fallback channel while none is known).
    ///
    /// # Errors
    /// The channel failed.
    pub fn receive(&mut self) -> Result<Option<Sample<T>>, Error> {
        let Some(p) = &self.provider else {
            return self.configured.receive();
        };
        let source = p.module.0;
        let sub = match &self.followed {
            Some(f) => {
                // Not read while another channel is followed: drain it.
                while self.configured.receive()?.is_some() {}
                f
            }
            None => &self.configured,
        };
        while let Some(s) = sub.receive()? {
            if s.header().source == source {
                return Ok(Some(s));
            }
            self.foreign += 1;
        }
        Ok(None)
    }

    /// Samples skipped because a module other than the provider published them.
    pub fn foreign(&self) -> u64 {
        self.foreign
    }
}

/// Wraps an angle to (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a % std::f64::consts::TAU;
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    } else if a <= -std::f64::consts::PI {
        a += std::f64::consts::TAU;
    }
    a
}

/// `a ⊕ b`: `b` (expressed in `a`'s frame) composed onto `a`.
pub fn compose(a: &Pose2D, b: &Pose2D) -> Pose2D {
    let (s, c) = a.theta.sin_cos();
    Pose2D {
        x: a.x + c * b.x - s * b.y,
        y: a.y + s * b.x + c * b.y,
        theta: wrap_angle(a.theta + b.theta),
    }
}

/// `a⁻¹ ⊕ b`: `b` expressed in `a`'s frame.
pub fn relative(a: &Pose2D, b: &Pose2D) -> Pose2D {
    let (s, c) = a.theta.sin_cos();
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    Pose2D {
        x: c * dx + s * dy,
        y: -s * dx + c * dy,
        theta: wrap_angle(b.theta - a.theta),
    }
}

/// Whatever follows the data channel of a need's provider: an input that reads it
/// ([`ContractedInput`], [`hng_runtime::control::ProviderInput`], [`crate::video::VideoInput`])
/// or a command output that writes to it (`Option<Publisher<T>>`, [`follow_output`]). With
/// [`crate::follow_needs!`] a module names, per need, the field that follows it.
pub trait FollowProvider {
    /// Follows `provider` (or none), from `on_provider_changed`.
    ///
    /// # Errors
    /// The provider's channel cannot be opened.
    fn follow_provider(
        &mut self,
        ctx: &mut Context,
        provider: Option<&ProviderInfo>,
    ) -> Result<(), Error>;
}

impl<T: Message> FollowProvider for ContractedInput<T> {
    fn follow_provider(
        &mut self,
        ctx: &mut Context,
        p: Option<&ProviderInfo>,
    ) -> Result<(), Error> {
        self.follow(ctx, p)
    }
}

impl<T: Message> FollowProvider for hng_runtime::control::ProviderInput<T> {
    fn follow_provider(
        &mut self,
        ctx: &mut Context,
        p: Option<&ProviderInfo>,
    ) -> Result<(), Error> {
        self.follow(ctx, p)
    }
}

impl<T: Message> FollowProvider for Option<Publisher<T>> {
    fn follow_provider(
        &mut self,
        ctx: &mut Context,
        p: Option<&ProviderInfo>,
    ) -> Result<(), Error> {
        follow_output(ctx, self, p)
    }
}

/// The provider alone, for a need whose data the module does not read itself (the
/// Interface's "Video": the operator page reads the images).
impl FollowProvider for Option<ProviderInfo> {
    fn follow_provider(
        &mut self,
        _ctx: &mut Context,
        p: Option<&ProviderInfo>,
    ) -> Result<(), Error> {
        *self = p.cloned();
        Ok(())
    }
}

/// Writes `Module::on_provider_changed` for a module whose needs are each followed by one
/// field ([`FollowProvider`]): `follow_needs!(ODOMETRY_NEED => odom, LIDAR_NEED => scan);`
/// inside `impl Module for ...`.
#[macro_export]
macro_rules! follow_needs {
    ($($need:path => $field:ident),+ $(,)?) => {
        fn on_provider_changed(
            &mut self,
            ctx: &mut ::hng_runtime::Context,
            need: u16,
            provider: ::std::option::Option<&::hng_runtime::control::ProviderInfo>,
        ) -> ::hng_runtime::ModuleResult {
            $(
                if need == $need {
                    $crate::common::FollowProvider::follow_provider(&mut self.$field, ctx, provider)?;
                }
            )+
            ::std::result::Result::Ok(())
        }
    };
}

/// Points `out` at the data channel of a need's new provider (a command publisher following
/// the contracted Robot, say): opens a publisher when the channel changes, none when the need
/// has no provider.
///
/// # Errors
/// Opening the publisher failed.
pub fn follow_output<T: Message>(
    ctx: &mut Context,
    out: &mut Option<Publisher<T>>,
    provider: Option<&ProviderInfo>,
) -> Result<(), Error> {
    let want = provider
        .map(|p| p.channel.as_str())
        .filter(|c| !c.is_empty());
    if want != out.as_ref().map(|p| p.channel()) {
        *out = match want {
            Some(c) => Some(ctx.publisher(c)?),
            None => None,
        };
    }
    Ok(())
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
        let a = Pose2D {
            x: 1.0,
            y: 2.0,
            theta: 0.5,
        };
        let b = Pose2D {
            x: -0.3,
            y: 0.7,
            theta: -1.2,
        };
        let r = relative(&a, &compose(&a, &b));
        assert!((r.x - b.x).abs() < 1e-12 && (r.y - b.y).abs() < 1e-12);
        assert!((r.theta - b.theta).abs() < 1e-12);
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
    }
}
