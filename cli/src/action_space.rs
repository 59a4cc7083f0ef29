//! `coadapt action-space`: its flags, over [`coadapt_coadaptation::action_space`].

use std::path::PathBuf;

use clap::Args;
use coadapt_coadaptation::action_space::{ActionSpaceOptions, run as learn};
use coadapt_learner::action_space::ActionSpaceConfig;

use crate::progress::shutdown_on_ctrl_c;

/// Learn a latent design-dependent action space from a co-adaptation's experience (thesis 6.2).
///
/// Trains an encoder e(a, s, xi) = z and a decoder d(z, s, xi) = a~ on the population replay of
/// RUN_DIR's newest snapshot (every design's experience), with Eq. 6.1's loss: the distance
/// between an action and its reconstruction, weighted by max(Q(s, a, xi), 0) under the run's
/// population critic. Writes OUT/action_space.safetensors (for `coadapt train
/// --latent-exploration`), OUT/loss.csv, OUT/latent_plane.svg (Fig. 6.1: the latent plane at a
/// start state, coloured by Q of each decoded action), OUT/decoded_grid.svg (Fig. 6.2: a latent grid decoded
/// for the run's shortest- and longest-legged designs, in action dimensions 2 and 4) and
/// OUT/summary.json, which it also prints.
#[derive(Debug, Args)]
pub struct ActionSpaceArgs {
    /// The co-adaptation's run directory (it needs a snapshot: `snapshots/`).
    #[arg(value_name = "RUN_DIR")]
    pub run: PathBuf,
    /// Where the files go (default RUN_DIR/action-space).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Dimensions of the latent code (the figures need 2).
    #[arg(long, default_value_t = 2)]
    pub latent_dim: usize,
    /// Hidden layers of the encoder and the decoder.
    #[arg(long, value_delimiter = ',', default_value = "64,64")]
    pub hidden: Vec<usize>,
    /// Adam updates.
    #[arg(long, default_value_t = 20_000)]
    pub updates: usize,
    /// Transitions per update.
    #[arg(long, default_value_t = 256)]
    pub batch_size: usize,
    /// Adam's step size.
    #[arg(long, default_value_t = 1e-3)]
    pub learning_rate: f32,
    /// Seed of the initial weights and the batches.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs `coadapt action-space`.
pub fn run(a: ActionSpaceArgs) -> anyhow::Result<()> {
    let cfg = ActionSpaceConfig { latent_dim: a.latent_dim, hidden: a.hidden, learning_rate: a.learning_rate, batch_size: a.batch_size };
    let opts = ActionSpaceOptions { run: a.run, out: a.out, cfg, updates: a.updates, seed: a.seed };
    let summary = learn(&opts, &shutdown_on_ctrl_c())?;
    coadapt_log::print_stdout_line(&summary.to_string());
    Ok(())
}
