//! How a module process runs: [`RunOptions`], read from the environment the supervisor sets,
//! and [`RunError`], why a run ended with an error.

use std::path::PathBuf;
use std::time::Duration;

use crate::clock::ClockMode;
use crate::error::Error;
use crate::wait::WaitMode;

/// How a module process runs; [`RunOptions::from_env`] reads what the supervisor sets.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Module name (`HNG_MODULE_NAME`).
    pub name: String,
    /// Prefix of the system (`HNG_PREFIX`).
    pub prefix: String,
    /// The module's configuration as TOML (`HNG_MODULE_CONFIG`); empty means defaults.
    pub config_toml: String,
    /// Where checkpoints go (`HNG_CHECKPOINT_DIR`); `None` disables them.
    pub checkpoint_dir: Option<PathBuf>,
    /// Checkpoint period (`HNG_CHECKPOINT_PERIOD_MS`, default 1000).
    pub checkpoint_period: Duration,
    /// Report (heartbeat) period (`HNG_REPORT_PERIOD_MS` or `HNG_HEARTBEAT_PERIOD_MS`, default
    /// 100).
    pub report_period: Duration,
    /// Longest report period of a module with nothing to do (`HNG_IDLE_REPORT_PERIOD_MS`,
    /// default 1000; never shorter than `report_period`). A module whose loop woke only to
    /// report doubles its period up to this, says so in each report (`period_ns`, which the
    /// watchdog's hang deadline follows), and reports at once at the normal period when work
    /// comes: the heartbeat of a module blocked in its wait costs about one wake-up a second.
    pub idle_report_period: Duration,
    /// Clock (`HNG_CLOCK`: `wall` or `sim`).
    pub clock: ClockMode,
    /// Wait mode (`HNG_WAIT`: `blocking`, `blocking:<µs>` or `spin`).
    pub wait: WaitMode,
    /// Turn SIGINT/SIGTERM/SIGHUP into a clean stop.
    pub catch_signals: bool,
    /// Run by the in-process test harness ([`crate::harness`]): scripted providers instead of
    /// the contract plane, and its stop flag. `None` in a module process.
    pub harness: Option<crate::harness::Hooks>,
}

impl RunOptions {
    /// Defaults for a module called `name`.
    pub fn new(name: &str) -> RunOptions {
        RunOptions {
            name: name.to_string(),
            prefix: crate::channel::DEFAULT_PREFIX.to_string(),
            config_toml: String::new(),
            checkpoint_dir: None,
            checkpoint_period: Duration::from_secs(1),
            report_period: Duration::from_millis(100),
            idle_report_period: Duration::from_secs(1),
            clock: ClockMode::Wall,
            wait: WaitMode::default(),
            catch_signals: true,
            harness: None,
        }
    }

    /// Reads the `HNG_*` environment; `default_name` is used when `HNG_MODULE_NAME` is unset.
    pub fn from_env(default_name: &str) -> Result<RunOptions, Error> {
        let var = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
        let ms = |k: &str, default: u64| -> Result<Duration, Error> {
            match var(k) {
                None => Ok(Duration::from_millis(default)),
                Some(v) => v.parse::<u64>().map(Duration::from_millis).map_err(|_| {
                    Error::Config(format!("{k}={v:?} is not a number of milliseconds"))
                }),
            }
        };
        let mut o = RunOptions::new(&var("HNG_MODULE_NAME").unwrap_or_else(|| default_name.into()));
        if let Some(p) = var("HNG_PREFIX") {
            o.prefix = p;
        }
        o.config_toml = var("HNG_MODULE_CONFIG").unwrap_or_default();
        o.checkpoint_dir = var("HNG_CHECKPOINT_DIR").map(PathBuf::from);
        o.checkpoint_period = ms("HNG_CHECKPOINT_PERIOD_MS", 1000)?;
        // The supervisor names it the heartbeat period; both spellings are accepted.
        o.report_period = match var("HNG_REPORT_PERIOD_MS") {
            Some(_) => ms("HNG_REPORT_PERIOD_MS", 100)?,
            None => ms("HNG_HEARTBEAT_PERIOD_MS", 100)?,
        };
        o.idle_report_period = ms("HNG_IDLE_REPORT_PERIOD_MS", 1000)?;
        o.clock = match var("HNG_CLOCK").as_deref() {
            None | Some("wall") => ClockMode::Wall,
            Some("sim") => ClockMode::Sim,
            Some(v) => {
                return Err(Error::Config(format!(
                    "HNG_CLOCK={v:?}: expected `wall` or `sim`"
                )));
            }
        };
        if let Some(w) = var("HNG_WAIT") {
            o.wait = WaitMode::parse(&w)?;
        }
        Ok(o)
    }
}

/// Why a module run ended with an error.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The runtime failed.
    #[error(transparent)]
    Runtime(#[from] Error),
    /// The module's configuration did not parse.
    #[error("module {module:?}: invalid configuration: {detail}")]
    Config {
        /// The module.
        module: String,
        /// The parser's message (names the field and line).
        detail: String,
    },
    /// A module callback failed in a way the module cannot run on.
    #[error("module {module:?}: {stage} failed: {source}")]
    Module {
        /// The module.
        module: String,
        /// Which callback.
        stage: &'static str,
        /// Its error.
        source: super::ModuleError,
    },
}
