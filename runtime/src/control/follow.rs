//! Following whichever provider serves a need: the one way a module wires a contracted need to
//! its data. [`ProviderInput`] (fixed-size messages) and [`SliceProviderInput`] (maps, images)
//! read the provider's channel, with an optional fallback channel read until a provider is
//! known; [`ProviderOutput`] writes to it (commands to the contracted Robot). All three
//! implement [`FollowProvider`], and [`crate::follow_needs!`] writes
//! [`crate::Module::on_provider_changed`] from a list of `need => field`.
//!
//! Like dora-rs and copper-rs, a module names its inputs and the runtime tells it which one has
//! data ([`ProviderReceiver::is`]); unlike them, where an input comes from is decided while the
//! system runs, by the contract tree, so the input follows the provider named in each
//! `on_provider_changed`.

use std::time::Duration;

use super::ProviderInfo;
use crate::Context;
use crate::channel::{Fixed, InputId, Kind, Publisher, Receiver, Slice};
use crate::error::Error;
use crate::msg::Message;

/// How many channels a [`ProviderReceiver`] or a [`ProviderOutput`] keeps open after leaving
/// them, by default ([`ProviderReceiver::keep_left`]): coming back to one (a re-established
/// tree, localization switching back and forth between two providers) opens no channel.
/// Opening a port costs milliseconds (much more on a loaded machine) and would block the
/// module's contract protocol meanwhile.
pub const PROVIDER_INPUT_CACHE: usize = 4;

/// The ports (subscribers, publishers) a follower left, kept open for the way back: at most
/// `keep`, the oldest closed first.
#[derive(Debug)]
struct Left<P> {
    ports: Vec<P>,
    keep: usize,
}

impl<P> Left<P> {
    fn new() -> Self {
        Left {
            ports: Vec::new(),
            keep: PROVIDER_INPUT_CACHE,
        }
    }

    /// Keeps `port` (closes it when none are kept).
    fn put(&mut self, port: P) {
        if self.keep == 0 {
            return;
        }
        if self.ports.len() >= self.keep {
            self.ports.remove(0);
        }
        self.ports.push(port);
    }

    /// The kept port on `channel`, taken out.
    fn take(&mut self, channel: &str, channel_of: impl Fn(&P) -> &str) -> Option<P> {
        let pos = self.ports.iter().position(|p| channel_of(p) == channel)?;
        Some(self.ports.remove(pos))
    }
}

/// Whatever follows the data channel of a need's provider: an input that reads it
/// ([`ProviderInput`], [`SliceProviderInput`]) or an output that writes to it
/// ([`ProviderOutput`]). Call it from [`crate::Module::on_provider_changed`], or name the fields
/// in [`crate::follow_needs!`].
pub trait FollowProvider {
    /// Follows `provider` (or none, back to the fallback if there is one).
    ///
    /// # Errors
    /// The provider's channel cannot be opened (e.g. it carries another type:
    /// [`Error::TypeMismatch`]).
    fn follow(&mut self, ctx: &mut Context, provider: Option<&ProviderInfo>) -> Result<(), Error>;
}

/// Input of fixed-size messages `T` from a need's provider.
pub type ProviderInput<T> = ProviderReceiver<Fixed<T>>;

/// Input of variable-size payloads described by `H` (maps, images) from a need's provider.
pub type SliceProviderInput<H> = ProviderReceiver<Slice<H>>;

/// A consumer's input from whichever provider serves one of its needs (paper 5.6, "Consumer").
///
/// - [`FollowProvider::follow`] subscribes to the provider's data channel (the one it named in
///   its proposal); [`ProviderReceiver::receive`] then returns only the samples that provider
///   published (by `header.source`), so two publishers sharing a channel never mix. Samples of
///   others are skipped and counted ([`ProviderReceiver::foreign`]).
/// - With a fallback ([`ProviderReceiver::with_fallback`]), the configured channel is read,
///   from any publisher, while no provider is known (the module is not, or not yet, selected;
///   a contract was cut), and again when the provider is lost. A provider publishing on the
///   fallback channel is read through the same subscription, filtered.
/// - The last [`ProviderReceiver::keep_left`] channels left stay open, detached from the
///   executor (they never wake the module); following one of them again discards what it
///   buffered meanwhile (it belongs to a former contract) and reuses it.
pub struct ProviderReceiver<K: Kind> {
    sub: Option<Receiver<K>>,
    left: Left<Receiver<K>>,
    provider: Option<ProviderInfo>,
    fallback: Option<String>,
    deadline: Option<Duration>,
    foreign: u64,
    reused: u64,
}

