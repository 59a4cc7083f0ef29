//! The acting half of Alg. 3, where the robot is: the frozen encoder and the stacked latent
//! state ([`FrameStack`]), one planning step ([`PlanScratch::plan`]), and [`LatentActor`], a
//! copy of the agent's encoder, actor, critic, model and reward model that a learner elsewhere updates
//! through a versioned weights topic ([`LatentAgent::acting_weights`] packs them,
//! [`LatentActor::set_weights`] unpacks them).
//!
//! Planning runs here rather than in the learner because it is per step: a robot with a
//! control period cannot wait for a round trip to another machine at every step, only at
//! every episode (for the new weights).
//!
//! [`LatentAgent::acting_weights`]: crate::LatentAgent::acting_weights

use coadapt_core::Rng64;
use coadapt_learner::{Exploration, ExplorationNoise};
use coadapt_nn::{Activations, Mlp, NnError};

use crate::{AgentConfig, CriticKind, Embedding, EmbeddingWork, Explore, LatentDynamics, Lbfgsb, Objective, PlanWork, Planner};

/// The frozen encoder and the stacked latent state of the running episode.
#[derive(Debug)]
pub struct FrameStack {
    emb: Embedding,
    enc: Vec<f32>,
    work: EmbeddingWork,
    z: Vec<f32>,
    code: Vec<f32>,
}

impl FrameStack {
    /// Codes of `enc` (the encoder's parameters of `emb`), `frames` of them stacked.
    pub fn new(emb: Embedding, enc: Vec<f32>, frames: usize) -> Self {
        let l = emb.cfg.latent;
        Self { emb, enc, work: EmbeddingWork::default(), z: vec![0.0; frames * l], code: vec![0.0; l] }
    }

    /// Values of one frame.
    pub fn image_len(&self) -> usize {
        self.emb.image_len()
    }

    /// The stacked state after a reset to `frame` (every slot its code).
    pub fn reset(&mut self, frame: &[f32]) -> &[f32] {
        let l = self.emb.cfg.latent;
        self.code.copy_from_slice(self.emb.encode(&self.enc, frame, 1, &mut self.work));
        for c in self.z.chunks_exact_mut(l) {
            c.copy_from_slice(&self.code);
        }
        &self.z
    }

    /// The stacked state after the newest `frame`.
    pub fn observe(&mut self, frame: &[f32]) -> &[f32] {
        let l = self.emb.cfg.latent;
        self.code.copy_from_slice(self.emb.encode(&self.enc, frame, 1, &mut self.work));
        let s = self.z.len();
        self.z.copy_within(l..s, 0);
        self.z[s - l..].copy_from_slice(&self.code);
        &self.z
    }

    /// The encoder's parameters.
    pub fn encoder(&self) -> &[f32] {
        &self.enc
    }

    /// The current stacked state.
    pub fn state(&self) -> &[f32] {
        &self.z
    }
}

/// The networks a plan is made through (borrowed; nothing is copied per step).
#[derive(Clone, Copy, Debug)]
pub struct PlanNets<'a> {
    pub actor: &'a Mlp,
    pub actor_params: &'a [f32],
    pub model: &'a LatentDynamics,
    pub model_params: &'a [f32],
    pub critic: &'a Mlp,
    pub critic_params: &'a [f32],
    pub reward: Option<(&'a Mlp, &'a [f32])>,
}

/// Planning's scratch, kept across steps: a warm planner allocates nothing.
#[derive(Debug, Default)]
pub struct PlanScratch {
    opt: Lbfgsb,
    actions: Vec<f32>,
    work: PlanWork,
    z: Vec<f32>,
    input: Vec<f32>,
    g: Vec<f32>,
    actor_act: Activations,
    model_act: Activations,
}

