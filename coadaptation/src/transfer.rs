//! Transfer between worlds (thesis section 6.1): a run starts with the population networks of
//! another run, one on the same robot in another world (friction, actuators, payload) or on
//! another simulator of the same robot. The source must have this run's state, action and
//! design dimensions and network sizes; the refusal names which differ.
//!
//! The source's dimensions are read from its files, so a source served over dm_env_rpc needs no
//! connection: the policy network's input is the state and the design, its output two numbers
//! per action, and `designs.csv` gives the design's length.

use std::path::{Path, PathBuf};

use coadapt_core::EnvSpec;
use coadapt_learner::coadapt::Transfer;
use coadapt_learner::{run_dir, snapshot};
use serde::{Deserialize, Serialize};

use crate::AppError;
use crate::error::Context;

/// `[init-population]`: the population networks a fresh run starts with.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct InitPopulation {
    /// The source run's directory: the run starts with its newest population networks
    /// (`checkpoints/population.safetensors`, written at the end of each design: policy, both
    /// critics, both targets). Empty: networks start at random.
    pub from: String,
    /// Also start with the source's population replay (from its newest snapshot; the capacity
    /// must be this run's). Off by default: the thesis copies the networks only.
    pub replay: bool,
}

impl InitPopulation {
    /// Whether the run starts from scratch.
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }
}

/// A source run, checked against this run.
#[derive(Clone, Debug, PartialEq)]
pub struct Source {
    pub dir: PathBuf,
    /// Its newest population checkpoint.
    pub networks: PathBuf,
    pub state_dim: usize,
    pub action_dim: usize,
    pub design_dim: usize,
}

fn config(why: String) -> AppError {
    AppError::Config(format!("init-population.from: {why}"))
}

/// The source `init` names, checked to have `spec`'s dimensions and a policy of `hidden` layers
/// (`None`: no transfer).
pub fn source(init: &InitPopulation, spec: &EnvSpec, hidden: &[usize]) -> crate::Result<Option<Source>> {
    if init.from.is_empty() {
        if init.replay {
            return Err(AppError::Config("init-population.replay: needs init-population.from (the run to take it from)".into()));
        }
        return Ok(None);
    }
    let dir = PathBuf::from(&init.from);
    let networks = dir.join("checkpoints").join("population.safetensors");
    if !networks.is_file() {
        return Err(config(format!(
            "{} has no checkpoints/population.safetensors (a run directory that finished at least one design)",
            dir.display()
        )));
    }
    let nets = coadapt_nn::load_networks(&networks).map_err(|e| config(e.to_string()))?;
    let policy =
        nets.iter().find(|n| n.name == "policy").ok_or_else(|| config(format!("{} has no `policy` network", networks.display())))?;
    let sizes = policy.mlp.sizes();
    let design_dim = design_dim(&dir)?;
    let (input, output) = (sizes[0], sizes[sizes.len() - 1]);
    let Some(state_dim) = input.checked_sub(design_dim) else {
        return Err(config(format!("{}: the policy takes {input} inputs, fewer than the {design_dim} design values", networks.display())));
    };
    let src = Source { dir: dir.clone(), networks, state_dim, action_dim: output / 2, design_dim };
    let ours = [("state", spec.state_dim), ("action", spec.act_dim()), ("design", spec.design.dim())];
    let theirs = [src.state_dim, src.action_dim, src.design_dim];
    for ((what, n), m) in ours.into_iter().zip(theirs) {
        if n != m {
            return Err(config(format!(
                "{}'s robot has {m} {what} dimensions, this run's ({}) has {n}: the networks cannot carry over",
                dir.display(),
                spec.name
            )));
        }
    }
    let src_hidden = &sizes[1..sizes.len() - 1];
    if src_hidden != hidden {
        return Err(config(format!(
            "{}'s networks have hidden layers {src_hidden:?}, this run's learner.sac.hidden is {hidden:?}",
            dir.display()
        )));
    }
    Ok(Some(src))
}

/// The design's length in a run directory's `designs.csv` (its first row).
fn design_dim(dir: &Path) -> crate::Result<usize> {
    let path = dir.join("designs.csv");
    let len = std::fs::metadata(&path).map_err(|e| config(format!("{}: {e}", path.display())))?.len();
    let rows = run_dir::read_designs(&path, len).map_err(|e| config(e.to_string()))?;
    let first = rows.first().ok_or_else(|| config(format!("{} has no design yet", path.display())))?;
    Ok(first.design.len())
}

/// What the learner starts with: the source's networks, and its newest snapshot when `replay`.
pub fn transfer(src: &Source, replay: bool) -> crate::Result<Transfer> {
    let replay = if replay {
        let root = crate::resume::snapshot_root(&src.dir);
        let (from, _, state, _) = snapshot::load_latest(&root).context("init-population.replay: the source's snapshots")?;
        coadapt_log::logln!("learner: population replay from {}", from.display());
        Some(state)
    } else {
        None
    };
    Ok(Transfer { networks: src.networks.clone(), replay })
}
