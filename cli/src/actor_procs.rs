//! How an actor process joins its learner's fleet: the `--transport`, `--fleet` and
//! `--connect` flags over the config's `[fleet]`.

use coadapt_fleet::FleetConfig;
use coadapt_fleet::app::AppError;

/// How an actor process joins its learner's fleet (over the config's `[fleet]`).
#[derive(Debug, clap::Args)]
pub struct JoinArgs {
    /// Override fleet.transport: shm or grpc.
    #[arg(long, value_enum)]
    pub transport: Option<coadapt_fleet::TransportKind>,
    /// Override fleet.name: the shared-memory fleet to join.
    #[arg(long)]
    pub fleet: Option<String>,
    /// Override fleet.connect: the learner's gRPC address.
    #[arg(long)]
    pub connect: Option<String>,
}

impl JoinArgs {
    /// `fleet` with the overrides; an actor process cannot join threads of another process (a
    /// setting: exit 78).
    pub fn apply(&self, fleet: &mut FleetConfig) -> Result<(), AppError> {
        if let Some(t) = self.transport {
            fleet.transport = t;
        }
        if let Some(f) = &self.fleet {
            fleet.name = f.clone();
        }
        if let Some(c) = &self.connect {
            fleet.connect = c.clone();
        }
        if fleet.transport == coadapt_fleet::TransportKind::InProcess {
            return Err(AppError::Config("fleet.transport: an actor process talks shm or grpc (--transport)".into()));
        }
        Ok(())
    }
}
