//! Supervision settings of a module: its own over `[defaults]` over the built-in defaults.

use std::collections::BTreeMap;
use std::time::Duration;

use super::raw::{RawSettings, S, Scalar};
use super::*;
use crate::units::{parse_duration, parse_size};

/// Settings after merging module over defaults, still spanned.
pub(crate) struct Merged<'r> {
    pub(crate) d: &'r RawSettings,
    pub(crate) m: &'r RawSettings,
    pub(crate) d_prefix: &'r str,
    pub(crate) m_prefix: String,
}

macro_rules! pick {
    ($self:ident, $field:ident) => {
        match (&$self.m.$field, &$self.d.$field) {
            (Some(v), _) => Some((v, format!("{}.{}", $self.m_prefix, stringify!($field)))),
            (None, Some(v)) => Some((v, format!("{}.{}", $self.d_prefix, stringify!($field)))),
            (None, None) => None,
        }
    };
}

impl Cx<'_> {
    /// Fill `spec` from module settings over defaults over built-in defaults.
    /// Values coming from `[defaults]` are checked once by
    /// `validate_settings_alone`, so errors are only reported here for values
    /// the module sets itself.
    pub(crate) fn apply_settings(&mut self, s: &Merged<'_>, spec: &mut ModuleSpec) {
        let report = |field: &str| field.starts_with(&s.m_prefix);
        let mut errs: Vec<(std::ops::Range<usize>, String, LaunchErrorKind)> = Vec::new();
        type Errs = Vec<(std::ops::Range<usize>, String, LaunchErrorKind)>;
        let dur = |v: Option<(&S<Scalar>, String)>,
                   allow_off: bool,
                   errs: &mut Errs|
         -> Option<Option<Duration>> {
            let (v, field) = v?;
            let r = match v.get_ref() {
                Scalar::Str(t) if allow_off && t.trim() == "off" => Ok(None),
                Scalar::Str(t) => Err(not_seconds(t, allow_off)),
                Scalar::Int(x) => seconds(*x as f64).map(Some),
                Scalar::Float(x) => seconds(*x).map(Some),
            };
            match r {
                Ok(d) => Some(d),
                Err(m) => {
                    if report(&field) {
                        errs.push((v.span(), field, LaunchErrorKind::InvalidValue(m)));
                    }
                    None
                }
            }
        };
        if let Some((v, _)) = pick!(s, restart) {
            spec.restart = *v.get_ref();
        }
        if let Some(Some(d)) = dur(pick!(s, backoff_initial_s), false, &mut errs) {
            spec.backoff_initial = d;
        }
        let backoff_max_field = pick!(s, backoff_max_s);
        if let Some(Some(d)) = dur(backoff_max_field.clone(), false, &mut errs) {
            spec.backoff_max = d;
        }
        if let Some(Some(d)) = dur(pick!(s, backoff_reset_after_s), false, &mut errs) {
            spec.backoff_reset_after = d;
        }
        // An error for the value of `f` (when set and reported here).
        let invalid = |f: &Option<(&S<Scalar>, String)>, why: &str, errs: &mut Errs| {
            if let Some((v, field)) = f
                && report(field)
            {
                errs.push((
                    v.span(),
                    field.clone(),
                    LaunchErrorKind::InvalidValue(why.to_owned()),
                ));
            }
        };
        // A duration that must not be zero (a zero would switch a safety mechanism off
        // without saying so): `None`, and an error, for a zero.
        let nonzero = |f: Option<(&S<Scalar>, String)>, why: &str, errs: &mut Errs| {
            let d = dur(f.clone(), false, errs)??;
            if d.is_zero() {
                invalid(&f, why, errs);
                None
            } else {
                Some(d)
            }
        };
        if let Some(d) = nonzero(
            pick!(s, give_up_window_s),
            "give_up_window_s = 0 would never count a restart, so a crash loop would never be stopped: give a window such as 60",
            &mut errs,
        ) {
            spec.give_up_window = d;
        }
        if let Some(d) = nonzero(
            pick!(s, start_timeout_s),
            "start_timeout_s = 0 would count every start as a hang: give the time a module may take to its first heartbeat, such as 5",
            &mut errs,
        ) {
            spec.start_timeout = d;
        }
        if let Some(d) = nonzero(
            pick!(s, stop_timeout_s),
            "stop_timeout_s = 0 would SIGKILL every module without letting it stop (no final checkpoint): give a time such as 5",
            &mut errs,
        ) {
            spec.stop_timeout = d;
        }
        if let Some(d) = dur(pick!(s, checkpoint_period_s), true, &mut errs) {
            spec.checkpoint_period = d.filter(|d| !d.is_zero());
        }
        let period_field = pick!(s, heartbeat_period_s);
        let period = dur(period_field.clone(), true, &mut errs).flatten();
        if period.is_some_and(|p| p.is_zero()) {
            invalid(
                &period_field,
                "heartbeat_period_s = 0 would switch hang detection off without saying so: give a period such as 0.1, or write \"off\"",
                &mut errs,
            );
        }
        let timeout_field = pick!(s, heartbeat_timeout_s);
        let timeout = dur(timeout_field.clone(), false, &mut errs).flatten();
        match (period, timeout, timeout_field) {
            (Some(p), t, tf) if !p.is_zero() => {
                let t = t.unwrap_or(p * DEFAULT_HEARTBEAT_TIMEOUT_PERIODS);
                if t <= p {
                    invalid(
                        &tf,
                        &format!(
                            "heartbeat_timeout_s ({}) must be longer than heartbeat_period_s ({}); 3 periods is usual",
                            t.as_secs_f64(),
                            p.as_secs_f64()
                        ),
                        &mut errs,
                    );
                }
                spec.heartbeat = Some(HeartbeatSpec {
                    period: p,
                    timeout: t,
                });
                if pick!(s, start_timeout_s).is_none() {
                    spec.start_timeout = spec.start_timeout.max(t);
                }
            }
            (_, Some(_), Some((v, f))) if report(&f) => errs.push((
                v.span(),
                f,
                LaunchErrorKind::InvalidValue(
                    "heartbeat_timeout_s is set but heartbeat_period_s is not: set heartbeat_period_s too"
                        .to_owned(),
                ),
            )),
            _ => spec.heartbeat = None,
        }
        if spec.backoff_initial > spec.backoff_max {
            invalid(
                &backoff_max_field,
                &format!(
                    "backoff_max_s ({}) is smaller than backoff_initial_s ({})",
                    spec.backoff_max.as_secs_f64(),
                    spec.backoff_initial.as_secs_f64()
                ),
                &mut errs,
            );
        }
        if let Some((v, f)) = pick!(s, give_up_failures) {
            match u32::try_from(*v.get_ref()) {
                Ok(n) => spec.give_up_failures = n,
                Err(_) if report(&f) => errs.push((
                    v.span(),
                    f,
                    LaunchErrorKind::InvalidValue(
                        "give_up_failures must be a non-negative integer".to_owned(),
                    ),
                )),
                Err(_) => {}
            }
        }
        if let Some((v, f)) = pick!(s, cpu_quota) {
            let r = match v.get_ref() {
                Scalar::Float(x) => Ok(*x),
                Scalar::Int(x) => Ok(*x as f64),
                Scalar::Str(t) => t
                    .trim()
                    .strip_suffix('%')
                    .and_then(|p| p.trim().parse::<f64>().ok())
                    .map(|p| p / 100.0)
                    .ok_or_else(|| format!("{t:?} is not a CPU quota: write 0.5 or \"50%\"")),
            }
            .and_then(|x| {
                if x.is_finite() && x > 0.0 && x <= 4096.0 {
                    Ok(x)
                } else {
                    Err(format!(
                        "cpu_quota {x} must be > 0 (fraction of one CPU, e.g. 0.5)"
                    ))
                }
            });
            match r {
                Ok(x) => spec.resources.cpu_quota = Some(x),
                Err(m) if report(&f) => errs.push((v.span(), f, LaunchErrorKind::InvalidValue(m))),
                Err(_) => {}
            }
        }
        if let Some((v, f)) = pick!(s, memory_max) {
            let r = match v.get_ref() {
                Scalar::Str(t) if t.trim() == "max" => Ok(None),
                Scalar::Str(t) => parse_size(t).map(Some),
                Scalar::Int(x) => u64::try_from(*x)
                    .map(Some)
                    .map_err(|_| "memory_max must not be negative".to_owned()),
                Scalar::Float(_) => {
                    Err("memory_max: write bytes or a string such as \"512MiB\"".to_owned())
                }
            };
            match r {
                Ok(Some(0)) if report(&f) => errs.push((
                    v.span(),
                    f,
                    LaunchErrorKind::InvalidValue(
                        "memory_max of 0 bytes leaves no room to run".to_owned(),
                    ),
                )),
                Ok(x) => spec.resources.memory_max = x,
                Err(m) if report(&f) => errs.push((v.span(), f, LaunchErrorKind::InvalidValue(m))),
                Err(_) => {}
            }
        }
        if let Some((v, f)) = pick!(s, pids_max) {
            let r = match v.get_ref() {
                Scalar::Str(t) if t.trim() == "max" => Ok(None),
                Scalar::Int(x) if *x >= 1 => Ok(u64::try_from(*x).ok()),
                _ => Err("pids_max must be an integer >= 1 or \"max\"".to_owned()),
            };
            match r {
                Ok(x) => spec.resources.pids_max = x,
                Err(m) if report(&f) => errs.push((v.span(), f, LaunchErrorKind::InvalidValue(m))),
                Err(_) => {}
            }
        }
        let mut env = BTreeMap::new();
        for (table, prefix) in [
            (&s.d.env, s.d_prefix.to_owned()),
            (&s.m.env, s.m_prefix.clone()),
        ] {
            for (k, v) in table.iter().flatten() {
                let key = k.get_ref();
                let field = format!("{prefix}.env.{key}");
                if key.is_empty() || key.contains(['=', '\0']) || v.get_ref().contains('\0') {
                    if report(&field) {
                        errs.push((
                            k.span(),
                            field,
                            LaunchErrorKind::InvalidValue(
                                "environment names must be non-empty without '=' or NUL".to_owned(),
                            ),
                        ));
                    }
                    continue;
                }
                env.insert(key.clone(), v.get_ref().clone());
            }
        }
        spec.env = env;
        for (span, field, kind) in errs {
            self.err(span, Some(field), kind);
        }
    }
}

/// A duration in seconds: finite and not negative.
fn seconds(x: f64) -> Result<Duration, String> {
    if !x.is_finite() {
        return Err(format!(
            "{x} is not a duration: give a finite number of seconds"
        ));
    }
    if x < 0.0 {
        return Err(format!(
            "{x} s is negative: a duration is 0 or more seconds"
        ));
    }
    Duration::try_from_secs_f64(x).map_err(|_| format!("{x} s is out of range"))
}

/// Why a string is not a duration here, with the number to write when it reads as one
/// (`"250ms"`: write 0.25).
fn not_seconds(text: &str, allow_off: bool) -> String {
    let or_off = if allow_off { " or \"off\"" } else { "" };
    match parse_duration(text) {
        Ok(d) => format!(
            "durations are seconds as a number{or_off}: write {} instead of {text:?}",
            d.as_secs_f64()
        ),
        Err(_) => {
            format!("{text:?} is not a duration: give seconds as a number{or_off}, e.g. 0.25")
        }
    }
}
