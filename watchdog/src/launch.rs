//! Launch files: which modules a system runs and how they are supervised.
//!
//! Two stages, as in ripgrep's CLI: a serde mirror of what the user wrote
//! (`deny_unknown_fields`, every value [`Spanned`] so it keeps its position),
//! then a validated [`LaunchPlan`] the [`Supervisor`](crate::Supervisor)
//! consumes. Every problem found is reported with file, line, column and
//! field, all at once, before anything starts.
//!
//! # Format
//!
//! ```toml
//! system = "explorer"                 # required: name of the system
//! clock = "wall"                      # optional: "wall" (default) or "sim" (modules follow hng/clock)
//! checkpoint_dir = "/var/lib/hng/explorer" # optional: where modules keep checkpoints
//!                                     # (relative to this file; default: the run directory)
//!
//! [defaults]                          # optional: applies to every module
//! restart = "on-failure"              # always | on-failure | never
//! backoff_initial = "100ms"           # 2nd consecutive restart waits this (1st is immediate)
//! backoff_max = "10s"                 # doubling stops here
//! backoff_reset_after = "30s"         # a run this long resets the backoff
//! give_up_failures = 5                # more than 5 restarts ...
//! give_up_window = "60s"              # ... within 60 s => module Deactivated
//! heartbeat_period = "100ms"          # or "off" (default): no hang detection
//! heartbeat_timeout = "300ms"         # default: 3 heartbeat periods
//! start_timeout = "5s"                # spawn -> first heartbeat
//! checkpoint_period = "1s"            # or "off" (default)
//! stop_timeout = "5s"                 # SIGTERM -> SIGKILL
//! cpu_quota = 0.5                     # fraction of one CPU (or "50%")
//! memory_max = "512MiB"               # bytes, K/M/G/T (1024) or kB/MB/GB (1000); "max" = none
//! pids_max = 64
//! env = { RUST_LOG = "info" }
//!
//! [[module]]
//! name = "slam"                       # required: [A-Za-z0-9_-], unique
//! command = ["hng", "module", "slam"] # required: program + args
//! manager = false                     # at most one module has manager = true
//! needs = ["scan", "odom"]            # optional: start after the providers of these
//! provides = ["map", "pose"]
//! restart = "always"                  # any [defaults] key can be overridden here
//! memory_max = "1GiB"
//! env = { SLAM_THREADS = "2" }        # merged over [defaults].env
//!
//! [module.config]                     # optional: the module's own typed configuration,
//! resolution_m = 0.05                 # passed to it as TOML in HNG_MODULE_CONFIG
//! ```
//!
//! # Programs
//!
//! `command[0]` is resolved when the file is loaded:
//! - `"hng"` or `"@hng"` is the running `hng` executable
//!   ([`LoadOptions::self_exe`], by default [`std::env::current_exe`]), so
//!   `["hng", "module", "slam"]` runs the built-in module with the same binary
//!   as the supervisor. To run some other `hng` from `PATH`, give its path.
//! - A name containing `/` is a path; relative paths are relative to the
//!   launch file's directory.
//! - Any other name is looked up in `PATH` ([`LoadOptions::path`]).
//!
//! The resolved file must exist and be executable.
//!
//! # Start order
//!
//! Modules start in file order, except that a module that `needs` something
//! starts after every module that `provides` it. A cycle is an error. Stop
//! order is the reverse of start order.

use std::collections::{BTreeMap, HashMap};
use std::ffi::OsString;
use std::fmt;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use toml::Spanned;
use toml::de::{DeTable, DeValue, ValueDeserializer};

use crate::units::{parse_duration, parse_size};

pub use self::check::{ModuleCheck, ModuleProblem};

// ---------------------------------------------------------------------------
// Validated plan
// ---------------------------------------------------------------------------

/// What to do when a module's process ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// Restart after every exit, even `exit(0)`.
    Always,
    /// Restart unless the process exited with status 0.
    OnFailure,
    /// Never restart.
    Never,
}

/// Resource caps for the resource manager to apply (cgroups). The supervisor
/// itself does not enforce them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ResourceCaps {
    /// Fraction of one CPU (`0.5` = half a core, `2.0` = two cores).
    pub cpu_quota: Option<f64>,
    /// Hard memory limit in bytes.
    pub memory_max: Option<u64>,
    /// Maximum number of tasks (processes and threads).
    pub pids_max: Option<u64>,
}

/// Hang detection parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct HeartbeatSpec {
    /// How often the module sends a heartbeat.
    pub period: Duration,
    /// A module silent for longer than this is killed (cause `Hang`).
    pub timeout: Duration,
}