impl<K: Kind> std::fmt::Debug for ProviderReceiver<K> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProviderReceiver")
            .field("channel", &self.channel())
            .field("provider", &self.provider)
            .field("fallback", &self.fallback)
            .field("kept", &self.left.ports.len())
            .field("foreign", &self.foreign)
            .finish_non_exhaustive()
    }
}

impl<K: Kind> Default for ProviderReceiver<K> {
    fn default() -> Self {
        Self::new()
    }
}

impl<K: Kind> ProviderReceiver<K> {
    /// An input following no provider yet, and reading nothing until one is known.
    pub fn new() -> Self {
        ProviderReceiver {
            sub: None,
            left: Left::new(),
            provider: None,
            fallback: None,
            deadline: None,
            foreign: 0,
            reused: 0,
        }
    }

    /// Watches whichever channel is read with a deadline
    /// ([`crate::Module::on_deadline_missed`]). Set it before [`ProviderReceiver::with_fallback`].
    #[must_use]
    pub fn with_deadline(mut self, deadline: Option<Duration>) -> Self {
        self.deadline = deadline;
        self
    }

    /// Keeps at most `n` channels open after leaving them (default [`PROVIDER_INPUT_CACHE`]).
    /// 0 closes a channel when it is left: a state channel whose latest sample matters on the
    /// way back (a new subscription receives it), or a channel whose publisher works only
    /// while it has readers (the Camera's images).
    #[must_use]
    pub fn keep_left(mut self, n: usize) -> Self {
        self.left.keep = n;
        self.left.ports.truncate(n);
        self
    }

    /// Reads `channel` (any publisher) until a provider is known, and whenever none is;
    /// subscribes to it now. An empty `channel` means no fallback.
    ///
    /// # Errors
    /// The channel cannot be opened.
    pub fn with_fallback(mut self, ctx: &mut Context, channel: &str) -> Result<Self, Error> {
        if !channel.is_empty() {
            self.fallback = Some(channel.to_string());
            self.read(ctx, channel)?;
        }
        Ok(self)
    }

    /// Makes `channel` the one read: kept when it is already, taken from the channels left,
    /// or opened; the channel read before is left (kept open or closed).
    fn read(&mut self, ctx: &mut Context, channel: &str) -> Result<(), Error> {
        if self.sub.as_ref().is_some_and(|s| s.channel() == channel) {
            return Ok(());
        }
        if let Some(old) = self.sub.take() {
            ctx.unsubscribe(old.id())?;
            self.left.put(old);
        }
        if channel.is_empty() {
            return Ok(());
        }
        if let Some(sub) = self.left.take(channel, Receiver::channel) {
            // What arrived while nobody listened belongs to a former contract.
            while sub.receive()?.is_some() {}
            ctx.resubscribe(&sub, self.deadline)?;
            self.reused += 1;
            self.sub = Some(sub);
        } else {
            self.sub = Some(ctx.subscribe_kind::<K>(channel, self.deadline)?);
        }
        Ok(())
    }

    /// How many times a kept subscription was reused instead of opening the channel.
    pub fn reused(&self) -> u64 {
        self.reused
    }

    /// The provider followed (`None`: the fallback channel, if any, is read).
    pub fn provider(&self) -> Option<&ProviderInfo> {
        self.provider.as_ref()
    }

    /// The channel read now (`None`: nothing is read).
    pub fn channel(&self) -> Option<&str> {
        self.sub.as_ref().map(Receiver::channel)
    }

    /// True when `input` is this input's subscription.
    pub fn is(&self, input: InputId) -> bool {
        self.sub.as_ref().is_some_and(|s| s.id() == input)
    }

    /// True when a sample published by module `source` is the provider's (any publisher's on
    /// the fallback channel while no provider is known).
    pub fn accepts(&self, source: u32) -> bool {
        self.provider.as_ref().is_none_or(|p| p.module.0 == source)
    }

    /// The next sample of the provider (of any publisher on the fallback channel while no
    /// provider is known); others are skipped and counted.
    ///
    /// # Errors
    /// The channel failed.
    pub fn receive(&mut self) -> Result<Option<K::Sample>, Error> {
        let Some(sub) = &self.sub else {
            return Ok(None);
        };
        while let Some(s) = sub.receive()? {
            if self.accepts(K::header(&s).source) {
                return Ok(Some(s));
            }
            self.foreign += 1;
        }
        Ok(None)
    }

