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

/// The settings allowed in `[defaults]` and in each module, listed once: [`RawSettings`] has
/// them alone, [`RawModule`] after the module's own keys, and `take_settings` moves them from
/// one to the other. (Not `#[serde(flatten)]`: that would lose the spans and
/// `deny_unknown_fields`.) Durations are seconds (`*_s`).
macro_rules! settings {
    ($($field:ident: $ty:ty,)+) => {
        /// Settings allowed in `[defaults]` and in each module.
        #[derive(Debug, Default, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub(crate) struct RawSettings {
            $(pub(crate) $field: Option<$ty>,)+
        }

        /// A `[[module]]` table: its own keys plus every `[defaults]` key.
        #[derive(Debug, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub(crate) struct RawModule {
            pub(crate) name: S<String>,
            pub(crate) command: S<Vec<S<String>>>,
            pub(crate) manager: Option<S<bool>>,
            pub(crate) needs: Option<Vec<S<String>>>,
            pub(crate) provides: Option<Vec<S<String>>>,
            pub(crate) config: Option<S<toml::Table>>,
            $(pub(crate) $field: Option<$ty>,)+
        }

        impl RawModule {
            /// Move the per-module settings out.
            pub(crate) fn take_settings(&mut self) -> RawSettings {
                RawSettings {
                    $($field: self.$field.take(),)+
                }
            }
        }
    };
}

settings! {
    restart: S<RestartPolicy>,
    backoff_initial_s: S<Scalar>,
    backoff_max_s: S<Scalar>,
    backoff_reset_after_s: S<Scalar>,
    give_up_failures: S<i64>,
    give_up_window_s: S<Scalar>,
    heartbeat_period_s: S<Scalar>,
    heartbeat_timeout_s: S<Scalar>,
    start_timeout_s: S<Scalar>,
    checkpoint_period_s: S<Scalar>,
    stop_timeout_s: S<Scalar>,
    cpu_quota: S<Scalar>,
    memory_max: S<Scalar>,
    pids_max: S<Scalar>,
    env: BTreeMap<S<String>, S<String>>,
}
