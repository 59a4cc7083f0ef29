//! DDPG with the thesis's value critic (Eq. 4.9, 4.10): actor `mu(z) = tanh(f(z))`, critic
//! `V(z)`, their targets, Adam, and the OU exploration of the Q version.
//!
//! An update (Alg. 3's order): the actor's loss `-V(Psi(z, mu(z)))` and the critic's loss against
//! `r + gamma (1 - done) V'(Psi(z, mu'(z)))` at the same parameters, both through the frozen
//! model (see [`crate::ValueLosses`]), then Adam on each and the Polyak targets.

use coadapt_core::{Batch, Rng64};
use coadapt_learner::ExplorationNoise;
use coadapt_learner::config::{DdpgConfig, Exploration};
use coadapt_nn::{Activations, Adam, AdamConfig, Mlp, NnError, clamp_elementwise, polyak};

use crate::{LatentDynamics, ValueLosses};

/// The value critic's networks (shapes only; the parameters live in [`ValueParams`], so the
/// losses can borrow the networks while the parameters step).
#[derive(Clone, Debug)]
pub struct ValueDdpg {
    pub cfg: DdpgConfig,
    pub actor: Mlp,
    pub v: Mlp,
    pub p: ValueParams,
}

/// Parameters, targets, optimisers and the exploration state of a [`ValueDdpg`].
#[derive(Clone, Debug)]
pub struct ValueParams {
    pub phi: Vec<f32>,
    pub phi_bar: Vec<f32>,
    pub v: Vec<f32>,
    pub v_bar: Vec<f32>,
    actor_adam: Adam,
    v_adam: Adam,
    grad_phi: Vec<f32>,
    grad_v: Vec<f32>,
    rew: Vec<f32>,
    done: Vec<bool>,
    ou: ExplorationNoise,
    act: Activations,
    rng: Rng64,
}

impl ValueDdpg {
    /// Actor `[state] -> hidden -> act` and critic `[state] -> hidden -> 1`, initialised as the
    /// learner's DDPG (last layers uniform within `final-init`).
    pub fn new(state: usize, act: usize, cfg: DdpgConfig, seed: u64) -> Result<Self, NnError> {
        let mut sizes = vec![state];
        sizes.extend_from_slice(&cfg.hidden);
        let mut a_sizes = sizes.clone();
        a_sizes.push(act);
        sizes.push(1);
        let (actor, v) = (Mlp::new(&a_sizes)?, Mlp::new(&sizes)?);
        let mut rng = coadapt_core::rng(seed, 1);
        let mut phi = actor.zeros();
        actor.init(&mut phi, cfg.final_init, &mut rng);
        let mut vp = v.zeros();
        v.init(&mut vp, cfg.final_init, &mut rng);
        let p = ValueParams {
            phi_bar: phi.clone(),
            v_bar: vp.clone(),
            actor_adam: Adam::new(phi.len(), AdamConfig { lr: cfg.actor_lr, ..AdamConfig::default() }),
            v_adam: Adam::new(vp.len(), AdamConfig { lr: cfg.critic_lr, ..AdamConfig::default() }),
            grad_phi: vec![0.0; phi.len()],
            grad_v: vec![0.0; vp.len()],
            phi,
            v: vp,
            rew: Vec::new(),
            done: Vec::new(),
            ou: ExplorationNoise::new(act),
            act: Activations::default(),
            rng,
        };
        Ok(Self { cfg, actor, v, p })
    }

    /// Restarts the OU process (at each episode's start).
    pub fn reset_noise(&mut self) {
        self.p.ou.reset();
    }

    /// `mu(z)`, plus OU noise unless `deterministic`, clipped to `[-1, 1]`.
    pub fn act(&mut self, z: &[f32], deterministic: bool, action: &mut [f32]) {
        let raw = self.actor.forward(&self.p.phi, z, 1, &mut self.p.act);
        for (a, r) in action.iter_mut().zip(raw) {
            *a = r.tanh();
        }
        if deterministic {
            return;
        }
        // Always OU, whatever `cfg.exploration` says (the thesis's ch. 4 baseline).
        self.p.ou.perturb(&mut self.p.rng, Exploration::OrnsteinUhlenbeck, self.cfg.sigma, self.cfg.theta, action);
    }
}

impl ValueParams {
    /// One update on `b` through the frozen model: returns (critic loss, actor loss).
    pub fn update(
        &mut self,
        cfg: &DdpgConfig,
        losses: &mut ValueLosses<'_>,
        model: &LatentDynamics,
        model_params: &[f32],
        b: &Batch,
    ) -> (f32, f32) {
        let n = b.rows;
        debug_assert_eq!(b.obs.len(), n * model.state_len());
        self.rew.clear();
        self.rew.extend(b.rew.iter().map(|r| cfg.reward_scale * r));
        self.done.clear();
        self.done.extend(b.done.iter().map(|d| *d > 0.5));
        let actor_loss = losses.actor_loss(&self.phi, &self.v, model_params, &b.obs, n, &mut self.grad_phi);
        let critic_loss =
            losses.critic(&self.v, &self.v_bar, &self.phi_bar, model_params, &b.obs, &self.rew, &self.done, n, &mut self.grad_v);
        if cfg.grad_clamp > 0.0 {
            clamp_elementwise(&mut self.grad_phi, cfg.grad_clamp);
            clamp_elementwise(&mut self.grad_v, cfg.grad_clamp);
        }
        self.actor_adam.step(&mut self.phi, &self.grad_phi);
        self.v_adam.step(&mut self.v, &self.grad_v);
        polyak(&mut self.phi_bar, &self.phi, cfg.tau);
        polyak(&mut self.v_bar, &self.v, cfg.tau);
        (critic_loss, actor_loss)
    }
}
