//! The co-adaptation application's error: the kind a caller branches on (a setting, a file, the
//! fleet's setup, the learner's run, the supervisor) with the context it was met in, as a chain
//! printed once (`outer: inner: cause`). [`Error::exit_code`] tells a binary whether a restart
//! could mend it.

use std::fmt::Display;

use coadapt_fleet::SetupError;
use coadapt_fleet::supervise::SuperviseError;
use coadapt_fleet::supervise::exit::{CONFIG, ExitCode};
use coadapt_learner::coadapt::CoadaptError;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A setting is wrong; the message names it.
    #[error("{0}")]
    Config(String),
    /// A file could not be read or written (a full disk is told apart by its kind).
    // Transparent, as every wrapper here: `#[from]` makes the inner error the source, and a
    // message of its own as well would print the cause twice in a `{:#}` chain.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Setup(#[from] SetupError),
    #[error(transparent)]
    Run(#[from] CoadaptError),
    #[error(transparent)]
    Supervise(#[from] SuperviseError),
    /// Anything else, said in words.
    #[error("{0}")]
    Failed(String),
    /// `inner`, met while doing `what`.
    #[error("{what}: {inner}")]
    Context { what: String, inner: Box<Error> },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// `Some(code)` when a restart cannot mend this failure (a setting, a full disk).
    pub fn exit_code(&self) -> Option<u8> {
        match self {
            Self::Config(_) => Some(CONFIG),
            Self::Io(e) => e.exit_code(),
            Self::Setup(e) => e.exit_code(),
            Self::Run(e) => e.exit_code(),
            Self::Supervise(e) => e.exit_code(),
            Self::Failed(_) => None,
            Self::Context { inner, .. } => inner.exit_code(),
        }
    }
}

/// A run's setting the learner refuses: a setting, so the run stops for good (exit 78).
impl From<coadapt_learner::ConfigError> for Error {
    fn from(e: coadapt_learner::ConfigError) -> Self {
        Self::Config(e.to_string())
    }
}

/// Errors of other libraries that carry no kind a caller branches on: their message is kept.
macro_rules! failed_from {
    ($($t:ty),* $(,)?) => {$(
        impl From<$t> for Error {
            fn from(e: $t) -> Self {
                Self::Failed(e.to_string())
            }
        }
    )*};
}

failed_from!(
    String,
    &str,
    toml::de::Error,
    toml::ser::Error,
    serde_json::Error,
    coadapt_design_optimizer::landscape::LandscapeError,
    coadapt_design_optimizer::objective::ObjectiveError,
    coadapt_learner::snapshot::SnapshotError,
    coadapt_nn::NnError,
    coadapt_transport::TransportError,
    plotters::drawing::DrawingAreaErrorKind<std::io::Error>,
    std::net::AddrParseError,
    std::string::FromUtf8Error,
    coadapt_actors::ActorError,
    coadapt_actors::role::ActorRoleError,
    coadapt_design_optimizer::role::OptimizerError,
);

/// Context for a failure, as `anyhow::Context` gives it, keeping the failure's kind.
pub trait Context<T> {
    fn context(self, what: impl Display) -> Result<T>;
    fn with_context<S: Display>(self, what: impl FnOnce() -> S) -> Result<T>;
}

impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
    fn context(self, what: impl Display) -> Result<T> {
        self.map_err(|e| Error::Context { what: what.to_string(), inner: Box::new(e.into()) })
    }

    fn with_context<S: Display>(self, what: impl FnOnce() -> S) -> Result<T> {
        self.map_err(|e| Error::Context { what: what().to_string(), inner: Box::new(e.into()) })
    }
}

impl<T> Context<T> for Option<T> {
    fn context(self, what: impl Display) -> Result<T> {
        self.ok_or_else(|| Error::Failed(what.to_string()))
    }

    fn with_context<S: Display>(self, what: impl FnOnce() -> S) -> Result<T> {
        self.ok_or_else(|| Error::Failed(what().to_string()))
    }
}

/// `return Err(Error::Failed(format!(...)))`.
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err($crate::error::Error::Failed(format!($($arg)*)))
    };
}
pub(crate) use bail;

/// `return Err(Error::Config(format!(...)))`: a setting is wrong.
macro_rules! bail_config {
    ($($arg:tt)*) => {
        return Err($crate::error::Error::Config(format!($($arg)*)))
    };
}
pub(crate) use bail_config;

/// `Error::Failed(format!(...))`.
macro_rules! failed {
    ($($arg:tt)*) => {
        $crate::error::Error::Failed(format!($($arg)*))
    };
}
pub(crate) use failed;

impl Error {
    /// This error, met while doing `what`.
    pub fn context(self, what: impl Display) -> Self {
        Self::Context { what: what.to_string(), inner: Box::new(self) }
    }
}
