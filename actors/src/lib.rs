//! The coadapt rollout actor: a policy copy that runs episodes on any [`Env`].
//!
//! # Layout
//! - [`Actor`]: holds an environment and a versioned copy of the policy's flat weights (as a
//!   transport delivers them), runs whole episodes and hands each transition to a sink.
//! - [`role`]: the actor role over the transport links: assignments in, experience out.
//!
//! The actor never learns: it acts with the newest weights it was given and reports the
//! weights version it acted with, so the learner can measure policy lag.

pub mod role;

use std::ops::ControlFlow;

use coadapt_core::{Env, EnvError, Rng64, Transition};
use coadapt_nn::{Activations, Mlp, squashed};
use rand::Rng;
use rand_distr::StandardNormal;

/// How the policy network's output becomes an action.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PolicyKind {
    /// SAC: output `[mean, log_std]`, action `tanh(mean + std eps)` (or `tanh(mean)`).
    SquashedGaussian,
    /// DDPG: output `f`, action `tanh(f)`; exploration noise is the caller's business.
    DeterministicTanh,
}

#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    #[error("weights have {got} values, the policy needs {expected}")]
    WeightsLen { expected: usize, got: usize },
    #[error("weights value {index} is not finite")]
    WeightsNonFinite { index: usize },
    #[error("policy input width {policy} does not match the observation width {env}")]
    Shape { policy: usize, env: usize },
    #[error(transparent)]
    Env(#[from] EnvError),
}

/// Weights that do not fit, or a robot that failed: a restart may mend it.
impl coadapt_fleet::supervise::exit::ExitCode for ActorError {}

/// Return and length of one episode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeStats {
    pub episode_return: f32,
    pub length: u64,
    /// Weights version the episode was acted with.
    pub weights_version: u64,
}

/// A rollout actor.
#[derive(Debug)]
pub struct Actor<E: Env> {
    env: E,
    policy: Mlp,
    kind: PolicyKind,
    params: Vec<f32>,
    version: u64,
    act: Activations,
    obs: Vec<f32>,
    action: Vec<f32>,
    eps: Vec<f32>,
    rng: Rng64,
}

impl<E: Env> Actor<E> {
    pub fn new(env: E, policy: Mlp, kind: PolicyKind, seed: u64) -> Result<Self, ActorError> {
        let spec = env.spec();
        if policy.n_in() != spec.obs_dim() {
            return Err(ActorError::Shape { policy: policy.n_in(), env: spec.obs_dim() });
        }
        let act_dim = spec.act_dim();
        Ok(Self {
            obs: vec![0.0; spec.obs_dim()],
            action: vec![0.0; act_dim],
            eps: vec![0.0; act_dim],
            params: policy.zeros(),
            act: policy.activations(1),
            env,
            policy,
            kind,
            version: 0,
            rng: coadapt_core::rng(seed, 3),
        })
    }

    pub fn env(&self) -> &E {
        &self.env
    }

    /// Installs weights `params` of `version`, refusing malformed ones (the old stay in force).
    pub fn set_weights(&mut self, version: u64, params: &[f32]) -> Result<(), ActorError> {
        if params.len() != self.params.len() {
            return Err(ActorError::WeightsLen { expected: self.params.len(), got: params.len() });
        }
        if let Some(index) = params.iter().position(|p| !p.is_finite()) {
            return Err(ActorError::WeightsNonFinite { index });
        }
        self.params.copy_from_slice(params);
        self.version = version;
        Ok(())
    }

    pub fn weights_version(&self) -> u64 {
        self.version
    }

    /// Restarts the exploration noise from `seed`, so an episode's actions depend on its own
    /// seed only, not on which actor ran it or what that actor ran before.
    pub fn reseed_noise(&mut self, seed: u64) {
        self.rng = coadapt_core::rng(seed, 3);
    }

    fn choose(&mut self, explore: bool) {
        let act_dim = self.action.len();
        let out = self.policy.forward(&self.params, &self.obs, 1, &mut self.act);
        match (self.kind, explore) {
            (PolicyKind::SquashedGaussian, true) => {
                for e in &mut self.eps {
                    *e = self.rng.sample(StandardNormal);
                }
                squashed::sample(out, &self.eps, act_dim, &mut self.action, &mut [0.0]);
            }
            (PolicyKind::SquashedGaussian, false) => squashed::mean_action(out, act_dim, &mut self.action),
            (PolicyKind::DeterministicTanh, _) => {
                for (a, o) in self.action.iter_mut().zip(out) {
                    *a = o.tanh();
                }
            }
        }
    }

    /// Runs one episode with body `design`, giving every transition to `sink`; the sink may
    /// stop the episode early with `ControlFlow::Break`.
    pub fn run_episode(
        &mut self,
        seed: u64,
        design: &[f32],
        explore: bool,
        sink: &mut dyn FnMut(&Transition<'_>) -> ControlFlow<()>,
    ) -> Result<EpisodeStats, ActorError> {
        let first = self.env.reset(seed, design)?;
        self.obs.copy_from_slice(first);
        let mut stats = EpisodeStats { episode_return: 0.0, length: 0, weights_version: self.version };
        loop {
            self.choose(explore);
            let step = self.env.step(&self.action)?;
            stats.episode_return += step.reward;
            stats.length += 1;
            let flow = sink(&Transition {
                obs: &self.obs,
                action: &self.action,
                reward: step.reward,
                next_obs: step.observation,
                terminated: step.terminated,
            });
            let done = step.terminated || step.truncated;
            self.obs.copy_from_slice(step.observation);
            if done || flow.is_break() {
                return Ok(stats);
            }
        }
    }
}
