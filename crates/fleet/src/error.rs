//! Why a fleet could not be set up: a setting (a restart cannot mend it), a transport, a file or
//! process. Callers branch on the kind: a supervisor does not restart a role that failed on its
//! config or a full disk ([`crate::exit`]).

use coadapt_transport::TransportError;

#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// A setting is wrong; the message names it.
    #[error("{0}")]
    Config(String),
    /// A transport could not be opened or joined; `what` says which.
    #[error("{what}: {error}")]
    Transport { what: String, error: TransportError },
    /// A file or process could not be made; `what` names it.
    #[error("{what}: {error}")]
    Io { what: String, error: std::io::Error },
    /// A remote environment could not be reached.
    #[error("{0}")]
    Env(String),
}

impl SetupError {
    /// The I/O error's kind, if it is one (a full disk is told apart by it).
    pub fn io_kind(&self) -> Option<std::io::ErrorKind> {
        match self {
            Self::Io { error, .. } => Some(error.kind()),
            _ => None,
        }
    }

    pub(crate) fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |error| Self::Io { what, error }
    }

    pub(crate) fn transport(what: impl Into<String>) -> impl FnOnce(TransportError) -> Self {
        let what = what.into();
        move |error| Self::Transport { what, error }
    }
}
