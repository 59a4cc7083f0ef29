//! [`SearchError`]: why `coadapt search` or one of its actors stopped, in the kinds a caller
//! branches on (a bad setting, a file, the fleet's setup, the rollouts, a remote robot).

use coadapt_fleet::SetupError;
use coadapt_fleet::supervise::exit::{CONFIG, DISK, ExitCode, is_disk_full};

use crate::RolloutError;

/// Why a search (or an actor of one) stopped. Wrapped errors are part of the message and not
/// `source()`s: a chain printed with `{:#}` would otherwise say each cause twice.
#[derive(Debug, thiserror::Error)]
pub enum SearchError {
    /// A setting is wrong (or the run directory does not fit it); the message names it.
    #[error("{0}")]
    Config(String),
    /// A file or directory; `what` names it and what was done with it.
    #[error("{what}: {error}")]
    Io { what: String, error: std::io::Error },
    /// The fleet could not be set up (links, actor processes, a remote robot's options).
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// An iteration's rollouts could not be run (an actor, the transport, a deadline).
    #[error(transparent)]
    Rollout(#[from] RolloutError),
    /// A dm_env_rpc robot could not be reached.
    #[error(transparent)]
    Remote(#[from] coadapt_env_rpc::RemoteError),
    /// A policy file could not be put together (safetensors).
    #[error("{0}")]
    Tensors(String),
    /// A plot could not be drawn.
    #[error("{0}")]
    Plot(String),
    /// Ctrl-C or SIGTERM; the message says what is kept.
    #[error("{0}")]
    Interrupted(String),
    /// `error`, with what was being done (`run 0 iteration 3`, `w-hat = ...`).
    #[error("{what}: {error}")]
    Context { what: String, error: Box<SearchError> },
}

impl SearchError {
    /// `Io` with `what`, for `map_err`.
    pub(crate) fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |error| Self::Io { what, error }
    }

    /// The error under any [`SearchError::Context`].
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
            _ => None,
        }
    }
}

impl ExitCode for SearchError {
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
    fn within<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, SearchError>;
}

impl<T, E: Into<SearchError>> Within<T> for Result<T, E> {
    fn within<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, SearchError> {
        self.map_err(|e| SearchError::Context { what: what().into(), error: Box::new(e.into()) })
    }
}

/// A plotters error as [`SearchError::Plot`].
pub(crate) fn plot_error<E: std::fmt::Display>(e: E) -> SearchError {
    SearchError::Plot(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_and_a_bad_setting_are_told_apart_under_context() {
        let full = SearchError::io("writing iterations.csv")(std::io::Error::from_raw_os_error(28));
        let e: Result<(), _> = Err(full);
        let e = e.within(|| "run 0 iteration 1").unwrap_err();
        assert_eq!(e.exit_code(), Some(DISK));
        let bad: Result<(), _> = Err(SearchError::Config("x: W is F32".into()));
        assert_eq!(bad.within(|| "w-hat = x").unwrap_err().exit_code(), Some(CONFIG));
        assert_eq!(SearchError::Rollout(RolloutError("gone".into())).exit_code(), None);
    }
}
