//! Launch-file errors: file, line, column, field and what is wrong.

use std::fmt;
use std::path::PathBuf;

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
