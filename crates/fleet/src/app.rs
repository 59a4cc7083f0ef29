//! [`AppError`]: why an application (the co-adaptation, `coadapt latent`, `coadapt search`, a
//! benchmark) or one of its roles stopped, written once for all of them.
//!
//! A binary branches on one thing: whether starting the process again could mend the failure
//! ([`AppError::exit_code`]: a bad setting or a full disk cannot be mended). So the kinds are
//! few: a setting, a named file, an interruption, a library's own error (which says its exit
//! code through [`ExitCode`] as it is converted), or words; each may sit under the context it was
//! met in, printed once as `outer: inner: cause`. [`Context`] adds that context the way
//! `anyhow::Context` does, keeping the kind.

use std::error::Error as StdError;
use std::fmt::{self, Display};

use crate::supervise::exit::{CONFIG, DISK, ExitCode, is_disk_full};

/// Why an application stopped. See the module's doc.
#[derive(Debug)]
pub enum AppError {
    /// A setting is wrong (or the run directory does not fit it); the message names it.
    Config(String),
    /// A file or directory; `what` names it and what was done with it.
    Io { what: String, error: std::io::Error },
    /// Ctrl-C or SIGTERM; the message says what is kept.
    Interrupted(String),
    /// Anything else, said in words.
    Failed(String),
    /// A library's error as it reports itself, with the exit code it asked for when converted.
    Library { error: Box<dyn StdError + Send + Sync>, code: Option<u8> },
    /// `inner`, met while doing `what`.
    Context { what: String, inner: Box<AppError> },
}

pub type Result<T, E = AppError> = std::result::Result<T, E>;

impl AppError {
    /// `Io` naming `what`, for `map_err`.
    pub fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |error| Self::Io { what, error }
    }

    /// `Failed` with the message of `e`: for errors that carry nothing a caller branches on
    /// (a plot that could not be drawn, a message in a `String`).
    pub fn failed(e: impl Display) -> Self {
        Self::Failed(e.to_string())
    }

    /// A library error that cannot say an exit code of its own (it comes from a crate that does
    /// not know [`ExitCode`]): a restart may mend it.
    pub fn library<E: StdError + Send + Sync + 'static>(error: E) -> Self {
        Self::Library { error: Box::new(error), code: None }
    }

    /// This error, met while doing `what`.
    pub fn context(self, what: impl Display) -> Self {
        Self::Context { what: what.to_string(), inner: Box::new(self) }
    }

    /// The error under any [`AppError::Context`].
    pub fn root(&self) -> &Self {
        match self {
            Self::Context { inner, .. } => inner.root(),
            e => e,
        }
    }

    /// `Some(code)` when a restart cannot mend this failure: [`CONFIG`] for a setting, [`DISK`]
    /// for a full disk, or the code a library's error asked for.
    pub fn exit_code(&self) -> Option<u8> {
        match self.root() {
            Self::Config(_) => Some(CONFIG),
            Self::Io { error, .. } => is_disk_full(error.kind()).then_some(DISK),
            Self::Library { code, .. } => *code,
            Self::Interrupted(_) | Self::Failed(_) | Self::Context { .. } => None,
        }
    }
}

impl Display for AppError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Config(m) | Self::Interrupted(m) | Self::Failed(m) => f.write_str(m),
            Self::Io { what, error } => write!(f, "{what}: {error}"),
            Self::Library { error, .. } => Display::fmt(error, f),
            Self::Context { what, inner } => write!(f, "{what}: {inner}"),
        }
    }
}

impl StdError for AppError {
    /// A library's error is shown as it reports itself (its causes follow in a `{:#}` chain);
    /// everything else says its cause in its own message, so a chain does not print it twice.
    fn source(&self) -> Option<&(dyn StdError + 'static)> {
        match self {
            Self::Library { error, .. } => error.source(),
            _ => None,
        }
    }
}

/// A library's error becomes [`AppError::Library`] with the exit code it says. `AppError` itself
/// is not an [`ExitCode`], so this does not overlap `From<AppError>`.
impl<E: StdError + ExitCode + Send + Sync + 'static> From<E> for AppError {
    fn from(error: E) -> Self {
        let code = error.exit_code();
        Self::Library { error: Box::new(error), code }
    }
}

/// Context for a failure, as `anyhow::Context` gives it, keeping the failure's kind.
pub trait Context<T> {
    fn context(self, what: impl Display) -> Result<T>;
    fn with_context<S: Display>(self, what: impl FnOnce() -> S) -> Result<T>;
}

