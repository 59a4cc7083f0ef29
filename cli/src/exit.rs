//! Exit codes that tell a supervisor whether starting a process again can help. Most failures
//! are worth a restart (a crash, a lost connection); a full disk or a bad config fails the same
//! way every time, and restarting only hides the cause under ten copies of it. Those exit with
//! their `sysexits.h` code, and the supervisor (`launch`) stops the fleet and says why.

use coadapt_bench::BenchError;
use coadapt_latent::app::LatentError;
use coadapt_learner::coadapt::CoadaptError;
use coadapt_policy_search::app::SearchError;

use coadapt_fleet::SetupError;
use coadapt_fleet::supervise::SuperviseError;
use coadapt_fleet::supervise::exit::ExitCode;
pub use coadapt_fleet::supervise::exit::{CONFIG, DISK, not_transient};

/// The exit code of a process that failed with `e`: [`DISK`], [`CONFIG`], or 1 (worth a
/// restart). Each library's error says which of its failures a restart cannot mend
/// ([`ExitCode`]); the first such cause in the chain decides.
pub fn code_of(e: &anyhow::Error) -> u8 {
    for cause in e.chain() {
        let code = cause
            .downcast_ref::<SuperviseError>()
            .and_then(ExitCode::exit_code)
            .or_else(|| cause.downcast_ref::<SetupError>().and_then(ExitCode::exit_code))
            .or_else(|| cause.downcast_ref::<CoadaptError>().and_then(ExitCode::exit_code))
            .or_else(|| cause.downcast_ref::<coadapt_coadaptation::Error>().and_then(coadapt_coadaptation::Error::exit_code))
            .or_else(|| cause.downcast_ref::<LatentError>().and_then(ExitCode::exit_code))
            .or_else(|| cause.downcast_ref::<SearchError>().and_then(ExitCode::exit_code))
            .or_else(|| cause.downcast_ref::<BenchError>().and_then(ExitCode::exit_code))
            .or_else(|| cause.downcast_ref::<std::io::Error>().and_then(ExitCode::exit_code));
        if let Some(code) = code {
            return code;
        }
    }
    1
}

#[cfg(test)]
mod tests {
    use std::io::ErrorKind;

    use super::*;

    #[test]
    fn a_full_disk_anywhere_in_the_chain_is_told_apart() {
        let full = std::io::Error::new(ErrorKind::StorageFull, "writing x/arrays.bin: No space left on device (os error 28)");
        assert_eq!(code_of(&anyhow::Error::new(full).context("snapshot")), DISK);
        let full = std::io::Error::from_raw_os_error(28);
        assert_eq!(code_of(&anyhow::Error::new(CoadaptError::Io(full)).context("learner")), DISK);
        assert_eq!(code_of(&anyhow::Error::new(CoadaptError::Config("schedule.x".into()))), CONFIG);
        let full = LatentError::Io { what: "writing episodes.csv".into(), error: std::io::Error::from_raw_os_error(28) };
        assert_eq!(code_of(&anyhow::Error::new(full)), DISK);
        assert_eq!(code_of(&anyhow::Error::new(SearchError::Config("method: \"sgd\"".into()))), CONFIG);
        assert_eq!(code_of(&anyhow::Error::new(BenchError::Config("--repetitions must be at least 1".into()))), CONFIG);
        let full = BenchError::Io { what: "writing under target/bench-snapshot/n1".into(), error: std::io::Error::from_raw_os_error(28) };
        assert_eq!(code_of(&anyhow::Error::new(full)), DISK);
        let setup = BenchError::Setup(SetupError::Config("tls".into()));
        assert_eq!(code_of(&anyhow::Error::new(setup)), CONFIG);
        assert_eq!(code_of(&anyhow::anyhow!("connection refused")), 1);
        // Through the co-adaptation's error, with context around it.
        let full = coadapt_coadaptation::Error::Run(CoadaptError::Io(std::io::Error::from_raw_os_error(28))).context("learner");
        assert_eq!(code_of(&anyhow::Error::new(full)), DISK);
        assert_eq!(code_of(&anyhow::Error::new(coadapt_coadaptation::Error::Config("actors: 0".into()))), CONFIG);
        assert_eq!(code_of(&anyhow::Error::new(std::io::Error::from(ErrorKind::ConnectionReset))), 1);
        assert!(not_transient(Some(73)).is_some() && not_transient(Some(1)).is_none() && not_transient(None).is_none());
    }
}