/// One module, validated and ready for the supervisor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModuleSpec {
    /// Unique name, `[A-Za-z0-9_-]+`.
    pub name: String,
    /// Resolved absolute path of the executable.
    pub program: PathBuf,
    /// Arguments after the program.
    pub args: Vec<String>,
    /// Extra environment (defaults merged with the module's own).
    pub env: BTreeMap<String, String>,
    /// Is this the system's Manager module?
    pub manager: bool,
    /// Restart policy.
    pub restart: RestartPolicy,
    /// Delay before the second consecutive restart; doubles each time after.
    pub backoff_initial: Duration,
    /// Cap of the restart delay.
    pub backoff_max: Duration,
    /// A process that ran at least this long resets the backoff.
    pub backoff_reset_after: Duration,
    /// More than this many automatic restarts within `give_up_window` deactivates the module.
    pub give_up_failures: u32,
    /// Window of the give-up rule.
    pub give_up_window: Duration,
    /// `None`: no hang detection.
    pub heartbeat: Option<HeartbeatSpec>,
    /// Spawn to first heartbeat, when heartbeats are on.
    pub start_timeout: Duration,
    /// How often the module should checkpoint (passed to it in `HNG_CHECKPOINT_PERIOD_MS`).
    pub checkpoint_period: Option<Duration>,
    /// SIGTERM to SIGKILL.
    pub stop_timeout: Duration,
    /// Caps for the resource manager.
    pub resources: ResourceCaps,
    /// Names this module needs (start ordering).
    pub needs: Vec<String>,
    /// Names this module provides.
    pub provides: Vec<String>,
    /// The module's `config` table as TOML text (empty: none); passed in `HNG_MODULE_CONFIG`.
    pub config: String,
}

impl ModuleSpec {
    /// A spec with the documented defaults, for programmatic use and tests.
    pub fn new(name: impl Into<String>, program: impl Into<PathBuf>, args: &[&str]) -> Self {
        Self {
            name: name.into(),
            program: program.into(),
            args: args.iter().map(|s| (*s).to_owned()).collect(),
            env: BTreeMap::new(),
            manager: false,
            restart: RestartPolicy::OnFailure,
            backoff_initial: DEFAULT_BACKOFF_INITIAL,
            backoff_max: DEFAULT_BACKOFF_MAX,
            backoff_reset_after: DEFAULT_BACKOFF_RESET_AFTER,
            give_up_failures: DEFAULT_GIVE_UP_FAILURES,
            give_up_window: DEFAULT_GIVE_UP_WINDOW,
            heartbeat: None,
            start_timeout: DEFAULT_START_TIMEOUT,
            checkpoint_period: None,
            stop_timeout: DEFAULT_STOP_TIMEOUT,
            resources: ResourceCaps::default(),
            needs: Vec::new(),
            provides: Vec::new(),
            config: String::new(),
        }
    }
}

/// Default of `backoff_initial`.
pub const DEFAULT_BACKOFF_INITIAL: Duration = Duration::from_millis(100);
/// Default of `backoff_max`.
pub const DEFAULT_BACKOFF_MAX: Duration = Duration::from_secs(10);
/// Default of `backoff_reset_after`.
pub const DEFAULT_BACKOFF_RESET_AFTER: Duration = Duration::from_secs(30);
/// Default of `give_up_failures` (systemd's StartLimitBurst).
pub const DEFAULT_GIVE_UP_FAILURES: u32 = 5;
/// Default of `give_up_window`.
pub const DEFAULT_GIVE_UP_WINDOW: Duration = Duration::from_secs(60);
/// Default of `start_timeout`.
pub const DEFAULT_START_TIMEOUT: Duration = Duration::from_secs(5);
/// Default of `stop_timeout`.
pub const DEFAULT_STOP_TIMEOUT: Duration = Duration::from_secs(5);
/// `heartbeat_timeout` defaults to this many periods.
pub const DEFAULT_HEARTBEAT_TIMEOUT_PERIODS: u32 = 3;

/// A validated launch file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LaunchPlan {
    /// The file it came from.
    pub file: PathBuf,
    /// Name of the system.
    pub system: String,
    /// Modules in start order.
    pub modules: Vec<ModuleSpec>,
    /// The modules run on the simulated clock (`clock = "sim"`: `HNG_CLOCK=sim`).
    pub sim_clock: bool,
    /// Where checkpoints go (`checkpoint_dir`, resolved against the file's folder);
    /// `None`: the runner's default (its run directory).
    pub checkpoint_dir: Option<PathBuf>,
    /// Problems that do not prevent starting (e.g. a need nobody provides).
    pub warnings: Vec<String>,
}