impl PlanScratch {
    /// Alg. 3's step at `z0`: the actor's own rollout through the model as the warm start of
    /// `a_t .. a_t+H`, then L-BFGS within `[-1, 1]` on the objective; the first action goes to
    /// `action`. Returns the objective after and before optimising.
    pub fn plan(&mut self, nets: &PlanNets<'_>, cfg: &AgentConfig, z0: &[f32], action: &mut [f32]) -> (f32, f32) {
        let (a, h, l) = (nets.model.act, cfg.horizon, nets.model.latent);
        let Self { opt, actions, work, z, input, g, actor_act, model_act } = self;
        actions.clear();
        z.clear();
        z.extend_from_slice(z0);
        for j in 0..=h {
            let out = nets.actor.forward(nets.actor_params, z, 1, actor_act);
            let start = actions.len();
            actions.extend(out.iter().map(|v| v.tanh()));
            if j < h {
                // The printed loop omits the first prediction z_t+1 = Psi(z_t, a_t); made here.
                input.clear();
                input.extend_from_slice(z);
                input.extend_from_slice(&actions[start..start + a]);
                let next = nets.model.net.forward(nets.model_params, input, 1, model_act);
                let s = z.len();
                z.copy_within(l..s, 0);
                z[s - l..].copy_from_slice(next);
            }
        }
        let mut planner = Planner::new(nets.model, nets.model_params, nets.critic, nets.critic_params, h)
            .with(cfg.objective, cfg.critic, nets.reward)
            .expect("callers pass a reward model exactly when the objective needs one")
            .reuse(std::mem::take(work));
        g.resize(actions.len(), 0.0);
        let before = planner.value_and_grad(z0, actions, g);
        let after = planner.plan(z0, actions, -1.0, 1.0, cfg.plan_iterations, opt);
        *work = planner.into_work();
        action.copy_from_slice(&actions[..a]);
        (after, before)
    }
}

/// Why a weights message does not fit a [`LatentActor`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ActingWeightsError {
    #[error(
        "acting weights: {got} values, this actor's networks need {expected} (encoder, actor, critic, model, reward model: same config?)"
    )]
    Len { expected: usize, got: usize },
    #[error("acting weights: value {index} is not finite")]
    NonFinite { index: usize },
}

/// The networks of Alg. 3 that act: built from the config alone, their parameters set from
/// the learner's packed weights.
#[derive(Debug)]
pub struct LatentActor {
    cfg: AgentConfig,
    frames: FrameStack,
    actor: Mlp,
    phi: Vec<f32>,
    critic: Mlp,
    theta: Vec<f32>,
    model: LatentDynamics,
    model_params: Vec<f32>,
    reward: Option<(Mlp, Vec<f32>)>,
    noise: ExplorationNoise,
    rng: Rng64,
    act_ws: Activations,
    scratch: PlanScratch,
    loaded: bool,
}

impl LatentActor {
    /// An actor of `act` actions seeing through the encoder of `emb` with `frames` stacked
    /// codes, the networks' shapes as a [`crate::LatentAgent`] of `cfg` builds them; its OU
    /// noise drawn from `seed`. It acts only once [`Self::set_weights`] has given it
    /// parameters (the frozen encoder's among them: an actor needs no embedding file).
    pub fn new(cfg: AgentConfig, emb: Embedding, frames: usize, act: usize, seed: u64) -> Result<Self, NnError> {
        let enc = vec![0.0; emb.encoder_params()];
        let state = frames * emb.cfg.latent;
        let model = LatentDynamics::new(emb.cfg.latent, frames, act, &cfg.model_hidden)?;
        let actor = coadapt_learner::networks::deterministic_policy(state, act, &cfg.ddpg.hidden)?;
        let critic = match cfg.critic {
            CriticKind::Q => coadapt_learner::networks::critic(state, act, &cfg.ddpg.hidden)?,
            CriticKind::V => Mlp::new(&[&[state][..], &cfg.ddpg.hidden, &[1]].concat())?,
        };
        let reward = match cfg.objective {
            Objective::RewardPlusQ => {
                let net = Mlp::new(&[&[state][..], &cfg.model_hidden, &[1]].concat())?;
                let p = net.zeros();
                Some((net, p))
            }
            _ => None,
        };
        Ok(Self {
            frames: FrameStack::new(emb, enc, frames),
            phi: actor.zeros(),
            theta: critic.zeros(),
            model_params: model.net.zeros(),
            actor,
            critic,
            model,
            reward,
            noise: ExplorationNoise::new(act),
            rng: coadapt_core::rng(seed, 13),
            act_ws: Activations::default(),
            scratch: PlanScratch::default(),
            loaded: false,
            cfg,
        })
    }

