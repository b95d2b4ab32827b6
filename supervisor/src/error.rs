//! The supervisor host's error: what failed, with the cause underneath (`hng` prints the
//! chain: "creating the supervisor's node: ...").

/// An error of the supervisor host.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    /// A step that failed, and why.
    #[error("{what}")]
    Context {
        /// What was being done.
        what: String,
        /// Why it failed.
        #[source]
        source: Box<HostError>,
    },
    /// A refusal or a failure said in words.
    #[error("{0}")]
    Message(String),
    /// A channel, node or waiter of the runtime.
    #[error(transparent)]
    Runtime(#[from] hng_runtime::Error),
    /// The watchdog's supervisor.
    #[error(transparent)]
    Supervisor(#[from] hng_watchdog::SupervisorError),
    /// A file or a thread.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// The built-in mission's world.
    #[error(transparent)]
    World(#[from] hng_simulator::SimError),
    /// A JSON document.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

impl HostError {
    /// An error said in words.
    pub fn msg(text: impl Into<String>) -> HostError {
        HostError::Message(text.into())
    }
}

/// The supervisor host's result.
pub type Result<T, E = HostError> = std::result::Result<T, E>;

/// Says what was being done when an error happened (as `anyhow::Context`, for this crate's
/// [`HostError`]).
pub trait Context<T> {
    /// With a fixed text.
    fn context(self, what: impl Into<String>) -> Result<T>;
    /// With a text made only on error.
    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T>;
}

impl<T, E: Into<HostError>> Context<T> for std::result::Result<T, E> {
    fn context(self, what: impl Into<String>) -> Result<T> {
        self.map_err(|e| HostError::Context {
            what: what.into(),
            source: Box::new(e.into()),
        })
    }

    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T> {
        self.map_err(|e| HostError::Context {
            what: what().into(),
            source: Box::new(e.into()),
        })
    }
}

/// Returns a [`HostError::Message`] made with `format!`.
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err($crate::error::HostError::Message(format!($($arg)*)))
    };
}
pub(crate) use bail;
