//! Deep Deterministic Policy Gradient (Lillicrap et al., 2016), thesis chapter 4.
//!
//! Notation: actor mu_phi(s) = tanh(f_phi(s)), critic Q_theta, targets mu_phi_bar and
//! Q_theta_bar. As in rlkit, both losses are taken at the same parameters before either network
//! steps, so the actor's and the critic's gradients are computed on separate cores.

use std::path::Path;

use coadapt_core::{Batch, Rng64};
use coadapt_nn::{Activations, Adam, AdamConfig, Mlp, NamedNetwork, NnError, clamp_elementwise, polyak};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::{DdpgConfig, Exploration};
use crate::networks::{concat_rows, critic, deterministic_policy, resize};

/// Losses of one update, for logging.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DdpgLosses {
    pub critic: f32,
    pub actor: f32,
}

#[derive(Clone, Debug, Default)]
struct ActorWork {
    act: Activations,
    q_act: Activations,
    a: Vec<f32>,
    x: Vec<f32>,
    dy: Vec<f32>,
    dx: Vec<f32>,
    d_raw: Vec<f32>,
    grad: Vec<f32>,
}

#[derive(Clone, Debug, Default)]
struct CriticWork {
    act: Activations,
    act_bar: Activations,
    act_mu_bar: Activations,
    a_next: Vec<f32>,
    x: Vec<f32>,
    x_next: Vec<f32>,
    dy: Vec<f32>,
    grad: Vec<f32>,
}

/// DDPG's exploration noise on an action in `[-1, 1]`: Ornstein-Uhlenbeck, `x <- x + theta
/// (0 - x) + sigma N(0, 1)` with dt = 1 as rlkit's OUStrategy, or independent Gaussian
/// `sigma N(0, 1)`; the noisy action is clipped to the box. The caller owns the random stream.
#[derive(Clone, Debug)]
pub struct ExplorationNoise {
    x: Vec<f32>,
}

impl ExplorationNoise {
    /// The process for actions of `dim` values, at rest.
    pub fn new(dim: usize) -> Self {
        Self { x: vec![0.0; dim] }
    }

    /// Back to rest (at each episode's start).
    pub fn reset(&mut self) {
        self.x.fill(0.0);
    }

    /// Adds one step of the noise to `action` and clips it to `[-1, 1]`.
    pub fn perturb<R: Rng + ?Sized>(&mut self, rng: &mut R, kind: Exploration, sigma: f32, theta: f32, action: &mut [f32]) {
        for (a, x) in action.iter_mut().zip(&mut self.x) {
            let n: f32 = rng.sample(StandardNormal);
            let noise = match kind {
                Exploration::OrnsteinUhlenbeck => {
                    *x += -theta * *x + sigma * n;
                    *x
                }
                Exploration::Gaussian => sigma * n,
            };
            *a = (*a + noise).clamp(-1.0, 1.0);
        }
    }
}

/// A DDPG agent with its exploration process.
#[derive(Clone, Debug)]
pub struct Ddpg {
    pub cfg: DdpgConfig,
    obs_dim: usize,
    act_dim: usize,
    actor: Mlp,
    critic: Mlp,
    phi: Vec<f32>,
    phi_bar: Vec<f32>,
    theta: Vec<f32>,
    theta_bar: Vec<f32>,
    actor_adam: Adam,
    critic_adam: Adam,
    aw: ActorWork,
    cw: CriticWork,
    act_ws: Activations,
    noise: ExplorationNoise,
    rng: Rng64,
}