/// How `command[0]` is resolved.
#[derive(Clone)]
pub struct LoadOptions {
    /// What `hng` / `@hng` means; `None`: [`std::env::current_exe`].
    pub self_exe: Option<PathBuf>,
    /// Search path for bare program names; `None`: the `PATH` variable.
    pub path: Option<OsString>,
    /// Check that programs exist and are executable.
    pub check_binaries: bool,
    /// Check every module whose program was resolved (see [`ModuleCheck`]).
    pub check_module: Option<ModuleCheck>,
}

impl fmt::Debug for LoadOptions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LoadOptions")
            .field("self_exe", &self.self_exe)
            .field("path", &self.path)
            .field("check_binaries", &self.check_binaries)
            .field("check_module", &self.check_module.is_some())
            .finish()
    }
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            self_exe: None,
            path: None,
            check_binaries: true,
            check_module: None,
        }
    }
}

// ---------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------

/// What is wrong at one place of a launch file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LaunchErrorKind {
    /// The file could not be read.
    Read(String),
    /// Not valid TOML.
    Syntax(String),
    /// A key the format does not have.
    UnknownField(String),
    /// A required key is absent.
    MissingField(String),
    /// A value of the wrong TOML type.
    WrongType(String),
    /// A value of the right type that is not acceptable.
    InvalidValue(String),
    /// `command[0]` cannot be executed.
    MissingBinary {
        /// What the file says.
        program: String,
        /// Why it cannot be used.
        reason: String,
    },
    /// Two modules with the same name.
    DuplicateModule {
        /// The name.
        name: String,
        /// Line of the first definition.
        first_line: usize,
    },
    /// More than one `manager = true`.
    TwoManagers {
        /// The first Manager.
        first: String,
        /// Its line.
        first_line: usize,
    },
    /// `needs`/`provides` form a cycle, so there is no start order.
    Cycle(Vec<String>),
}

impl fmt::Display for LaunchErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Read(m) => write!(f, "cannot read the launch file: {m}"),
            Self::Syntax(m) => write!(f, "TOML syntax error: {m}"),
            Self::UnknownField(m) => write!(f, "{m}"),
            Self::MissingField(m) => write!(f, "{m}"),
            Self::WrongType(m) => write!(f, "wrong type: {m}"),
            Self::InvalidValue(m) => write!(f, "{m}"),
            Self::MissingBinary { program, reason } => {
                write!(f, "program {program:?} cannot be run: {reason}")
            }
            Self::DuplicateModule { name, first_line } => write!(
                f,
                "duplicate module name {name:?} (first defined at line {first_line}): module names must be unique"
            ),
            Self::TwoManagers { first, first_line } => write!(
                f,
                "a second Manager: {first:?} (line {first_line}) is already the Manager; set manager = true on one module only"
            ),
            Self::Cycle(path) => write!(
                f,
                "needs/provides cycle, no start order exists: {}",
                path.join(" -> ")
            ),
        }
    }
}

/// One problem, with its position.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}:{line}:{column}: {}{kind}", file.display(), field.as_deref().map(|f| format!("`{f}`: ")).unwrap_or_default())]
pub struct LaunchError {
    /// The launch file.
    pub file: PathBuf,
    /// 1-based line.
    pub line: usize,
    /// 1-based column (in characters).
    pub column: usize,
    /// Dotted path of the field, e.g. `module[2].command` or `defaults.restart`.
    pub field: Option<String>,
    /// What is wrong.
    pub kind: LaunchErrorKind,
}

/// Every problem found in a launch file, in file order.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct LaunchErrors(pub Vec<LaunchError>);

impl fmt::Display for LaunchErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.0.len();
        write!(
            f,
            "{n} error{} in launch file",
            if n == 1 { "" } else { "s" }
        )?;
        for e in &self.0 {
            write!(f, "\n  {e}")?;
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------
// Serde mirror
// ---------------------------------------------------------------------------

/// A scalar whose type is checked by the validator (better messages than serde's).
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum Scalar {
    Int(i64),
    Float(f64),
    Str(String),
}

type S<T> = Spanned<T>;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTop {
    system: S<String>,
    clock: Option<S<String>>,
    checkpoint_dir: Option<S<String>>,
    defaults: Option<S<RawSettings>>,
}

/// Settings allowed in `[defaults]` and in each module.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSettings {
    restart: Option<S<RestartPolicy>>,
    backoff_initial: Option<S<Scalar>>,
    backoff_max: Option<S<Scalar>>,
    backoff_reset_after: Option<S<Scalar>>,
    give_up_failures: Option<S<i64>>,
    give_up_window: Option<S<Scalar>>,
    heartbeat_period: Option<S<Scalar>>,
    heartbeat_timeout: Option<S<Scalar>>,
    start_timeout: Option<S<Scalar>>,
    checkpoint_period: Option<S<Scalar>>,
    stop_timeout: Option<S<Scalar>>,
    cpu_quota: Option<S<Scalar>>,
    memory_max: Option<S<Scalar>>,
    pids_max: Option<S<Scalar>>,
    env: Option<BTreeMap<S<String>, S<String>>>,
}

