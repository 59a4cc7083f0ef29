//! What a benchmark can fail with. A caller branches on three kinds: a bad option
//! ([`BenchError::Config`], exit 78), a file or process that could not be made
//! ([`BenchError::Io`], or a snapshot's own I/O error: a full disk under `bench snapshot --dir`
//! exits 73) and the fleet's setup ([`BenchError::Setup`]). The rest is the measured code's own error, shown as it reports
//! itself (`transparent`: the message and its causes read as before the move).

use coadapt_fleet::SetupError;
use coadapt_fleet::supervise::exit::{CONFIG, DISK, ExitCode, is_disk_full};
use coadapt_learner::snapshot::SnapshotError;

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// An option is wrong; the message names the flag.
    #[error("{0}")]
    Config(String),
    /// A file or process could not be made, written or read; `what` names it.
    #[error("{what}: {error}")]
    Io { what: String, error: std::io::Error },
    /// The fleet's links or TLS settings (`bench transport`, `bench design --tls`).
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// A figure could not be taken: a peer process fell silent, a self-check disagreed.
    #[error("{0}")]
    Failed(String),
    #[error(transparent)]
    Nn(#[from] coadapt_nn::NnError),
    #[error(transparent)]
    Space(#[from] coadapt_core::SpaceError),
    #[error(transparent)]
    Env(#[from] coadapt_core::EnvError),
    #[error(transparent)]
    UnknownEnv(#[from] coadapt_robots::UnknownEnv),
    #[error(transparent)]
    Sim(#[from] coadapt_robots::bench::BenchError),
    #[error(transparent)]
    Remote(#[from] coadapt_env_rpc::RemoteError),
    #[error(transparent)]
    Transport(#[from] coadapt_transport::TransportError),
    #[error(transparent)]
    Objective(#[from] coadapt_design_optimizer::ObjectiveError),
    #[error(transparent)]
    Search(#[from] coadapt_design_optimizer::SearchError),
    #[error(transparent)]
    Tls(#[from] coadapt_auth::TlsError),
    #[error(transparent)]
    Connect(#[from] tonic::transport::Error),
    #[error(transparent)]
    Rpc(#[from] tonic::Status),
    #[error(transparent)]
    Replay(#[from] coadapt_core::ReplayError),
    #[error(transparent)]
    Snapshot(#[from] SnapshotError),
    #[error(transparent)]
    Rollout(#[from] coadapt_policy_search::RolloutError),
}

impl BenchError {
    /// `Io` naming `what`, for `map_err`.
    pub(crate) fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |error| Self::Io { what, error }
    }
}

impl ExitCode for BenchError {
    fn exit_code(&self) -> Option<u8> {
        match self {
            Self::Config(_) => Some(CONFIG),
            Self::Io { error, .. } if is_disk_full(error.kind()) => Some(DISK),
            Self::Snapshot(SnapshotError::Io(error)) if is_disk_full(error.kind()) => Some(DISK),
            Self::Setup(e) => e.exit_code(),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_option_and_a_full_disk_say_a_restart_cannot_mend_them() {
        let full = || std::io::Error::from_raw_os_error(28);
        assert_eq!(BenchError::Config("--repetitions must be at least 1".into()).exit_code(), Some(CONFIG));
        assert_eq!(BenchError::Io { what: "writing x.json".into(), error: full() }.exit_code(), Some(DISK));
        assert_eq!(BenchError::Snapshot(SnapshotError::Io(full())).exit_code(), Some(DISK));
        assert_eq!(BenchError::Setup(SetupError::Config("security.tls-cert".into())).exit_code(), Some(CONFIG));
        assert_eq!(BenchError::Failed("a peer did not answer".into()).exit_code(), None);
        let e = BenchError::Io { what: "writing x.json".into(), error: std::io::Error::from(std::io::ErrorKind::NotFound) };
        assert_eq!(e.exit_code(), None);
        assert!(e.to_string().starts_with("writing x.json: "));
    }
}