impl Ddpg {
    pub fn new(obs_dim: usize, act_dim: usize, cfg: DdpgConfig, seed: u64) -> Result<Self, NnError> {
        let actor = deterministic_policy(obs_dim, act_dim, &cfg.hidden)?;
        let critic = critic(obs_dim, act_dim, &cfg.hidden)?;
        let mut rng = coadapt_core::rng(seed, 1);
        let mut phi = actor.zeros();
        actor.init(&mut phi, cfg.final_init, &mut rng);
        let mut theta = critic.zeros();
        critic.init(&mut theta, cfg.final_init, &mut rng);
        Ok(Self {
            obs_dim,
            act_dim,
            actor_adam: Adam::new(actor.n_params(), AdamConfig { lr: cfg.actor_lr, ..AdamConfig::default() }),
            critic_adam: Adam::new(critic.n_params(), AdamConfig { lr: cfg.critic_lr, ..AdamConfig::default() }),
            phi_bar: phi.clone(),
            theta_bar: theta.clone(),
            phi,
            theta,
            actor,
            critic,
            aw: ActorWork::default(),
            cw: CriticWork::default(),
            act_ws: Activations::default(),
            noise: ExplorationNoise::new(act_dim),
            rng,
            cfg,
        })
    }

    pub fn actor(&self) -> &Mlp {
        &self.actor
    }

    pub fn critic(&self) -> &Mlp {
        &self.critic
    }

    pub fn actor_params(&self) -> &[f32] {
        &self.phi
    }

    /// The critic's parameters (a planner differentiates through them).
    pub fn critic_params(&self) -> &[f32] {
        &self.theta
    }

    /// Overwrites actor, critic and both targets.
    pub fn set_params(&mut self, phi: &[f32], theta: &[f32], phi_bar: &[f32], theta_bar: &[f32]) {
        self.phi.copy_from_slice(phi);
        self.theta.copy_from_slice(theta);
        self.phi_bar.copy_from_slice(phi_bar);
        self.theta_bar.copy_from_slice(theta_bar);
    }

    /// Restarts the exploration process (call at each episode start).
    pub fn reset_noise(&mut self) {
        self.noise.reset();
    }

    /// `mu(s)`, plus exploration noise unless `deterministic`, clipped to `[-1, 1]`.
    pub fn act(&mut self, obs: &[f32], deterministic: bool, action: &mut [f32]) {
        let raw = self.actor.forward(&self.phi, obs, 1, &mut self.act_ws);
        for (a, r) in action.iter_mut().zip(raw) {
            *a = r.tanh();
        }
        if deterministic {
            return;
        }
        self.noise.perturb(&mut self.rng, self.cfg.exploration, self.cfg.sigma, self.cfg.theta, action);
    }