/// A `[[module]]` table: its own keys plus every `[defaults]` key. (Not
/// `#[serde(flatten)]`: that would lose the spans and `deny_unknown_fields`.)
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModule {
    name: S<String>,
    command: S<Vec<S<String>>>,
    manager: Option<S<bool>>,
    needs: Option<Vec<S<String>>>,
    provides: Option<Vec<S<String>>>,
    config: Option<S<toml::Table>>,
    restart: Option<S<RestartPolicy>>,
    backoff_initial: Option<S<Scalar>>,
    backoff_max: Option<S<Scalar>>,
    backoff_reset_after: Option<S<Scalar>>,
    give_up_failures: Option<S<i64>>,
    give_up_window: Option<S<Scalar>>,
    heartbeat_period: Option<S<Scalar>>,
    heartbeat_timeout: Option<S<Scalar>>,
    start_timeout: Option<S<Scalar>>,
    checkpoint_period: Option<S<Scalar>>,
    stop_timeout: Option<S<Scalar>>,
    cpu_quota: Option<S<Scalar>>,
    memory_max: Option<S<Scalar>>,
    pids_max: Option<S<Scalar>>,
    env: Option<BTreeMap<S<String>, S<String>>>,
}

impl RawModule {
    /// Move the per-module settings out.
    fn take_settings(&mut self) -> RawSettings {
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

// ---------------------------------------------------------------------------
// Loading
// ---------------------------------------------------------------------------

/// Read and validate a launch file.
pub fn load(file: &Path, opts: &LoadOptions) -> Result<LaunchPlan, LaunchErrors> {
    match std::fs::read_to_string(file) {
        Ok(src) => parse(&src, file, opts),
        Err(e) => Err(LaunchErrors(vec![LaunchError {
            file: file.to_owned(),
            line: 1,
            column: 1,
            field: None,
            kind: LaunchErrorKind::Read(e.to_string()),
        }])),
    }
}

/// Validate launch-file text; `file` is used in messages and to resolve
/// relative program paths.
pub fn parse(src: &str, file: &Path, opts: &LoadOptions) -> Result<LaunchPlan, LaunchErrors> {
    let mut cx = Cx {
        src,
        file,
        errors: Vec::new(),
    };
    let plan = cx.parse(opts);
    let mut errors = cx.errors;
    if errors.is_empty()
        && let Some(plan) = plan
    {
        return Ok(plan);
    }
    errors.sort_by_key(|e| (e.line, e.column));
    errors.dedup();
    Err(LaunchErrors(errors))
}

struct Cx<'a> {
    src: &'a str,
    file: &'a Path,
    errors: Vec<LaunchError>,
}

/// 1-based line and column (in characters) of a byte offset.
pub fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(src.len());
    let before = src.get(..offset).unwrap_or(src);
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before.get(line_start..).map_or(0, |s| s.chars().count()) + 1;
    (line, column)
}

