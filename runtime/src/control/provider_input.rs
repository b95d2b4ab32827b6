//! Following whichever provider serves a need: [`ProviderInput`].

use std::time::Duration;

use super::ProviderInfo;
use crate::channel::{InputId, Sample, Subscriber};
use crate::error::Error;
use crate::msg::Message;

/// Subscriptions a [`ProviderInput`] keeps after leaving a provider, so that coming back to it
/// (a re-established tree, localization switching back and forth between two providers) opens
/// no channel: opening a subscriber costs milliseconds (much more on a loaded machine) and
/// would block the module's contract protocol meanwhile.
pub const PROVIDER_INPUT_CACHE: usize = 4;

/// A consumer's input from whichever provider currently serves one of its needs.
///
/// Call [`ProviderInput::follow`] from [`crate::Module::on_provider_changed`]: it stops
/// listening to the old provider's channel and subscribes to the new one's. [`ProviderInput::receive`]
/// returns only samples published by the selected provider (by `header.source`), so two
/// providers sharing a channel never mix. The last [`PROVIDER_INPUT_CACHE`] channels left are
/// kept open (detached from the executor, so they never wake the module); following one of
/// them again discards what it buffered meanwhile and reuses it.
#[derive(Debug)]
pub struct ProviderInput<T: Message> {
    sub: Option<(String, Subscriber<T>)>,
    cache: Vec<(String, Subscriber<T>)>,
    provider: Option<ProviderInfo>,
    deadline: Option<Duration>,
    foreign: u64,
    reused: u64,
}

impl<T: Message> Default for ProviderInput<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Message> ProviderInput<T> {
    /// An input following no provider yet.
    pub fn new() -> Self {
        ProviderInput {
            sub: None,
            cache: Vec::new(),
            provider: None,
            deadline: None,
            foreign: 0,
            reused: 0,
        }
    }

    /// Watches the input with a deadline ([`crate::Module::on_deadline_missed`]).
    #[must_use]
    pub fn with_deadline(mut self, deadline: Duration) -> Self {
        self.deadline = Some(deadline);
        self
    }

    /// Follows `provider` (or none): (re)subscribes to its data channel when it changed.
    ///
    /// # Errors
    /// The channel cannot be opened (e.g. its type is not `T`: [`Error::TypeMismatch`]).
    pub fn follow(
        &mut self,
        ctx: &mut crate::Context,
        provider: Option<&ProviderInfo>,
    ) -> Result<(), Error> {
        let same_channel = match (&self.sub, provider) {
            (Some((c, _)), Some(p)) => *c == p.channel,
            _ => false,
        };
        self.provider = provider.cloned();
        if same_channel {
            return Ok(());
        }
        if let Some((channel, old)) = self.sub.take() {
            ctx.unsubscribe(old.id())?;
            if self.cache.len() >= PROVIDER_INPUT_CACHE {
                self.cache.remove(0);
            }
            self.cache.push((channel, old));
        }
        let Some(p) = provider.filter(|p| !p.channel.is_empty()) else {
            return Ok(());
        };
        if let Some(pos) = self.cache.iter().position(|(c, _)| *c == p.channel) {
            let (channel, sub) = self.cache.remove(pos);
            // What arrived while nobody listened belongs to a former contract.
            while sub.receive()?.is_some() {}
            ctx.resubscribe(&sub, self.deadline)?;
            self.reused += 1;
            self.sub = Some((channel, sub));
        } else {
            let sub = ctx.subscribe::<T>(&p.channel, self.deadline)?;
            self.sub = Some((p.channel.clone(), sub));
        }
        Ok(())
    }

    /// How many times [`ProviderInput::follow`] reused a kept subscription instead of opening
    /// the channel.
    pub fn reused(&self) -> u64 {
        self.reused
    }

    /// The provider followed.
    pub fn provider(&self) -> Option<&ProviderInfo> {
        self.provider.as_ref()
    }

    /// True when `input` is this input's subscriber.
    pub fn is(&self, input: InputId) -> bool {
        self.sub.as_ref().is_some_and(|(_, s)| s.id() == input)
    }

    /// The next sample from the selected provider; samples of other publishers on the same
    /// channel are skipped (and counted, [`ProviderInput::foreign`]).
    ///
    /// # Errors
    /// The channel failed.
    pub fn receive(&mut self) -> Result<Option<Sample<T>>, Error> {
        let (Some((_, sub)), Some(p)) = (&self.sub, &self.provider) else {
            return Ok(None);
        };
        while let Some(s) = sub.receive()? {
            if s.header().source == p.module.0 {
                return Ok(Some(s));
            }
            self.foreign += 1;
        }
        Ok(None)
    }

    /// Samples skipped because another module published them.
    pub fn foreign(&self) -> u64 {
        self.foreign
    }
}