    /// One gradient step of actor and critic, then the Polyak targets.
    pub fn update(&mut self, b: &Batch) -> DdpgLosses {
        let (n, obs, act) = (b.rows, self.obs_dim, self.act_dim);
        let w = obs + act;
        let Self { cfg, actor, critic, phi, phi_bar, theta, theta_bar, actor_adam, aw, cw, .. } = self;
        let (phi_r, theta_r): (&[f32], &[f32]) = (phi, theta);
        let (actor_loss, critic_loss) = rayon::join(
            || {
                // J_mu(phi) = -mean_b Q_theta(s_b, mu_phi(s_b)).
                resize(&mut aw.a, n * act);
                resize(&mut aw.x, n * w);
                resize(&mut aw.dy, n);
                resize(&mut aw.dx, n * w);
                resize(&mut aw.d_raw, n * act);
                resize(&mut aw.grad, actor.n_params());
                let raw = actor.forward(phi_r, &b.obs, n, &mut aw.act);
                for (a, r) in aw.a.iter_mut().zip(raw) {
                    *a = r.tanh();
                }
                concat_rows(&b.obs, obs, &aw.a, act, &mut aw.x);
                let q = critic.forward(theta_r, &aw.x, n, &mut aw.q_act);
                let loss = -q.iter().sum::<f32>() / n as f32;
                aw.dy.fill(-1.0 / n as f32);
                critic.backward(theta_r, &aw.x, &mut aw.q_act, 0..n, &aw.dy, None, Some(&mut aw.dx));
                for ((d, row), a) in aw.d_raw.chunks_exact_mut(act).zip(aw.dx.chunks_exact(w)).zip(aw.a.chunks_exact(act)) {
                    for j in 0..act {
                        d[j] = row[obs + j] * (1.0 - a[j] * a[j]);
                    }
                }
                actor.backward(phi_r, &b.obs, &mut aw.act, 0..n, &aw.d_raw, Some(&mut aw.grad), None);
                loss
            },
            || {
                // y = scale r + gamma (1 - d) Q_theta_bar(s', mu_phi_bar(s')); J_Q = mean (Q(s, a) - y)^2.
                resize(&mut cw.a_next, n * act);
                resize(&mut cw.x, n * w);
                resize(&mut cw.x_next, n * w);
                resize(&mut cw.dy, n);
                resize(&mut cw.grad, critic.n_params());
                let raw = actor.forward(phi_bar, &b.next_obs, n, &mut cw.act_mu_bar);
                for (a, r) in cw.a_next.iter_mut().zip(raw) {
                    *a = r.tanh();
                }
                concat_rows(&b.next_obs, obs, &cw.a_next, act, &mut cw.x_next);
                let q_next = critic.forward(theta_bar, &cw.x_next, n, &mut cw.act_bar);
                for i in 0..n {
                    cw.dy[i] = cfg.reward_scale * b.rew[i] + cfg.gamma * (1.0 - b.done[i]) * q_next[i];
                }
                concat_rows(&b.obs, obs, &b.act, act, &mut cw.x);
                let q = critic.forward(theta_r, &cw.x, n, &mut cw.act);
                let mut loss = 0.0;
                for (d, q) in cw.dy.iter_mut().zip(q) {
                    let err = q - *d;
                    loss += err * err;
                    *d = 2.0 * err / n as f32;
                }
                critic.backward(theta_r, &cw.x, &mut cw.act, 0..n, &cw.dy, Some(&mut cw.grad), None);
                loss / n as f32
            },
        );
        if cfg.grad_clamp > 0.0 {
            clamp_elementwise(&mut aw.grad, cfg.grad_clamp);
            clamp_elementwise(&mut cw.grad, cfg.grad_clamp);
        }
        actor_adam.step(phi, &aw.grad);
        self.critic_adam.step(theta, &cw.grad);
        polyak(phi_bar, phi, cfg.tau);
        polyak(theta_bar, theta, cfg.tau);
        DdpgLosses { critic: critic_loss, actor: actor_loss }
    }

    /// Saves `actor`, `critic`, `actor_target` and `critic_target` as one safetensors file.
    pub fn save(&self, path: &Path) -> Result<(), NnError> {
        coadapt_nn::save_networks(
            path,
            &[
                ("actor", &self.actor, &self.phi),
                ("critic", &self.critic, &self.theta),
                ("actor_target", &self.actor, &self.phi_bar),
                ("critic_target", &self.critic, &self.theta_bar),
            ],
        )
    }

    /// Loads networks saved by [`Ddpg::save`]; the shapes must match this agent's.
    pub fn load(&mut self, path: &Path) -> Result<(), NnError> {
        let nets = coadapt_nn::load_networks(path)?;
        let get = |name: &str, mlp: &Mlp| NamedNetwork::find(&nets, path, name, mlp.sizes()).map(|n| n.params.clone());
        let (phi, theta) = (get("actor", &self.actor)?, get("critic", &self.critic)?);
        let (phi_bar, theta_bar) = (get("actor_target", &self.actor)?, get("critic_target", &self.critic)?);
        self.set_params(&phi, &theta, &phi_bar, &theta_bar);
        Ok(())
    }

    #[doc(hidden)]
    /// Test hook: the last update's (clamped) gradients of the actor and the critic.
    pub fn last_gradients(&self) -> (&[f32], &[f32]) {
        (&self.aw.grad, &self.cw.grad)
    }
}
