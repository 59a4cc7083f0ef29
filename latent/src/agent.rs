//! Alg. 3: DDPG on the latent state of a frozen embedding, with the Q critic (Eq. 4.6, 4.7) or
//! the value critic (Eq. 4.9, 4.10), exploring either with Ornstein-Uhlenbeck noise (the
//! baseline) or by planning through the learned model.
//!
//! Per step: the newest frame is encoded and joins the stacked state `z_t`; the action is the
//! actor's (evaluation), the actor's plus OU noise, or the first of `H + 1` actions optimised
//! for the objective (f_Q Eq. 4.11, f_{r+Q} Eq. 4.12 or last-Q) from the actor's own rollout
//! through the model (the printed loop omits the first prediction `z_t+1 = Psi(z_t, a_t)`; it is
//! made here). At the end of an episode, `updates-per-episode` times on a fresh batch: the
//! model, the reward model (f_{r+Q} only), then DDPG (actor, critic, targets).
//!
//! The latent reward model `r(z)` (the thesis does not say how it is learned): an MLP of the
//! model's hidden sizes regressing each stored reward on the state it led to,
//! `|r(z_t+1) - r_t|^2`, Adam at the model's rate, as Eq. 4.12 credits `r(z_t+j)` for arriving.

use coadapt_core::{Batch, ReplayBuffer, Transition};
use coadapt_learner::config::DdpgConfig;
use coadapt_learner::ddpg::Ddpg;
use coadapt_nn::{Activations, Adam, AdamConfig, Mlp, NnError};
use rand::Rng;

use crate::{CriticKind, Embedding, FrameStack, LatentDynamics, Objective, PlanNets, PlanScratch, ValueDdpg, ValueLosses};

/// How an agent explores while it trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Explore {
    /// The baseline: the actor's action plus OU noise (sigma 0.5, theta 0.15 in the thesis).
    #[serde(rename = "ou")]
    OrnsteinUhlenbeck,
    /// Trajectory optimisation through the model: the first of `H + 1` planned actions.
    Plan,
}

/// Alg. 3's settings (TOML, kebab-case; every key has a default).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct AgentConfig {
    /// `plan` (trajectory optimisation through the model) or `ou` (the actor plus OU noise).
    pub explore: Explore,
    /// The Q critic or the value critic.
    pub critic: CriticKind,
    /// What planning maximises.
    pub objective: Objective,
    /// H: the plan covers actions a_t .. a_t+H.
    pub horizon: usize,
    /// L-BFGS iterations per step (20 in the thesis).
    pub plan_iterations: usize,
    /// Hidden widths of the latent dynamics psi_bar (and of the reward model).
    pub model_hidden: Vec<usize>,
    /// Adam's rate for the dynamics and reward models.
    pub model_lr: f32,
    /// Model and DDPG updates at each episode's end (1000 in Fig. 4.5).
    pub updates_per_episode: usize,
    pub replay_capacity: usize,
    /// DDPG's networks and optimisers (`sigma`, `theta`: the OU noise).
    pub ddpg: DdpgConfig,
}

impl Default for AgentConfig {
    fn default() -> Self {
        let ddpg = DdpgConfig { sigma: 0.5, theta: 0.15, ..DdpgConfig::default() };
        Self {
            explore: Explore::Plan,
            critic: CriticKind::Q,
            objective: Objective::SumQ,
            horizon: 10,
            plan_iterations: 20,
            model_hidden: vec![400, 400],
            model_lr: 1e-3,
            updates_per_episode: 1000,
            replay_capacity: 1_000_000,
            ddpg,
        }
    }
}

/// The critic and its DDPG.
#[derive(Debug)]
#[allow(clippy::large_enum_variant)] // one per agent, never moved in a loop
pub enum Critic {
    Q(Ddpg),
    V(ValueDdpg),
}

/// The latent reward model `r(z)` for f_{r+Q}, and its optimiser.
#[derive(Debug)]
pub struct RewardModel {
    pub net: Mlp,
    pub params: Vec<f32>,
    adam: Adam,
    grad: Vec<f32>,
    act: Activations,
    dy: Vec<f32>,
}

/// A DDPG agent on the latent state, with its model and its replays.
#[derive(Debug)]
pub struct LatentAgent {
    pub cfg: AgentConfig,
    /// The frozen encoder and the running episode's stacked state.
    frames: FrameStack,
    pub critic: Critic,
    pub reward: Option<RewardModel>,
    pub model: LatentDynamics,
    pub model_params: Vec<f32>,
    model_adam: Adam,
    model_act: Activations,
    model_dy: Vec<f32>,
    model_grad: Vec<f32>,
    /// (z_t, a_t, r, z_t+1) for DDPG; the model learns from the same rows (its target is the
    /// newest code of z_t+1).
    pub replay: ReplayBuffer,
    batch: Batch,
    scratch: PlanScratch,
}

