//! The serde mirror of a launch file: what the user wrote, every value spanned.

use std::collections::BTreeMap;

use serde::Deserialize;
use toml::Spanned;

use super::RestartPolicy;

/// A scalar whose type is checked by the validator (better messages than serde's).
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub(crate) enum Scalar {
    Int(i64),
    Float(f64),
    Str(String),
}

pub(crate) type S<T> = Spanned<T>;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTop {
    pub(crate) system: S<String>,
    pub(crate) clock: Option<S<String>>,
    pub(crate) checkpoint_dir: Option<S<String>>,
    pub(crate) defaults: Option<S<RawSettings>>,
}

/// Settings allowed in `[defaults]` and in each module.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSettings {
    pub(crate) restart: Option<S<RestartPolicy>>,
    pub(crate) backoff_initial: Option<S<Scalar>>,
    pub(crate) backoff_max: Option<S<Scalar>>,
    pub(crate) backoff_reset_after: Option<S<Scalar>>,
    pub(crate) give_up_failures: Option<S<i64>>,
    pub(crate) give_up_window: Option<S<Scalar>>,
    pub(crate) heartbeat_period: Option<S<Scalar>>,
    pub(crate) heartbeat_timeout: Option<S<Scalar>>,
    pub(crate) start_timeout: Option<S<Scalar>>,
    pub(crate) checkpoint_period: Option<S<Scalar>>,
    pub(crate) stop_timeout: Option<S<Scalar>>,
    pub(crate) cpu_quota: Option<S<Scalar>>,
    pub(crate) memory_max: Option<S<Scalar>>,
    pub(crate) pids_max: Option<S<Scalar>>,
    pub(crate) env: Option<BTreeMap<S<String>, S<String>>>,
}

/// A `[[module]]` table: its own keys plus every `[defaults]` key. (Not
/// `#[serde(flatten)]`: that would lose the spans and `deny_unknown_fields`.)
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawModule {
    pub(crate) name: S<String>,
    pub(crate) command: S<Vec<S<String>>>,
    pub(crate) manager: Option<S<bool>>,
    pub(crate) needs: Option<Vec<S<String>>>,
    pub(crate) provides: Option<Vec<S<String>>>,
    pub(crate) config: Option<S<toml::Table>>,
    pub(crate) restart: Option<S<RestartPolicy>>,
    pub(crate) backoff_initial: Option<S<Scalar>>,
    pub(crate) backoff_max: Option<S<Scalar>>,
    pub(crate) backoff_reset_after: Option<S<Scalar>>,
    pub(crate) give_up_failures: Option<S<i64>>,
    pub(crate) give_up_window: Option<S<Scalar>>,
    pub(crate) heartbeat_period: Option<S<Scalar>>,
    pub(crate) heartbeat_timeout: Option<S<Scalar>>,
    pub(crate) start_timeout: Option<S<Scalar>>,
    pub(crate) checkpoint_period: Option<S<Scalar>>,
    pub(crate) stop_timeout: Option<S<Scalar>>,
    pub(crate) cpu_quota: Option<S<Scalar>>,
    pub(crate) memory_max: Option<S<Scalar>>,
    pub(crate) pids_max: Option<S<Scalar>>,
    pub(crate) env: Option<BTreeMap<S<String>, S<String>>>,
}

impl RawModule {
    /// Move the per-module settings out.
    pub(crate) fn take_settings(&mut self) -> RawSettings {
        RawSettings {
            restart: self.restart.take(),
            backoff_initial: self.backoff_initial.take(),
            backoff_max: self.backoff_max.take(),
            backoff_reset_after: self.backoff_reset_after.take(),
            give_up_failures: self.give_up_failures.take(),
            give_up_window: self.give_up_window.take(),
            heartbeat_period: self.heartbeat_period.take(),
            heartbeat_timeout: self.heartbeat_timeout.take(),
            start_timeout: self.start_timeout.take(),
            checkpoint_period: self.checkpoint_period.take(),
            stop_timeout: self.stop_timeout.take(),
            cpu_quota: self.cpu_quota.take(),
            memory_max: self.memory_max.take(),
            pids_max: self.pids_max.take(),
            env: self.env.take(),
        }
    }
}