impl<T, E: Into<AppError>> Context<T> for std::result::Result<T, E> {
    fn context(self, what: impl Display) -> Result<T> {
        self.map_err(|e| e.into().context(what))
    }

    fn with_context<S: Display>(self, what: impl FnOnce() -> S) -> Result<T> {
        self.map_err(|e| e.into().context(what()))
    }
}

/// A missing value is a failure said in words.
impl<T> Context<T> for Option<T> {
    fn context(self, what: impl Display) -> Result<T> {
        self.ok_or_else(|| AppError::Failed(what.to_string()))
    }

    fn with_context<S: Display>(self, what: impl FnOnce() -> S) -> Result<T> {
        self.ok_or_else(|| AppError::Failed(what().to_string()))
    }
}

// The libraries below the fleet cannot name `ExitCode`; what their errors mean for a restart is
// said here. A name or address that does not parse fails the same way every time; a weights
// file that cannot be written may be a full disk; the rest may pass (a server that was down, a
// broken link, a robot that fell over).

impl ExitCode for coadapt_robots::UnknownEnv {
    fn exit_code(&self) -> Option<u8> {
        Some(CONFIG)
    }
}

impl ExitCode for coadapt_env_rpc::AddressError {
    fn exit_code(&self) -> Option<u8> {
        Some(CONFIG)
    }
}

impl ExitCode for coadapt_env_rpc::RemoteError {
    fn exit_code(&self) -> Option<u8> {
        matches!(self, Self::Address { .. }).then_some(CONFIG)
    }
}

impl ExitCode for coadapt_nn::NnError {
    fn exit_code(&self) -> Option<u8> {
        match self {
            Self::Write { cause, .. } | Self::Read { cause, .. } => cause.exit_code(),
            _ => None,
        }
    }
}

impl ExitCode for coadapt_core::EnvError {}
impl ExitCode for coadapt_core::ReplayError {}
impl ExitCode for coadapt_core::SpaceError {}
impl ExitCode for coadapt_transport::TransportError {}
impl ExitCode for coadapt_auth::TlsError {}
impl ExitCode for coadapt_robots::bench::BenchError {}
impl ExitCode for tonic::Status {}
impl ExitCode for tonic::transport::Error {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SetupError;

    fn full() -> std::io::Error {
        std::io::Error::from_raw_os_error(28)
    }

    #[test]
    fn a_full_disk_and_a_bad_setting_are_told_apart_under_context() {
        let e: Result<()> = Err(AppError::io("writing episodes.csv")(full()));
        let e = e.with_context(|| "run 0").unwrap_err();
        assert_eq!(e.exit_code(), Some(DISK));
        assert_eq!(e.to_string(), format!("run 0: writing episodes.csv: {}", full()));
        let bad: Result<()> = Err(AppError::Config("runs = 0: at least 1".into()));
        assert_eq!(bad.context("w-hat = x").unwrap_err().exit_code(), Some(CONFIG));
        assert_eq!(AppError::Failed("gone".into()).exit_code(), None);
        assert_eq!(AppError::Interrupted("stopped".into()).exit_code(), None);
        let e = AppError::Io { what: "x.json".into(), error: std::io::Error::from(std::io::ErrorKind::NotFound) };
        assert_eq!(e.exit_code(), None);
    }

    #[test]
    fn a_library_error_keeps_the_code_it_asked_for_and_its_message() {
        let setup: Result<(), SetupError> = Err(SetupError::Config("security.tls-cert: missing".into()));
        let e = setup.context("starting the learner").unwrap_err();
        assert_eq!(e.exit_code(), Some(CONFIG));
        assert_eq!(e.to_string(), "starting the learner: security.tls-cert: missing");
        let disk: Result<(), std::io::Error> = Err(full());
        assert_eq!(disk.context("snapshot").unwrap_err().exit_code(), Some(DISK));
        let reset: Result<(), std::io::Error> = Err(std::io::ErrorKind::ConnectionReset.into());
        assert_eq!(reset.context("link").unwrap_err().exit_code(), None);
        #[derive(Debug, thiserror::Error)]
        #[error("no exit code of its own")]
        struct Plain;
        assert_eq!(AppError::library(Plain).exit_code(), None);
        assert_eq!(None::<u8>.context("no value").unwrap_err().to_string(), "no value");
    }
}