impl LatentAgent {
    /// An agent for `act` actions over the frozen encoder `enc` of `emb`, stacking `frames`
    /// codes.
    pub fn new<R: Rng + ?Sized>(
        cfg: AgentConfig,
        emb: Embedding,
        enc: Vec<f32>,
        frames: usize,
        act: usize,
        seed: u64,
        rng: &mut R,
    ) -> Result<Self, NnError> {
        let l = emb.cfg.latent;
        let model = LatentDynamics::new(l, frames, act, &cfg.model_hidden)?;
        let mut model_params = model.net.zeros();
        model.net.init(&mut model_params, 3e-3, rng);
        let critic = match cfg.critic {
            CriticKind::Q => Critic::Q(Ddpg::new(frames * l, act, cfg.ddpg.clone(), seed)?),
            CriticKind::V => Critic::V(ValueDdpg::new(frames * l, act, cfg.ddpg.clone(), seed)?),
        };
        let reward = if cfg.objective == Objective::RewardPlusQ {
            let mut sizes = vec![frames * l];
            sizes.extend_from_slice(&cfg.model_hidden);
            sizes.push(1);
            let net = Mlp::new(&sizes)?;
            let mut params = net.zeros();
            net.init(&mut params, 3e-3, rng);
            Some(RewardModel {
                adam: Adam::new(params.len(), AdamConfig { lr: cfg.model_lr, ..AdamConfig::default() }),
                grad: vec![0.0; params.len()],
                net,
                params,
                act: Activations::default(),
                dy: Vec::new(),
            })
        } else {
            None
        };
        let batch = Batch::new(cfg.ddpg.batch_size, frames * l, act);
        Ok(Self {
            model_adam: Adam::new(model_params.len(), AdamConfig { lr: cfg.model_lr, ..AdamConfig::default() }),
            model_grad: vec![0.0; model_params.len()],
            replay: ReplayBuffer::new(frames * l, act, cfg.replay_capacity),
            frames: FrameStack::new(emb, enc, frames),
            critic,
            reward,
            model,
            model_params,
            model_act: Activations::default(),
            model_dy: Vec::new(),
            batch,
            scratch: PlanScratch::default(),
            cfg,
        })
    }

    /// Values of one frame the agent encodes.
    pub fn image_len(&self) -> usize {
        self.frames.image_len()
    }

    /// The stacked state after a reset to `frame` (every slot its code).
    pub fn reset(&mut self, frame: &[f32]) -> &[f32] {
        match &mut self.critic {
            Critic::Q(d) => d.reset_noise(),
            Critic::V(d) => d.reset_noise(),
        }
        self.frames.reset(frame)
    }

    /// The stacked state after the newest `frame`.
    pub fn observe(&mut self, frame: &[f32]) -> &[f32] {
        self.frames.observe(frame)
    }

    /// The action at the current state: deterministic, OU-noisy, or planned (see [`Explore`]).
    /// For a planned one, returns f_Q of the plan and of the actor's own rollout it started from.
    pub fn act(&mut self, explore: bool, action: &mut [f32]) -> Option<(f32, f32)> {
        if explore && self.cfg.explore == Explore::Plan {
            return Some(self.plan(action));
        }
        match &mut self.critic {
            Critic::Q(d) => d.act(self.frames.state(), !explore, action),
            Critic::V(d) => d.act(self.frames.state(), !explore, action),
        }
        None
    }

    /// The actor's network and parameters.
    pub fn actor(&self) -> (&Mlp, &[f32]) {
        match &self.critic {
            Critic::Q(d) => (d.actor(), d.actor_params()),
            Critic::V(d) => (&d.actor, &d.p.phi),
        }
    }

    /// Warm start from the actor's rollout through the model, then L-BFGS on the objective.
    fn plan(&mut self, action: &mut [f32]) -> (f32, f32) {
        let (actor, actor_params, critic, critic_params) = match &self.critic {
            Critic::Q(d) => (d.actor(), d.actor_params(), d.critic(), d.critic_params()),
            Critic::V(d) => (&d.actor, &d.p.phi[..], &d.v, &d.p.v[..]),
        };
        let nets = PlanNets {
            actor,
            actor_params,
            model: &self.model,
            model_params: &self.model_params,
            critic,
            critic_params,
            reward: self.reward.as_ref().map(|r| (&r.net, &r.params[..])),
        };
        self.scratch.plan(&nets, &self.cfg, self.frames.state(), action)
    }

    /// The networks an actor elsewhere acts and plans with, packed into one buffer for the
    /// acting-weights topic: the frozen encoder (about a tenth of the values: an actor then
    /// needs no embedding file and can never see through another one), actor, critic (Q or
    /// V), model, reward model (f_{r+Q} only), each in its own parameter order
    /// ([`crate::LatentActor::set_weights`] unpacks them).
    pub fn acting_weights(&self, out: &mut Vec<f32>) {
        out.clear();
        out.extend_from_slice(self.frames.encoder());
        out.extend_from_slice(self.actor().1);
        match &self.critic {
            Critic::Q(d) => out.extend_from_slice(d.critic_params()),
            Critic::V(d) => out.extend_from_slice(&d.p.v),
        }
        out.extend_from_slice(&self.model_params);
        if let Some(r) = &self.reward {
            out.extend_from_slice(&r.params);
        }
    }