/// Settings after merging module over defaults, still spanned.
struct Merged<'r> {
    d: &'r RawSettings,
    m: &'r RawSettings,
    d_prefix: &'r str,
    m_prefix: String,
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
    fn err(&mut self, span: std::ops::Range<usize>, field: Option<String>, kind: LaunchErrorKind) {
        let (line, column) = line_col(self.src, span.start);
        self.errors.push(LaunchError {
            file: self.file.to_owned(),
            line,
            column,
            field,
            kind,
        });
    }

    fn line_of(&self, offset: usize) -> usize {
        line_col(self.src, offset).0
    }

    /// Turn a serde error of `value` (deserialized at `prefix`) into a LaunchError.
    fn serde_err(&mut self, e: &toml::de::Error, table: Option<&DeTable<'_>>, prefix: &str) {
        let span = e.span().unwrap_or(0..0);
        let msg = e.message().to_owned();
        let key = table.and_then(|t| key_at(t, span.start));
        let field = match key {
            Some(k) if prefix.is_empty() => k,
            Some(k) => format!("{prefix}.{k}"),
            None => prefix.to_owned(),
        };
        let kind = if msg.starts_with("unknown field") {
            LaunchErrorKind::UnknownField(msg)
        } else if msg.starts_with("missing field") {
            LaunchErrorKind::MissingField(msg)
        } else if msg.starts_with("invalid type") {
            LaunchErrorKind::WrongType(msg)
        } else if msg.starts_with("data did not match any variant") {
            LaunchErrorKind::WrongType("expected a number or a string".to_owned())
        } else {
            LaunchErrorKind::InvalidValue(msg)
        };
        let field = if field.is_empty() { None } else { Some(field) };
        self.err(span, field, kind);
    }

    fn parse(&mut self, opts: &LoadOptions) -> Option<LaunchPlan> {
        let (root, syntax) = DeTable::parse_recoverable(self.src);
        if !syntax.is_empty() {
            for e in syntax {
                let span = e.span().unwrap_or(0..0);
                self.err(span, None, LaunchErrorKind::Syntax(e.message().to_owned()));
            }
            return None;
        }
        let root_span = root.span();
        let mut root = root.into_inner();

        // Split off the modules so every one is deserialized (and reported) on its own.
        let modules_value = root
            .keys()
            .find(|k| k.get_ref() == "module")
            .cloned()
            .and_then(|key| root.remove(&key));
        let top_table = root.clone();
        let top = match RawTop::deserialize(ValueDeserializer::from(Spanned::new(
            root_span,
            DeValue::Table(root),
        ))) {
            Ok(t) => Some(t),
            Err(e) => {
                self.serde_err(&e, Some(&top_table), "");
                None
            }
        };

        let mut raws: Vec<(
            usize,
            RawModule,
            std::ops::Range<usize>,
            Option<DeTable<'_>>,
        )> = Vec::new();
        match modules_value {
            None => {
                if let Some(top) = &top {
                    self.err(
                        top.system.span(),
                        Some("module".to_owned()),
                        LaunchErrorKind::MissingField(
                            "no [[module]] tables: a system needs at least one module".to_owned(),
                        ),
                    );
                }
            }
            Some(v) => match v.get_ref() {
                DeValue::Array(arr) => {
                    for (i, el) in arr.iter().enumerate() {
                        let table = match el.get_ref() {
                            DeValue::Table(t) => Some(t.clone()),
                            _ => None,
                        };
                        let prefix = format!("module[{i}]");
                        match RawModule::deserialize(ValueDeserializer::from(el.clone())) {
                            Ok(m) => raws.push((i, m, el.span(), table)),
                            Err(e) => self.serde_err(&e, table.as_ref(), &prefix),
                        }
                    }
                }
                _ => self.err(
                    v.span(),
                    Some("module".to_owned()),
                    LaunchErrorKind::WrongType(
                        "`module` must be an array of tables: write [[module]]".to_owned(),
                    ),
                ),
            },
        }

        let top = top?;
        let empty = RawSettings::default();
        let defaults = top.defaults.as_ref().map_or(&empty, |d| d.get_ref());
        // Validate [defaults] on its own too, so errors there are reported once.
        let self_exe = opts
            .self_exe
            .clone()
            .or_else(|| std::env::current_exe().ok());
        let system = top.system.get_ref().trim().to_owned();
        if system.is_empty() {
            self.err(
                top.system.span(),
                Some("system".to_owned()),
                LaunchErrorKind::InvalidValue("the system name must not be empty".to_owned()),
            );
        }
        self.validate_settings_alone(defaults);
        let sim_clock = match &top.clock {
            None => false,
            Some(c) => match c.get_ref().trim() {
                "wall" => false,
                "sim" => true,
                other => {
                    self.err(
                        c.span(),
                        Some("clock".to_owned()),
                        LaunchErrorKind::InvalidValue(format!(
                            "clock {other:?}: expected \"wall\" or \"sim\""
                        )),
                    );
                    false
                }
            },
        };
        let checkpoint_dir = top.checkpoint_dir.as_ref().and_then(|d| {
            let text = d.get_ref().trim();
            if text.is_empty() {
                self.err(
                    d.span(),
                    Some("checkpoint_dir".to_owned()),
                    LaunchErrorKind::InvalidValue(
                        "checkpoint_dir must not be empty (leave it out for the default)"
                            .to_owned(),
                    ),
                );
                return None;
            }
            let p = Path::new(text);
            Some(if p.is_absolute() {
                p.to_owned()
            } else {
                self.file.parent().unwrap_or_else(|| Path::new(".")).join(p)
            })
        });

        let mut specs = Vec::new();
        let mut seen: HashMap<String, usize> = HashMap::new();
        let mut manager: Option<(String, usize)> = None;
        let mut spans = Vec::new();
        for (i, mut raw, span, table) in raws {
            let prefix = format!("module[{i}]");
            let name = raw.name.get_ref().clone();
            if !valid_name(&name) {
                self.err(
                    raw.name.span(),
                    Some(format!("{prefix}.name")),
                    LaunchErrorKind::InvalidValue(format!(
                        "module name {name:?} must be non-empty and use only A-Z, a-z, 0-9, '_' and '-'"
                    )),
                );
            }
            let name_line = self.line_of(raw.name.span().start);
            if let Some(first_line) = seen.get(&name) {
                let first_line = *first_line;
                self.err(
                    raw.name.span(),
                    Some(format!("{prefix}.name")),
                    LaunchErrorKind::DuplicateModule {
                        name: name.clone(),
                        first_line,
                    },
                );
            } else {
                seen.insert(name.clone(), name_line);
            }
            if let Some(m) = &raw.manager
                && *m.get_ref()
            {
                match &manager {
                    Some((first, first_line)) => {
                        let kind = LaunchErrorKind::TwoManagers {
                            first: first.clone(),
                            first_line: *first_line,
                        };
                        self.err(m.span(), Some(format!("{prefix}.manager")), kind);
                    }
                    None => manager = Some((name.clone(), self.line_of(m.span().start))),
                }
            }
            let settings = raw.take_settings();
            let merged = Merged {
                d: defaults,
                m: &settings,
                d_prefix: "defaults",
                m_prefix: prefix.clone(),
            };
            let program = self.resolve_program(&raw.command, &prefix, self_exe.as_deref(), opts);
            let resolved = program.is_some();
            let mut spec = ModuleSpec::new(name, program.unwrap_or_default(), &[]);
            spec.args = raw
                .command
                .get_ref()
                .iter()
                .skip(1)
                .map(|a| a.get_ref().clone())
                .collect();
            spec.manager = raw.manager.as_ref().is_some_and(|m| *m.get_ref());
            spec.needs = raw
                .needs
                .iter()
                .flatten()
                .map(|s| s.get_ref().clone())
                .collect();
            spec.provides = raw
                .provides
                .iter()
                .flatten()
                .map(|s| s.get_ref().clone())
                .collect();
            self.apply_settings(&merged, &mut spec);
            if let Some(cfg) = &raw.config {
                match toml::to_string(cfg.get_ref()) {
                    Ok(text) => spec.config = text,
                    Err(e) => self.err(
                        cfg.span(),
                        Some(format!("{prefix}.config")),
                        LaunchErrorKind::InvalidValue(format!(
                            "the config table cannot be passed on as TOML: {e}"
                        )),
                    ),
                }
            }
            if resolved
                && let Some(check) = &opts.check_module
                && let Err(problem) = check(&spec)
            {
                self.module_problem(problem, &raw, table.as_ref(), &spec.config, &prefix);
            }
            specs.push(spec);
            spans.push((
                span,
                raw.needs.as_ref().and_then(|n| n.first().map(|s| s.span())),
            ));
        }

        let (order, warnings) = self.start_order(&specs, &spans);
        if !self.errors.is_empty() {
            return None;
        }
        let modules = order
            .into_iter()
            .filter_map(|i| specs.get(i).cloned())
            .collect();
        Some(LaunchPlan {
            file: self.file.to_owned(),
            system,
            modules,
            sim_clock,
            checkpoint_dir,
            warnings,
        })
    }

    fn resolve_program(
        &mut self,
        command: &S<Vec<S<String>>>,
        prefix: &str,
        self_exe: Option<&Path>,
        opts: &LoadOptions,
    ) -> Option<PathBuf> {
        let field = Some(format!("{prefix}.command"));
        let Some(first) = command.get_ref().first() else {
            self.err(
                command.span(),
                field,
                LaunchErrorKind::InvalidValue(
                    "command is empty: give the program and its arguments, e.g. [\"hng\", \"module\", \"slam\"]"
                        .to_owned(),
                ),
            );
            return None;
        };
        let program = first.get_ref();
        let missing = |reason: String| LaunchErrorKind::MissingBinary {
            program: program.clone(),
            reason,
        };
        let candidate = if program == "hng" || program == "@hng" {
            match self_exe {
                Some(p) => p.to_owned(),
                None => {
                    self.err(
                        first.span(),
                        field,
                        missing("the path of the running executable is unknown".to_owned()),
                    );
                    return None;
                }
            }
        } else if program.contains('/') {
            let p = Path::new(program);
            if p.is_absolute() {
                p.to_owned()
            } else {
                self.file.parent().unwrap_or_else(|| Path::new(".")).join(p)
            }
        } else {
            let path = opts
                .path
                .clone()
                .or_else(|| std::env::var_os("PATH"))
                .unwrap_or_default();
            let found = std::env::split_paths(&path)
                .map(|dir| dir.join(program))
                .find(|p| is_executable(p).is_ok());
            match found {
                Some(p) => p,
                None if !opts.check_binaries => PathBuf::from(program),
                None => {
                    self.err(
                        first.span(),
                        field,
                        missing("not found in PATH (or not executable there)".to_owned()),
                    );
                    return None;
                }
            }
        };
        if opts.check_binaries
            && let Err(reason) = is_executable(&candidate)
        {
            self.err(
                first.span(),
                field,
                missing(format!("{}: {reason}", candidate.display())),
            );
            return None;
        }
        Some(candidate)
    }

    fn validate_settings_alone(&mut self, d: &RawSettings) {
        let none = RawSettings::default();
        let merged = Merged {
            d: &none,
            m: d,
            d_prefix: "defaults",
            m_prefix: "defaults".to_owned(),
        };
        let mut scratch = ModuleSpec::new("defaults", "", &[]);
        self.apply_settings(&merged, &mut scratch);
    }

    /// Fill `spec` from module settings over defaults over built-in defaults.
    /// Values coming from `[defaults]` are checked once by
    /// `validate_settings_alone`, so errors are only reported here for values
    /// the module sets itself.
    fn apply_settings(&mut self, s: &Merged<'_>, spec: &mut ModuleSpec) {
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
                Scalar::Str(t) => parse_duration(t).map(Some),
                Scalar::Int(0) => Ok(Some(Duration::ZERO)),
                Scalar::Int(_) | Scalar::Float(_) => Err(
                    "a duration needs a unit: write a string such as \"250ms\" or \"2s\""
                        .to_owned(),
                ),
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
        if let Some(Some(d)) = dur(pick!(s, backoff_initial), false, &mut errs) {
            spec.backoff_initial = d;
        }
        let backoff_max_field = pick!(s, backoff_max);
        if let Some(Some(d)) = dur(backoff_max_field.clone(), false, &mut errs) {
            spec.backoff_max = d;
        }
        if let Some(Some(d)) = dur(pick!(s, backoff_reset_after), false, &mut errs) {
            spec.backoff_reset_after = d;
        }
        // A zero here would switch a safety mechanism off without saying so.
        let zero = |f: &Option<(&S<Scalar>, String)>, why: &str, errs: &mut Errs| {
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
        let f = pick!(s, give_up_window);
        match dur(f.clone(), false, &mut errs) {
            Some(Some(d)) if d.is_zero() => zero(
                &f,
                "give_up_window = 0 would never count a restart, so a crash loop would never be stopped: give a window such as \"60s\"",
                &mut errs,
            ),
            Some(Some(d)) => spec.give_up_window = d,
            _ => {}
        }
        let f = pick!(s, start_timeout);
        match dur(f.clone(), false, &mut errs) {
            Some(Some(d)) if d.is_zero() => zero(
                &f,
                "start_timeout = 0 would count every start as a hang: give the time a module may take to its first heartbeat, such as \"5s\"",
                &mut errs,
            ),
            Some(Some(d)) => spec.start_timeout = d,
            _ => {}
        }
        let f = pick!(s, stop_timeout);
        match dur(f.clone(), false, &mut errs) {
            Some(Some(d)) if d.is_zero() => zero(
                &f,
                "stop_timeout = 0 would SIGKILL every module without letting it stop (no final checkpoint): give a time such as \"5s\"",
                &mut errs,
            ),
            Some(Some(d)) => spec.stop_timeout = d,
            _ => {}
        }
        if let Some(d) = dur(pick!(s, checkpoint_period), true, &mut errs) {
            spec.checkpoint_period = d.filter(|d| !d.is_zero());
        }
        let period_field = pick!(s, heartbeat_period);
        let period = dur(period_field.clone(), true, &mut errs).flatten();
        if period.is_some_and(|p| p.is_zero()) {
            zero(
                &period_field,
                "heartbeat_period = 0 would switch hang detection off without saying so: give a period such as \"100ms\", or write \"off\"",
                &mut errs,
            );
        }
        let timeout_field = pick!(s, heartbeat_timeout);
        let timeout = dur(timeout_field.clone(), false, &mut errs).flatten();
        match (period, timeout, timeout_field) {
            (Some(p), t, tf) if !p.is_zero() => {
                let t = t.unwrap_or(p * DEFAULT_HEARTBEAT_TIMEOUT_PERIODS);
                if t <= p
                    && let Some((v, f)) = tf
                    && report(&f)
                {
                    errs.push((
                        v.span(),
                        f,
                        LaunchErrorKind::InvalidValue(format!(
                            "heartbeat_timeout ({t:?}) must be longer than heartbeat_period ({p:?}); 3 periods is usual"
                        )),
                    ));
                }
                spec.heartbeat = Some(HeartbeatSpec {
                    period: p,
                    timeout: t,
                });
                if pick!(s, start_timeout).is_none() {
                    spec.start_timeout = spec.start_timeout.max(t);
                }
            }
            (_, Some(_), Some((v, f))) if report(&f) => errs.push((
                v.span(),
                f,
                LaunchErrorKind::InvalidValue(
                    "heartbeat_timeout is set but heartbeat_period is not: set heartbeat_period too"
                        .to_owned(),
                ),
            )),
            _ => spec.heartbeat = None,
        }
        if spec.backoff_initial > spec.backoff_max
            && let Some((v, f)) = backoff_max_field
            && report(&f)
        {
            errs.push((
                v.span(),
                f,
                LaunchErrorKind::InvalidValue(format!(
                    "backoff_max ({:?}) is smaller than backoff_initial ({:?})",
                    spec.backoff_max, spec.backoff_initial
                )),
            ));
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

    /// Topological order from needs/provides (stable: file order among ready
    /// modules). Reports cycles as errors and unprovided needs as warnings.
    fn start_order(
        &mut self,
        specs: &[ModuleSpec],
        spans: &[(std::ops::Range<usize>, Option<std::ops::Range<usize>>)],
    ) -> (Vec<usize>, Vec<String>) {
        let mut warnings = Vec::new();
        let mut providers: HashMap<&str, Vec<usize>> = HashMap::new();
        for (i, s) in specs.iter().enumerate() {
            for p in &s.provides {
                providers.entry(p.as_str()).or_default().push(i);
            }
        }
        // deps[i]: modules that must start before i.
        let mut deps: Vec<Vec<usize>> = vec![Vec::new(); specs.len()];
        for (i, s) in specs.iter().enumerate() {
            for n in &s.needs {
                match providers.get(n.as_str()) {
                    Some(ps) => deps[i].extend(ps.iter().copied().filter(|&p| p != i)),
                    None => warnings.push(format!(
                        "module {:?} needs {n:?} but no module provides it",
                        s.name
                    )),
                }
            }
        }
        let mut done = vec![false; specs.len()];
        let mut order = Vec::with_capacity(specs.len());
        while order.len() < specs.len() {
            let next = (0..specs.len()).find(|&i| !done[i] && deps[i].iter().all(|&d| done[d]));
            match next {
                Some(i) => {
                    done[i] = true;
                    order.push(i);
                }
                None => {
                    // Every remaining module waits on another: walk to a cycle.
                    let Some(start) = (0..specs.len()).find(|&i| !done[i]) else {
                        break;
                    };
                    let mut path = vec![start];
                    let mut cur = start;
                    let cycle = loop {
                        let Some(&next) = deps[cur].iter().find(|&&d| !done[d]) else {
                            break vec![cur];
                        };
                        if let Some(pos) = path.iter().position(|&p| p == next) {
                            let mut c = path.split_off(pos);
                            c.push(next);
                            break c;
                        }
                        path.push(next);
                        cur = next;
                    };
                    let names: Vec<String> = cycle.iter().map(|&i| specs[i].name.clone()).collect();
                    let first = cycle.first().copied().unwrap_or(start);
                    let (module_span, needs_span) = spans[first].clone();
                    self.err(
                        needs_span.unwrap_or(module_span),
                        Some(format!("module \"{}\".needs", specs[first].name)),
                        LaunchErrorKind::Cycle(names),
                    );
                    // Mark the cycle done and keep going, so every cycle is reported.
                    for &i in &cycle {
                        if !done[i] {
                            done[i] = true;
                            order.push(i);
                        }
                    }
                }
            }
        }
        (order, warnings)
    }
}

/// The innermost key of `table` (recursively) whose key or value span
/// contains `offset`. Sub-tables are searched first: the span of a `[table]`
/// value covers only its header, not its keys.
fn key_at(table: &DeTable<'_>, offset: usize) -> Option<String> {
    for (k, v) in table.iter() {
        if let DeValue::Table(inner) = v.get_ref()
            && let Some(sub) = key_at(inner, offset)
        {
            return Some(format!("{}.{sub}", k.get_ref()));
        }
    }
    table
        .iter()
        .find(|(k, v)| {
            let ks = k.span();
            ks.contains(&offset)
                || v.span().contains(&offset)
                || (ks.start == offset && ks.is_empty())
        })
        .map(|(k, _)| k.get_ref().to_string())
}

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

fn is_executable(p: &Path) -> Result<(), String> {
    match std::fs::metadata(p) {
        Err(e) => Err(e.to_string()),
        Ok(m) if !m.is_file() => Err("not a regular file".to_owned()),
        Ok(m) if m.permissions().mode() & 0o111 == 0 => {
            Err("not executable (no x permission)".to_owned())
        }
        Ok(_) => Ok(()),
    }
}

mod check;
#[cfg(test)]
mod tests;
