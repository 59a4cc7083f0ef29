//! Learner hyper-parameters. Defaults are the reference settings (DESIGN.md section 2). And
//! [`ConfigError`], a run's setting that cannot work.

use coadapt_nn::{HiddenInit, Precision};
use serde::{Deserialize, Serialize};

/// A setting of a co-adaptation run (`[schedule]`, `[flow]`, `[snapshot]`) that cannot work;
/// the message names its key as a config file spells it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// A duration that is not a positive number of seconds; `key` is e.g.
    /// `flow.assignment-lease-secs`.
    #[error("{key}: {value} is not a positive number of seconds")]
    NotPositiveSeconds { key: &'static str, value: f64 },
    /// `snapshot.keep` below 2.
    #[error("snapshot.keep: {0} is fewer than 2 (a damaged newest snapshot needs one to fall back to)")]
    TooFewSnapshots(usize),
    /// `snapshot.max-share` outside (0, 1].
    #[error("snapshot.max-share: {0} is not a share of the run's time in (0, 1] (1: no bound)")]
    SnapshotShare(f64),
    /// `learner.population-critics` below 2.
    #[error("learner.population-critics: {0} is fewer than 2 (the twin critics are SAC's; more are ensemble heads)")]
    TooFewCritics(usize),
    /// Another setting that cannot work; the message names its key (e.g.
    /// `learner.conservative.step`).
    #[error("{0}")]
    Invalid(String),
}

/// A setting fails the same way every time.
impl coadapt_fleet::supervise::exit::ExitCode for ConfigError {
    fn exit_code(&self) -> Option<u8> {
        Some(coadapt_fleet::supervise::exit::CONFIG)
    }
}

/// Soft Actor-Critic settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct SacConfig {
    /// Hidden layer widths of the policy and of each critic.
    pub hidden: Vec<usize>,
    /// Discount factor gamma.
    pub gamma: f32,
    /// Polyak rate of the target critics, applied at every update.
    pub tau: f32,
    /// Adam learning rate of the policy.
    pub policy_lr: f32,
    /// Adam learning rate of each critic.
    pub critic_lr: f32,
    /// Transitions per gradient step.
    pub batch_size: usize,
    /// Rewards are multiplied by this before the Bellman target.
    pub reward_scale: f32,
    /// Entropy coefficient alpha (the initial value when `auto-alpha` is on).
    pub alpha: f32,
    /// Tune alpha so the policy's entropy tracks `target-entropy`.
    pub auto_alpha: bool,
    /// Target entropy for `auto-alpha`; default minus the action dimension.
    pub target_entropy: Option<f32>,
    /// Adam learning rate of log(alpha).
    pub alpha_lr: f32,
    /// Element-wise gradient clamp; 0 disables it.
    pub grad_clamp: f32,
    /// How the hidden layers start: `rlkit` (the reference's networks: weights uniform in
    /// +-1/sqrt(layer output width), biases 0.1) or `pytorch` (nn.Linear's default).
    pub hidden_init: HiddenInit,
    /// Uniform init range of the policy's last layer.
    pub policy_final_init: f32,
    /// Uniform init range of the critics' last layer.
    pub critic_final_init: f32,
    /// Arithmetic of the networks' matrix products: `f32`, or `bf16` (bfloat16 operands with
    /// f32 accumulation, on CPUs with AMX or AVX-512 BF16, f32 elsewhere; parameters,
    /// optimiser states and element-wise work stay f32). Experimental (issue 34): f32 until
    /// the learning checks pass.
    pub precision: Precision,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            hidden: vec![200, 200, 200],
            gamma: 0.99,
            tau: 0.005,
            policy_lr: 3e-4,
            critic_lr: 3e-4,
            batch_size: 256,
            reward_scale: 1.0,
            alpha: 0.01,
            auto_alpha: false,
            target_entropy: None,
            alpha_lr: 3e-4,
            grad_clamp: 1.0,
            hidden_init: HiddenInit::Rlkit,
            policy_final_init: 1e-3,
            critic_final_init: 3e-3,
            precision: Precision::F32,
        }
    }
}

/// Which exploration noise DDPG adds to its deterministic action.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Exploration {
    /// Ornstein-Uhlenbeck process, reset at each episode.
    OrnsteinUhlenbeck,
    /// Independent Gaussian noise of standard deviation `sigma`.
    Gaussian,
}

/// DDPG settings (thesis chapter 4; step sizes as Stable-Baselines3's DDPG).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct DdpgConfig {
    /// Hidden layer widths of the actor and the critic.
    pub hidden: Vec<usize>,
    pub gamma: f32,
    /// Polyak rate of both targets, applied at every update.
    pub tau: f32,
    pub actor_lr: f32,
    pub critic_lr: f32,
    pub batch_size: usize,
    pub reward_scale: f32,
    /// Element-wise gradient clamp; 0 disables it.
    pub grad_clamp: f32,
    pub exploration: Exploration,
    /// Noise scale: the OU sigma, or the Gaussian standard deviation.
    pub sigma: f32,
    /// OU mean-reversion rate theta.
    pub theta: f32,
    /// Uniform init range of both networks' last layers.
    pub final_init: f32,
}

impl Default for DdpgConfig {
    fn default() -> Self {
        Self {
            hidden: vec![400, 300],
            gamma: 0.99,
            tau: 0.005,
            actor_lr: 1e-3,
            critic_lr: 1e-3,
            batch_size: 256,
            reward_scale: 1.0,
            grad_clamp: 1.0,
            exploration: Exploration::OrnsteinUhlenbeck,
            sigma: 0.5,
            theta: 0.15,
            final_init: 3e-3,
        }
    }
}