    /// Length of the packed weights: encoder, actor, critic, model, reward model (if any), in
    /// order.
    pub fn weights_len(&self) -> usize {
        self.frames.enc.len() + self.phi.len() + self.theta.len() + self.model_params.len() + self.reward.as_ref().map_or(0, |r| r.1.len())
    }

    /// Takes the learner's packed weights (see [`crate::LatentAgent::acting_weights`]); on
    /// an error the actor keeps the parameters it had.
    pub fn set_weights(&mut self, w: &[f32]) -> Result<(), ActingWeightsError> {
        let expected = self.weights_len();
        if w.len() != expected {
            return Err(ActingWeightsError::Len { expected, got: w.len() });
        }
        if let Some(index) = w.iter().position(|v| !v.is_finite()) {
            return Err(ActingWeightsError::NonFinite { index });
        }
        let mut rest = w;
        let mut take = |dst: &mut Vec<f32>| {
            let (head, tail) = rest.split_at(dst.len());
            dst.copy_from_slice(head);
            rest = tail;
        };
        take(&mut self.frames.enc);
        take(&mut self.phi);
        take(&mut self.theta);
        take(&mut self.model_params);
        if let Some((_, p)) = &mut self.reward {
            take(p);
        }
        self.loaded = true;
        Ok(())
    }

    /// Whether weights have been set.
    pub fn loaded(&self) -> bool {
        self.loaded
    }

    /// Values of one frame.
    pub fn image_len(&self) -> usize {
        self.frames.image_len()
    }

    /// The stacked state after a reset to `frame`; the OU process restarts.
    pub fn reset(&mut self, frame: &[f32]) -> &[f32] {
        self.noise.reset();
        self.frames.reset(frame)
    }

    /// The stacked state after the newest `frame`.
    pub fn observe(&mut self, frame: &[f32]) -> &[f32] {
        self.frames.observe(frame)
    }

    /// The action at the current state: the actor's (`explore` false), its plus OU noise, or
    /// planned (`cfg.explore`). For a planned one, the objective after and before optimising.
    pub fn act(&mut self, explore: bool, action: &mut [f32]) -> Option<(f32, f32)> {
        let z = self.frames.state();
        if explore && self.cfg.explore == Explore::Plan {
            let nets = PlanNets {
                actor: &self.actor,
                actor_params: &self.phi,
                model: &self.model,
                model_params: &self.model_params,
                critic: &self.critic,
                critic_params: &self.theta,
                reward: self.reward.as_ref().map(|(n, p)| (n, &p[..])),
            };
            return Some(self.scratch.plan(&nets, &self.cfg, z, action));
        }
        let raw = self.actor.forward(&self.phi, z, 1, &mut self.act_ws);
        for (a, r) in action.iter_mut().zip(raw) {
            *a = r.tanh();
        }
        if explore {
            // As the agent's DDPG: the Q critic's as configured, the value critic's always OU.
            let kind = if self.cfg.critic == CriticKind::V { Exploration::OrnsteinUhlenbeck } else { self.cfg.ddpg.exploration };
            self.noise.perturb(&mut self.rng, kind, self.cfg.ddpg.sigma, self.cfg.ddpg.theta, action);
        }
        None
    }
}
