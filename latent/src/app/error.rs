//! [`LatentError`]: why `coadapt latent` or one of its actors stopped, in the kinds a caller
//! branches on (a bad setting, a file, the fleet's setup, the robot, the fleet).

use coadapt_core::{EnvError, ReplayError};
use coadapt_fleet::SetupError;
use coadapt_fleet::supervise::exit::{CONFIG, DISK, ExitCode, is_disk_full};
use coadapt_nn::NnError;

use crate::{EmbeddingFileError, FleetError};

/// Why a latent run (or an actor of one) stopped. Wrapped errors are part of the message and
/// not `source()`s: a chain printed with `{:#}` would otherwise say each cause twice.
#[derive(Debug, thiserror::Error)]
pub enum LatentError {
    /// A setting is wrong (or the run directory does not fit it); the message names it.
    #[error("{0}")]
    Config(String),
    /// A file or directory; `what` names it and what was done with it.
    #[error("{what}: {error}")]
    Io { what: String, error: std::io::Error },
    /// The fleet could not be set up (links, actor processes, a remote robot's options).
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// The robot failed.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// An episode through the fleet failed (an actor, the transport, a deadline).
    #[error(transparent)]
    Fleet(#[from] FleetError),
    /// The embedding file could not be read or written.
    #[error(transparent)]
    EmbeddingFile(#[from] EmbeddingFileError),
    /// A network could not be built or its checkpoint written.
    #[error(transparent)]
    Nn(#[from] NnError),
    /// A transition the replay refused.
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// A plot could not be drawn.
    #[error("{0}")]
    Plot(String),
    /// Ctrl-C or SIGTERM; the message says what is kept.
    #[error("{0}")]
    Interrupted(String),
    /// `error`, with what was being done (`run 0 training episode 3`, `robot = ...`).
    #[error("{what}: {error}")]
    Context { what: String, error: Box<LatentError> },
}

impl LatentError {
    /// `Io` with `what`, for `map_err`.
    pub(crate) fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |error| Self::Io { what, error }
    }

    /// The error under any [`LatentError::Context`].
    pub fn root(&self) -> &Self {
        match self {
            Self::Context { error, .. } => error.root(),
            e => e,
        }
    }

    /// The I/O error's kind, if it is one (a full disk is told apart by it).
    pub fn io_kind(&self) -> Option<std::io::ErrorKind> {
        match self.root() {
            Self::Io { error, .. } => Some(error.kind()),
            Self::Setup(e) => e.io_kind(),
            Self::Nn(NnError::Write { cause, .. } | NnError::Read { cause, .. }) => Some(cause.kind()),
            Self::EmbeddingFile(EmbeddingFileError::Io { source, .. }) => Some(source.kind()),
            _ => None,
        }
    }
}

impl ExitCode for LatentError {
    fn exit_code(&self) -> Option<u8> {
        match self.root() {
            Self::Config(_) => Some(CONFIG),
            Self::Setup(e) => e.exit_code(),
            e if e.io_kind().is_some_and(is_disk_full) => Some(DISK),
            _ => None,
        }
    }
}

/// `.within(|| what)`: the error with what was being done, as anyhow's `with_context` did.
pub(crate) trait Within<T> {
    fn within<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, LatentError>;
}

impl<T, E: Into<LatentError>> Within<T> for Result<T, E> {
    fn within<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, LatentError> {
        self.map_err(|e| LatentError::Context { what: what().into(), error: Box::new(e.into()) })
    }
}

/// A plotters error as [`LatentError::Plot`].
pub(crate) fn plot_error<E: std::fmt::Display>(e: E) -> LatentError {
    LatentError::Plot(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_and_a_bad_setting_are_told_apart_under_context() {
        let full = LatentError::io("writing episodes.csv")(std::io::Error::from_raw_os_error(28));
        let e: Result<(), _> = Err(full);
        let e = e.within(|| "run 0").unwrap_err();
        assert_eq!(e.exit_code(), Some(DISK));
        assert_eq!(e.to_string(), format!("run 0: writing episodes.csv: {}", std::io::Error::from_raw_os_error(28)));
        assert_eq!(LatentError::Config("runs = 0: at least 1".into()).exit_code(), Some(CONFIG));
        assert_eq!(LatentError::Fleet(FleetError::Learner("gone".into())).exit_code(), None);
    }
}
