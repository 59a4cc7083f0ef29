//! Exit codes that tell a supervisor whether starting a process again can help. Most failures
//! are worth a restart (a crash, a lost connection); a full disk or a bad config fails the same
//! way every time, and restarting only hides the cause under ten copies of it. Those exit with
//! their `sysexits.h` code, and the supervisor (`launch`) stops the fleet and says why.

use coadapt_fleet::SetupError;
use coadapt_fleet::app::AppError;
use coadapt_fleet::supervise::exit::ExitCode;
pub use coadapt_fleet::supervise::exit::{CONFIG, DISK, not_transient};
use coadapt_learner::train::TrainError;

/// The exit code of a process that failed with `e`: [`DISK`], [`CONFIG`], or 1 (worth a
/// restart). Every application (co-adaptation, latent, search, bench) fails with the fleet's
/// [`AppError`], which kept the code its cause asked for; the few library calls this binary
/// makes itself (a listen address, a training run, a file) are asked directly. The first cause
/// in the chain that knows a code decides.
pub fn code_of(e: &anyhow::Error) -> u8 {
    for cause in e.chain() {
        let code = if let Some(e) = cause.downcast_ref::<AppError>() {
            e.exit_code()
        } else if let Some(e) = cause.downcast_ref::<SetupError>() {
            e.exit_code()
        } else if let Some(e) = cause.downcast_ref::<TrainError>() {
            e.exit_code()
        } else {
            cause.downcast_ref::<std::io::Error>().and_then(ExitCode::exit_code)
        };
        if let Some(code) = code {
            return code;
        }
    }
    1
}

#[cfg(test)]
mod tests {
    use std::io::ErrorKind;

    use coadapt_fleet::app::Context;
    use coadapt_learner::coadapt::CoadaptError;

    use super::*;

    fn full() -> std::io::Error {
        std::io::Error::from_raw_os_error(28)
    }

    #[test]
    fn a_full_disk_or_a_bad_setting_anywhere_in_the_chain_is_told_apart() {
        // Raw, under anyhow's context.
        let e = std::io::Error::new(ErrorKind::StorageFull, "writing x/arrays.bin: No space left on device (os error 28)");
        assert_eq!(code_of(&anyhow::Error::new(e).context("snapshot")), DISK);
        assert_eq!(code_of(&anyhow::Error::new(SetupError::Config("tls".into())).context("serve")), CONFIG);
        // An application's error: its own kinds, and a library's code kept through context.
        let e = AppError::io("writing episodes.csv")(full()).context("run 0");
        assert_eq!(code_of(&anyhow::Error::new(e)), DISK);
        assert_eq!(code_of(&anyhow::Error::new(AppError::Config("method: \"sgd\"".into()))), CONFIG);
        let run: Result<(), CoadaptError> = Err(CoadaptError::Io(full()));
        assert_eq!(code_of(&anyhow::Error::new(run.context("learner").unwrap_err())), DISK);
        let run: Result<(), CoadaptError> = Err(CoadaptError::Config("schedule.x".into()));
        assert_eq!(code_of(&anyhow::Error::new(run.context("learner").unwrap_err())), CONFIG);
        let setup: Result<(), SetupError> = Err(SetupError::Config("security.tls-cert".into()));
        assert_eq!(code_of(&anyhow::Error::new(setup.context("bench design").unwrap_err())), CONFIG);
        // What a restart may mend.
        assert_eq!(code_of(&anyhow::anyhow!("connection refused")), 1);
        assert_eq!(code_of(&anyhow::Error::new(std::io::Error::from(ErrorKind::ConnectionReset))), 1);
        assert_eq!(code_of(&anyhow::Error::new(AppError::Failed("a peer did not answer".into()))), 1);
        assert!(not_transient(Some(73)).is_some() && not_transient(Some(1)).is_none() && not_transient(None).is_none());
    }
}