    /// The next sample on the channel read, whoever published it: for a client that keeps
    /// every publisher's latest state (Planning keeps each Mapping provider's map, so that
    /// switching back never leaves it without one); [`ProviderReceiver::accepts`] tells which
    /// is the provider's.
    ///
    /// # Errors
    /// The channel failed.
    pub fn receive_any(&mut self) -> Result<Option<K::Sample>, Error> {
        match &self.sub {
            Some(sub) => sub.receive(),
            None => Ok(None),
        }
    }

    /// Samples skipped because a module other than the provider published them.
    pub fn foreign(&self) -> u64 {
        self.foreign
    }
}

impl<K: Kind> FollowProvider for ProviderReceiver<K> {
    fn follow(&mut self, ctx: &mut Context, provider: Option<&ProviderInfo>) -> Result<(), Error> {
        self.provider = provider.cloned();
        let channel = match provider {
            Some(p) => p.channel.clone(),
            None => self.fallback.clone().unwrap_or_default(),
        };
        self.read(ctx, &channel)
    }
}

/// An output to whichever provider serves a need: commands to the contracted Robot. It has a
/// publisher on the provider's channel while a provider is known, none otherwise (or on the
/// fallback channel, [`ProviderOutput::with_fallback`]); the last
/// [`PROVIDER_INPUT_CACHE`] publishers left are kept, so going back to a driver opens no
/// channel.
#[derive(Debug)]
pub struct ProviderOutput<T: Message> {
    out: Option<Publisher<T>>,
    left: Left<Publisher<T>>,
    fallback: Option<String>,
}

impl<T: Message> Default for ProviderOutput<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Message> ProviderOutput<T> {
    /// An output with no provider yet: nothing is sent.
    pub fn new() -> Self {
        ProviderOutput {
            out: None,
            left: Left::new(),
            fallback: None,
        }
    }

    /// Publishes on `channel` while no provider is known (a static wiring); opens it now. An
    /// empty `channel` means no fallback.
    ///
    /// # Errors
    /// The channel cannot be opened.
    pub fn with_fallback(mut self, ctx: &mut Context, channel: &str) -> Result<Self, Error> {
        if !channel.is_empty() {
            self.fallback = Some(channel.to_string());
            self.write_to(ctx, channel)?;
        }
        Ok(self)
    }

    fn write_to(&mut self, ctx: &mut Context, channel: &str) -> Result<(), Error> {
        if self.out.as_ref().is_some_and(|p| p.channel() == channel) {
            return Ok(());
        }
        if let Some(old) = self.out.take() {
            self.left.put(old);
        }
        if channel.is_empty() {
            return Ok(());
        }
        self.out = Some(match self.left.take(channel, Publisher::channel) {
            Some(p) => p,
            None => ctx.publisher(channel)?,
        });
        Ok(())
    }

    /// The publisher on the provider's channel (`None`: no provider, nothing to send to).
    pub fn publisher(&self) -> Option<&Publisher<T>> {
        self.out.as_ref()
    }

    /// Sends `msg` to the provider; `false` when there is none.
    ///
    /// # Errors
    /// Publishing failed.
    pub fn publish(&self, msg: T) -> Result<bool, Error> {
        match &self.out {
            Some(p) => p.publish(msg).map(|()| true),
            None => Ok(false),
        }
    }
}

impl<T: Message> FollowProvider for ProviderOutput<T> {
    fn follow(&mut self, ctx: &mut Context, provider: Option<&ProviderInfo>) -> Result<(), Error> {
        let channel = match provider.filter(|p| !p.channel.is_empty()) {
            Some(p) => p.channel.clone(),
            None => self.fallback.clone().unwrap_or_default(),
        };
        self.write_to(ctx, &channel)
    }
}

/// Writes [`crate::Module::on_provider_changed`] for a module whose needs are each followed by
/// one field ([`FollowProvider`]), inside `impl Module for ...`:
/// `hng_runtime::follow_needs!(ODOMETRY_NEED => odom, LIDAR_NEED => scan);`.
#[macro_export]
macro_rules! follow_needs {
    ($($need:expr => $field:ident),+ $(,)?) => {
        fn on_provider_changed(
            &mut self,
            ctx: &mut $crate::Context,
            need: u16,
            provider: ::std::option::Option<&$crate::control::ProviderInfo>,
        ) -> $crate::ModuleResult {
            $(
                if need == $need {
                    $crate::control::FollowProvider::follow(&mut self.$field, ctx, provider)?;
                }
            )+
            ::std::result::Result::Ok(())
        }
    };
}
