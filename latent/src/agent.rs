//! Alg. 3 with the Q critic: DDPG on the latent state of a frozen embedding, exploring either
//! with Ornstein-Uhlenbeck noise (the baseline) or by planning through the learned model.
//!
//! Per step: the newest frame is encoded and joins the stacked state `z_t`; the action is the
//! actor's (evaluation), the actor's plus OU noise, or the first of `H + 1` actions optimised
//! for f_Q (Eq. 4.11) from the actor's own rollout through the model (the printed loop omits
//! the first prediction `z_t+1 = Psi(z_t, a_t)`; it is made here). At the end of an episode the
//! model is trained, then DDPG (actor, critic, targets) for `updates-per-episode` steps.

use coadapt_core::{Batch, ReplayBuffer, Transition};
use coadapt_learner::config::DdpgConfig;
use coadapt_learner::ddpg::Ddpg;
use coadapt_nn::{Activations, Adam, AdamConfig, NnError};
use rand::Rng;

use crate::{Embedding, EmbeddingWork, LatentDynamics, Lbfgsb, Planner};

/// How an agent explores while it trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Explore {
    /// The baseline: the actor's action plus OU noise (sigma 0.5, theta 0.15 in the thesis).
    OrnsteinUhlenbeck,
    /// Trajectory optimisation through the model: the first of `H + 1` planned actions.
    Plan,
}

/// Alg. 3's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct AgentConfig {
    pub explore: Explore,
    pub horizon: usize,
    /// L-BFGS iterations per step (20 in the thesis).
    pub plan_iterations: usize,
    pub model_hidden: Vec<usize>,
    pub model_lr: f32,
    /// Model and DDPG updates at each episode's end (1000 in Fig. 4.5).
    pub updates_per_episode: usize,
    pub replay_capacity: usize,
    pub ddpg: DdpgConfig,
}

impl Default for AgentConfig {
    fn default() -> Self {
        let ddpg = DdpgConfig { sigma: 0.5, theta: 0.15, ..DdpgConfig::default() };
        Self {
            explore: Explore::Plan,
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

/// A DDPG agent on the latent state, with its model and its replays.
#[derive(Debug)]
pub struct LatentAgent {
    pub cfg: AgentConfig,
    emb: Embedding,
    enc: Vec<f32>,
    work: EmbeddingWork,
    pub ddpg: Ddpg,
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
    opt: Lbfgsb,
    plan_actions: Vec<f32>,
    rollout_act: Activations,
    /// The stacked state of the running episode.
    z: Vec<f32>,
    code: Vec<f32>,
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
        let ddpg = Ddpg::new(frames * l, act, cfg.ddpg.clone(), seed)?;
        let batch = Batch::new(cfg.ddpg.batch_size, frames * l, act);
        Ok(Self {
            model_adam: Adam::new(model_params.len(), AdamConfig { lr: cfg.model_lr, ..AdamConfig::default() }),
            model_grad: vec![0.0; model_params.len()],
            replay: ReplayBuffer::new(frames * l, act, cfg.replay_capacity),
            emb,
            enc,
            work: EmbeddingWork::default(),
            ddpg,
            model,
            model_params,
            model_act: Activations::default(),
            model_dy: Vec::new(),
            batch,
            opt: Lbfgsb::default(),
            plan_actions: Vec::new(),
            rollout_act: Activations::default(),
            z: vec![0.0; frames * l],
            code: vec![0.0; l],
            cfg,
        })
    }

    /// The stacked state after a reset to `frame` (every slot its code).
    pub fn reset(&mut self, frame: &[f32]) -> &[f32] {
        let l = self.emb.cfg.latent;
        self.code.copy_from_slice(self.emb.encode(&self.enc, frame, 1, &mut self.work));
        for c in self.z.chunks_exact_mut(l) {
            c.copy_from_slice(&self.code);
        }
        self.ddpg.reset_noise();
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

    /// The action at the current state: deterministic, OU-noisy, or planned (see [`Explore`]).
    /// For a planned one, returns f_Q of the plan and of the actor's own rollout it started from.
    pub fn act(&mut self, explore: bool, action: &mut [f32]) -> Option<(f32, f32)> {
        if !explore {
            self.ddpg.act(&self.z.clone(), true, action);
            return None;
        }
        match self.cfg.explore {
            Explore::OrnsteinUhlenbeck => {
                self.ddpg.act(&self.z.clone(), false, action);
                None
            }
            Explore::Plan => Some(self.plan(action)),
        }
    }

    /// Warm start from the actor's rollout through the model, then L-BFGS on f_Q.
    fn plan(&mut self, action: &mut [f32]) -> (f32, f32) {
        let (a, h, l) = (self.model.act, self.cfg.horizon, self.model.latent);
        self.plan_actions.clear();
        let mut z = self.z.clone();
        for j in 0..=h {
            let out = self.ddpg.actor().forward(self.ddpg.actor_params(), &z, 1, &mut self.rollout_act);
            let start = self.plan_actions.len();
            self.plan_actions.extend(out.iter().map(|v| v.tanh()));
            if j < h {
                let mut input = z.clone();
                input.extend_from_slice(&self.plan_actions[start..start + a]);
                let next = self.model.net.forward(&self.model_params, &input, 1, &mut self.model_act);
                let s = z.len();
                z.copy_within(l..s, 0);
                z[s - l..].copy_from_slice(next);
            }
        }
        let mut planner = Planner::new(&self.model, &self.model_params, self.ddpg.critic(), self.ddpg.critic_params(), h);
        let mut g = vec![0.0; self.plan_actions.len()];
        let before = planner.value_and_grad(&self.z, &self.plan_actions, &mut g);
        let after = planner.plan(&self.z, &mut self.plan_actions, -1.0, 1.0, self.cfg.plan_iterations, &mut self.opt);
        action.copy_from_slice(&self.plan_actions[..a]);
        (after, before)
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

    /// The end of an episode: the model, then DDPG, `updates-per-episode` steps each. Returns
    /// the last model loss.
    pub fn train<R: Rng + ?Sized>(&mut self, rng: &mut R) -> f32 {
        if self.replay.len() < self.cfg.ddpg.batch_size {
            return f32::NAN;
        }
        let (s, a, l) = (self.model.state_len(), self.model.act, self.model.latent);
        let n = self.batch.rows;
        let (mut input, mut target) = (vec![0.0; n * (s + a)], vec![0.0; n * l]);
        let mut loss = f32::NAN;
        for _ in 0..self.cfg.updates_per_episode {
            if self.replay.sample(rng, &mut self.batch).is_err() {
                break;
            }
            for i in 0..n {
                input[i * (s + a)..i * (s + a) + s].copy_from_slice(&self.batch.obs[i * s..(i + 1) * s]);
                input[i * (s + a) + s..(i + 1) * (s + a)].copy_from_slice(&self.batch.act[i * a..(i + 1) * a]);
                target[i * l..(i + 1) * l].copy_from_slice(&self.batch.next_obs[(i + 1) * s - l..(i + 1) * s]);
            }
            loss = self.model.loss_and_grad(
                &self.model_params,
                &input,
                &target,
                n,
                &mut self.model_grad,
                &mut self.model_act,
                &mut self.model_dy,
            );
            self.model_adam.step(&mut self.model_params, &self.model_grad);
            self.ddpg.update(&self.batch);
        }
        loss
    }
}
