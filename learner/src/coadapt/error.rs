//! Why a run stopped ([`CoadaptError`]), and the exit code a supervisor reads from it.

use coadapt_transport::TransportError;

use crate::ConfigError;
use crate::snapshot::SnapshotError;

/// Why a run stopped. The wrapped errors are part of the message and deliberately not
/// `source()`s: an error chain printed with `{:#}` would otherwise say every cause twice
/// ("No space left on device (os error 28): No space left on device (os error 28)").
#[derive(Debug, thiserror::Error)]
pub enum CoadaptError {
    #[error("config: {0}")]
    Config(String),
    #[error("transport: {0}")]
    Transport(TransportError),
    #[error("{0}")]
    Protocol(String),
    #[error("replay: {0}")]
    Replay(coadapt_core::ReplayError),
    /// A non-finite update (the message names the pair, the update, the design and episode).
    #[error(transparent)]
    Train(#[from] crate::fear::TrainError),
    /// Reading or writing the run directory; the message names the file and what was done.
    #[error("run directory: {0}")]
    Io(std::io::Error),
    #[error("saving a checkpoint: {0}")]
    Checkpoint(coadapt_nn::NnError),
    #[error("snapshot: {0}")]
    Snapshot(SnapshotError),
}

macro_rules! from_without_source {
    ($($variant:ident($t:ty)),*) => {$(
        impl From<$t> for CoadaptError {
            fn from(e: $t) -> Self {
                Self::$variant(e)
            }
        }
    )*};
}
from_without_source!(
    Transport(TransportError),
    Replay(coadapt_core::ReplayError),
    Io(std::io::Error),
    Checkpoint(coadapt_nn::NnError),
    Snapshot(SnapshotError)
);

impl From<ConfigError> for CoadaptError {
    fn from(e: ConfigError) -> Self {
        Self::Config(e.to_string())
    }
}

impl CoadaptError {
    /// The I/O error underneath, if any (a full disk is told apart by its kind).
    pub fn io_kind(&self) -> Option<std::io::ErrorKind> {
        match self {
            Self::Io(e) | Self::Snapshot(SnapshotError::Io(e)) => Some(e.kind()),
            Self::Checkpoint(coadapt_nn::NnError::Write { cause, .. } | coadapt_nn::NnError::Read { cause, .. }) => Some(cause.kind()),
            _ => None,
        }
    }
}

impl coadapt_fleet::supervise::exit::ExitCode for CoadaptError {
    fn exit_code(&self) -> Option<u8> {
        use coadapt_fleet::supervise::exit::{CONFIG, DISK, is_disk_full};
        match self {
            Self::Config(_) => Some(CONFIG),
            e if e.io_kind().is_some_and(is_disk_full) => Some(DISK),
            _ => None,
        }
    }
}
