//! What a training loop needs of an RL algorithm.

use std::path::Path;

use coadapt_core::Batch;
use coadapt_nn::NnError;
use serde::{Deserialize, Serialize};

use crate::{Ddpg, Sac};

/// The algorithms `coadapt train` offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Algo {
    Sac,
    Ddpg,
}

impl std::fmt::Display for Algo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Algo::Sac => "sac",
            Algo::Ddpg => "ddpg",
        })
    }
}

/// An off-policy agent: acts, learns from replayed batches, saves its networks.
pub trait Agent: Send {
    /// Fills `action` for `obs`: exploratory when `explore`, else the deterministic action.
    fn act(&mut self, obs: &[f32], explore: bool, action: &mut [f32]);
    /// Called at each episode start (restarts exploration noise).
    fn begin_episode(&mut self) {}
    /// One gradient step; returns (critic loss, policy loss).
    fn update(&mut self, batch: &Batch) -> (f32, f32);
    fn batch_size(&self) -> usize;
    fn save(&self, path: &Path) -> Result<(), NnError>;
    fn load(&mut self, path: &Path) -> Result<(), NnError>;
}

impl Agent for Sac {
    fn act(&mut self, obs: &[f32], explore: bool, action: &mut [f32]) {
        Sac::act(self, obs, !explore, action)
    }
    fn update(&mut self, batch: &Batch) -> (f32, f32) {
        let l = Sac::update(self, batch);
        (0.5 * (l.q1 + l.q2), l.policy)
    }
    fn batch_size(&self) -> usize {
        self.cfg.batch_size
    }
    fn save(&self, path: &Path) -> Result<(), NnError> {
        Sac::save(self, path)
    }
    fn load(&mut self, path: &Path) -> Result<(), NnError> {
        Sac::load(self, path)
    }
}

impl Agent for Ddpg {
    fn act(&mut self, obs: &[f32], explore: bool, action: &mut [f32]) {
        Ddpg::act(self, obs, !explore, action)
    }
    fn begin_episode(&mut self) {
        self.reset_noise()
    }
    fn update(&mut self, batch: &Batch) -> (f32, f32) {
        let l = Ddpg::update(self, batch);
        (l.critic, l.actor)
    }
    fn batch_size(&self) -> usize {
        self.cfg.batch_size
    }
    fn save(&self, path: &Path) -> Result<(), NnError> {
        Ddpg::save(self, path)
    }
    fn load(&mut self, path: &Path) -> Result<(), NnError> {
        Ddpg::load(self, path)
    }
}