    /// Stores a step of the running episode (`next` is the stacked state after it).
    pub fn store(
        &mut self,
        z: &[f32],
        action: &[f32],
        reward: f32,
        next: &[f32],
        terminated: bool,
    ) -> Result<(), coadapt_core::ReplayError> {
        self.replay.push(&Transition { obs: z, action, reward, next_obs: next, terminated })
    }

    /// The end of an episode: the model (and reward model), then DDPG, `updates-per-episode`
    /// steps each. Returns the last model loss.
    pub fn train<R: Rng + ?Sized>(&mut self, rng: &mut R) -> f32 {
        if self.replay.len() < self.cfg.ddpg.batch_size {
            return f32::NAN;
        }
        let (s, a, l) = (self.model.state_len(), self.model.act, self.model.latent);
        let n = self.batch.rows;
        let (mut input, mut target) = (vec![0.0; n * (s + a)], vec![0.0; n * l]);
        let mut loss = f32::NAN;
        let Self { cfg, critic, reward, model, model_params, model_adam, model_act, model_dy, model_grad, replay, batch, .. } = self;
        // The value critic's losses borrow its networks while its parameters step.
        let (mut q, mut value) = match critic {
            Critic::V(d) => (None, Some((ValueLosses::new(&d.v, &d.actor, model, d.cfg.gamma), &mut d.p, &d.cfg))),
            Critic::Q(d) => (Some(d), None),
        };
        for _ in 0..cfg.updates_per_episode {
            if replay.sample(rng, batch).is_err() {
                break;
            }
            for i in 0..n {
                input[i * (s + a)..i * (s + a) + s].copy_from_slice(&batch.obs[i * s..(i + 1) * s]);
                input[i * (s + a) + s..(i + 1) * (s + a)].copy_from_slice(&batch.act[i * a..(i + 1) * a]);
                target[i * l..(i + 1) * l].copy_from_slice(&batch.next_obs[(i + 1) * s - l..(i + 1) * s]);
            }
            loss = model.loss_and_grad(model_params, &input, &target, n, model_grad, model_act, model_dy);
            model_adam.step(model_params, model_grad);
            if let Some(r) = reward.as_mut() {
                // |r(z_t+1) - r_t|^2 over the batch.
                let out = r.net.forward(&r.params, &batch.next_obs, n, &mut r.act);
                r.dy.clear();
                r.dy.extend(out.iter().zip(&batch.rew).map(|(p, t)| 2.0 * (p - t) / n as f32));
                r.net.backward(&r.params, &batch.next_obs, &mut r.act, 0..n, &r.dy, Some(&mut r.grad), None);
                r.adam.step(&mut r.params, &r.grad);
            }
            if let Some(d) = q.as_mut() {
                d.update(batch);
            }
            if let Some((losses, p, dcfg)) = value.as_mut() {
                p.update(dcfg, losses, model, model_params, batch);
            }
        }
        loss
    }

    /// Saves the agent's networks to one safetensors file (PyTorch `nn.Sequential` naming):
    /// `actor`, the critic (`critic` for Q, `value` for V), `model` (psi_bar) and, for
    /// f_{r+Q}, `reward`: a checkpoint to act, plan and evaluate with (the targets and optimiser
    /// states, needed only to resume training, are not saved).
    pub fn save(&self, path: &std::path::Path) -> Result<(), NnError> {
        let (actor, phi) = self.actor();
        let mut nets: Vec<(&str, &Mlp, &[f32])> = vec![("actor", actor, phi), ("model", &self.model.net, &self.model_params)];
        match &self.critic {
            Critic::Q(d) => nets.push(("critic", d.critic(), d.critic_params())),
            Critic::V(d) => nets.push(("value", &d.v, &d.p.v)),
        }
        if let Some(r) = &self.reward {
            nets.push(("reward", &r.net, &r.params));
        }
        coadapt_nn::save_networks(path, &nets)
    }

    /// The reward model's mean squared error on `n` rows sampled from the replay (NaN without
    /// one or before a batch fits).
    pub fn reward_loss<R: Rng + ?Sized>(&mut self, rng: &mut R) -> f32 {
        let Some(r) = self.reward.as_mut() else { return f32::NAN };
        if self.replay.sample(rng, &mut self.batch).is_err() {
            return f32::NAN;
        }
        let n = self.batch.rows;
        let out = r.net.forward(&r.params, &self.batch.next_obs, n, &mut r.act);
        out.iter().zip(&self.batch.rew).map(|(p, t)| (p - t) * (p - t)).sum::<f32>() / n as f32
    }
}
