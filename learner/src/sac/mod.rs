//! Soft Actor-Critic (Haarnoja et al., 2018) with twin critics, as rlkit's `SACTrainer`, which the
//! reference implementation uses: every loss is computed at the same parameters, then every
//! network steps. That makes the critics and the policy independent within an update, so they
//! run on separate cores.
//!
//! Notation: policy pi_phi, critics Q_theta_i with targets Q_theta_bar_i, entropy weight alpha,
//! a batch `(s, a, r, s', d)` of size B, and reparameterised actions
//! `a~ = tanh(mu_phi(s) + sigma_phi(s) eps)`, `eps ~ N(0, I)`.
//!
//! # Layout
//! - this file: [`Sac`], its update in the paper's notation, acting, parameter access.
//! - `critics`: one twin critic with its target (what one core owns in an update) and the
//!   ensemble heads, with the conservative term when it is on.
//! - `state`: networks to and from safetensors, and the whole state for a snapshot.

use coadapt_core::{Batch, Rng64};
use coadapt_nn::{Activations, Adam, AdamConfig, Mlp, NnError, clamp_elementwise, squashed};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::SacConfig;
use crate::conservative::Conservative;
use crate::networks::{critic, gaussian_policy, resize};

mod critics;
mod state;

use critics::{Critic, Head};

/// Losses of one update, for logging.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SacLosses {
    pub q1: f32,
    pub q2: f32,
    pub policy: f32,
    pub alpha: f32,
    /// Mean log pi(a~|s) of the batch (minus the policy's entropy).
    pub log_pi: f32,
    /// Mean loss of the ensemble heads (0 without heads).
    pub heads: f32,
    /// The conservative term's gap, mean over the ensemble heads of mean Q at the adversarial
    /// designs minus mean Q at the batch's (0 when the term is off; [`crate::conservative`]).
    pub conservative_gap: f32,
    /// The term's weight lambda after this update's dual step (0 when off).
    pub conservative_weight: f32,
}

/// The policy's scratch for one update.
#[derive(Clone, Debug, Default)]
struct PolicyWork {
    act_s: Activations,
    act_s_next: Activations,
    eps: Vec<f32>,
    eps_next: Vec<f32>,
    a_new: Vec<f32>,
    log_pi: Vec<f32>,
    a_next: Vec<f32>,
    log_pi_next: Vec<f32>,
    y: Vec<f32>,
    d_a: Vec<f32>,
    d_log_pi: Vec<f32>,
    d_head: Vec<f32>,
    grad: Vec<f32>,
}

/// A SAC agent: policy, twin critics with targets, their optimisers and entropy weight.
#[derive(Clone, Debug)]
pub struct Sac {
    pub cfg: SacConfig,
    obs_dim: usize,
    act_dim: usize,
    policy: Mlp,
    critic: Mlp,
    phi: Vec<f32>,
    phi_adam: Adam,
    critics: [Critic; 2],
    /// Ensemble heads beyond the twin (see [`Sac::with_heads`]); empty in plain SAC.
    heads: Vec<Head>,
    /// COMs' conservative term on the ensemble heads ([`Sac::set_conservative`]); off in plain
    /// SAC.
    conservative: Option<Conservative>,
    log_alpha: f32,
    alpha_adam: Adam,
    target_entropy: f32,
    work: PolicyWork,
    act_ws: Activations,
    /// Noise of the last `act` call (any action width).
    act_eps: Vec<f32>,
    rng: Rng64,
    updates: u64,
}

impl Sac {
    /// A freshly initialised agent for observations of `obs_dim` and actions of `act_dim`.
    pub fn new(obs_dim: usize, act_dim: usize, cfg: SacConfig, seed: u64) -> Result<Self, NnError> {
        let policy = gaussian_policy(obs_dim, act_dim, &cfg.hidden)?.with_precision(cfg.precision);
        let critic = critic(obs_dim, act_dim, &cfg.hidden)?.with_precision(cfg.precision);
        let mut rng = coadapt_core::rng(seed, 1);
        let mut phi = policy.zeros();
        policy.init_with(cfg.hidden_init, &mut phi, cfg.policy_final_init, &mut rng);
        let c1 = Critic::new(&critic, &cfg, &mut rng);
        let c2 = Critic::new(&critic, &cfg, &mut rng);
        Ok(Self {
            obs_dim,
            act_dim,
            phi_adam: Adam::new(policy.n_params(), AdamConfig { lr: cfg.policy_lr, ..AdamConfig::default() }),
            log_alpha: cfg.alpha.ln(),
            alpha_adam: Adam::new(1, AdamConfig { lr: cfg.alpha_lr, ..AdamConfig::default() }),
            target_entropy: cfg.target_entropy.unwrap_or(-(act_dim as f32)),
            policy,
            critic,
            phi,
            critics: [c1, c2],
            heads: Vec::new(),
            conservative: None,
            work: PolicyWork::default(),
            act_ws: Activations::default(),
            act_eps: Vec::new(),
            rng,
            updates: 0,
            cfg,
        })
    }

    /// The agent with `extra` ensemble heads beside the twin critics, initialised from their own
    /// generator stream (`seed`, stream 9), so the twin, the policy and every action are those of
    /// [`Sac::new`] with the same seed: the heads only watch. Each update fits every head to the
    /// twin's Bellman target on the same batch (one more forward and backward pass on the
    /// batch per head, against three per twin critic).
    pub fn with_heads(obs_dim: usize, act_dim: usize, cfg: SacConfig, seed: u64, extra: usize) -> Result<Self, NnError> {
        let mut sac = Self::new(obs_dim, act_dim, cfg, seed)?;
        let mut rng = coadapt_core::rng(seed, 9);
        sac.heads = (0..extra).map(|_| Head::new(&sac.critic, &sac.cfg, &mut rng)).collect();
        Ok(sac)
    }

    /// Turns COMs' conservative term on the ensemble heads on (`Some`) or off (`None`: the heads
    /// regress on the twin's target alone); see [`crate::conservative`]. The twin, the policy
    /// and every action are the same either way. FEAR sets it on the population pair.
    /// The term's weight starts where `c` has it and follows its dual ascent; a term already on
    /// (an earlier call, or a restored snapshot) keeps the weight it has reached.
    pub fn set_conservative(&mut self, c: Option<Conservative>) {
        let reached = self.conservative.as_ref().map(|old| old.log_weight);
        self.conservative = c;
        if let (Some(c), Some(log_weight)) = (self.conservative.as_mut(), reached) {
            c.log_weight = log_weight;
        }
    }

    /// Ensemble heads beyond the twin.
    pub fn extra_heads(&self) -> usize {
        self.heads.len()
    }

    /// Ensemble head `i`'s parameters (`i < extra_heads()`).
    pub fn head_params(&self, i: usize) -> &[f32] {
        &self.heads[i].theta
    }

    pub fn alpha(&self) -> f32 {
        self.log_alpha.exp()
    }

    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Steps taken by each Adam optimiser since its last reset: policy, critic 1, critic 2,
    /// log-alpha.
    pub fn optimiser_steps(&self) -> [u32; 4] {
        [self.phi_adam.steps(), self.critics[0].adam.steps(), self.critics[1].adam.steps(), self.alpha_adam.steps()]
    }

    pub fn policy(&self) -> &Mlp {
        &self.policy
    }

    pub fn critic(&self) -> &Mlp {
        &self.critic
    }

    /// The policy's flat parameters phi (what actors need).
    pub fn policy_params(&self) -> &[f32] {
        &self.phi
    }

    /// Critic `i`'s parameters theta_i and target theta_bar_i.
    pub fn critic_params(&self, i: usize) -> (&[f32], &[f32]) {
        (&self.critics[i].theta, &self.critics[i].theta_bar)
    }

    /// Overwrites every network's parameters (e.g. with reference weights in tests).
    pub fn set_params(&mut self, phi: &[f32], theta: [&[f32]; 2], theta_bar: [&[f32]; 2]) {
        self.phi.copy_from_slice(phi);
        for i in 0..2 {
            self.critics[i].theta.copy_from_slice(theta[i]);
            self.critics[i].theta_bar.copy_from_slice(theta_bar[i]);
        }
    }

    /// Copies every network of `other` (policy, critics, targets and alpha) and restarts all
    /// optimisers' moment estimates: FEAR's "pi_indvd = pi_pop, Q_indvd = Q_pop" at a new design.
    pub fn copy_networks_from(&mut self, other: &Sac) {
        assert_eq!(self.policy, other.policy, "copying between agents of different shapes");
        self.phi.copy_from_slice(&other.phi);
        for (c, o) in self.critics.iter_mut().zip(&other.critics) {
            c.theta.copy_from_slice(&o.theta);
            c.theta_bar.copy_from_slice(&o.theta_bar);
            c.adam.reset();
        }
        // Heads both agents have (FEAR's individual pair has none).
        for (h, o) in self.heads.iter_mut().zip(&other.heads) {
            h.theta.copy_from_slice(&o.theta);
            h.adam.reset();
        }
        self.phi_adam.reset();
        self.log_alpha = other.log_alpha;
        self.alpha_adam.reset();
    }

    /// Draws an action for one observation: `tanh(mu + sigma eps)`, or `tanh(mu)` when
    /// `deterministic`.
    pub fn act(&mut self, obs: &[f32], deterministic: bool, action: &mut [f32]) {
        let head = self.policy.forward(&self.phi, obs, 1, &mut self.act_ws);
        if deterministic {
            squashed::mean_action(head, self.act_dim, action);
        } else {
            resize(&mut self.act_eps, self.act_dim);
            for e in self.act_eps.iter_mut() {
                *e = self.rng.sample(StandardNormal);
            }
            let mut lp = [0.0];
            squashed::sample(head, &self.act_eps, self.act_dim, action, &mut lp);
        }
    }

    /// One gradient step on every network from `b`, with fresh noise from the agent's generator.
    pub fn update(&mut self, b: &Batch) -> SacLosses {
        let n = b.rows * self.act_dim;
        let w = &mut self.work;
        resize(&mut w.eps, n);
        resize(&mut w.eps_next, n);
        for e in w.eps.iter_mut().chain(w.eps_next.iter_mut()) {
            *e = self.rng.sample(StandardNormal);
        }
        self.update_with_noise(b)
    }

    /// The update with the noise already in `work.eps` (at s) and `work.eps_next` (at s'), so a
    /// test can reproduce it exactly against a reference.
    fn update_with_noise(&mut self, b: &Batch) -> SacLosses {
        let (n, act, obs) = (b.rows, self.act_dim, self.obs_dim);
        let Self {
            cfg, policy, critic, phi, phi_adam, critics, heads, conservative, log_alpha, alpha_adam, target_entropy, work: w, ..
        } = self;
        for v in [&mut w.a_new, &mut w.a_next, &mut w.d_a] {
            resize(v, n * act);
        }
        for v in [&mut w.log_pi, &mut w.log_pi_next, &mut w.y, &mut w.d_log_pi] {
            resize(v, n);
        }
        resize(&mut w.d_head, n * 2 * act);
        resize(&mut w.grad, policy.n_params());

        // a~ ~ pi_phi(.|s) and a~' ~ pi_phi(.|s'), one core each.
        let PolicyWork { act_s, act_s_next, eps, eps_next, a_new, log_pi, a_next, log_pi_next, .. } = w;
        rayon::join(
            || squashed::sample(policy.forward(phi, &b.obs, n, act_s), eps, act, a_new, log_pi),
            || squashed::sample(policy.forward(phi, &b.next_obs, n, act_s_next), eps_next, act, a_next, log_pi_next),
        );

        // J(alpha) = -E[log alpha (log pi(a~|s) + H_bar)], stepped first as rlkit does.
        let mean_log_pi = w.log_pi.iter().sum::<f32>() / n as f32;
        let alpha_loss = -*log_alpha * (mean_log_pi + *target_entropy);
        if cfg.auto_alpha {
            let mut la = [*log_alpha];
            alpha_adam.step(&mut la, &[-(mean_log_pi + *target_entropy)]);
            *log_alpha = la[0];
        }
        let alpha = log_alpha.exp();

        // Q_theta_i(s, a), Q_theta_i(s, a~), dQ_theta_i/da~ and Q_theta_bar_i(s', a~'), one core per critic.
        let [c1, c2] = critics;
        rayon::join(|| c1.evaluate(critic, b, &w.a_new, &w.a_next, obs, act), || c2.evaluate(critic, b, &w.a_new, &w.a_next, obs, act));

        // y = scale r + gamma (1 - d) (min_i Q_theta_bar_i(s', a~') - alpha log pi(a~'|s')).
        for i in 0..n {
            let v_next = c1.q_next[i].min(c2.q_next[i]) - alpha * w.log_pi_next[i];
            w.y[i] = cfg.reward_scale * b.rew[i] + cfg.gamma * (1.0 - b.done[i]) * v_next;
        }

        // The ensemble heads regress on the same target (with the conservative term when it is
        // on); nothing else reads them.
        let (mut head_loss, mut gap, mut sd) = (0.0, 0.0, 0.0);
        for h in heads.iter_mut() {
            let (loss, g, s) = h.fit(critic, b, &w.y, obs, act, cfg, conservative.as_ref());
            head_loss += loss;
            gap += g;
            sd += s;
        }
        if !heads.is_empty() {
            let k = heads.len() as f32;
            (head_loss, gap, sd) = (head_loss / k, gap / k, sd / k);
        }
        // lambda follows the heads' lead (the dual step, [`Conservative::dual_step`]).
        let mut cons_weight = 0.0;
        if let Some(c) = conservative.as_mut() {
            if !heads.is_empty() {
                c.dual_step(gap, sd);
            }
            cons_weight = c.weight();
        }

        // J_pi(phi) = mean_b [alpha log pi(a~_b|s_b) - min_i Q_theta_i(s_b, a~_b)]; the gradient
        // reaches a~ through whichever critic is the smaller for that sample.
        let mut policy_loss = 0.0;
        for i in 0..n {
            let (q1, q2) = (c1.q[n + i], c2.q[n + i]);
            let (q_min, dq) = if q1 <= q2 { (q1, &c1.dq_da) } else { (q2, &c2.dq_da) };
            policy_loss += alpha * w.log_pi[i] - q_min;
            for j in 0..act {
                w.d_a[i * act + j] = -dq[i * act + j] / n as f32;
            }
            w.d_log_pi[i] = alpha / n as f32;
        }

        // Step both critics and the policy. Each backward pass is two halves of about equal
        // cost, the deltas (chained layer to layer) and the weight gradient (each layer's on
        // its own), so the six halves split evenly over two cores in two rounds: the policy's
        // deltas and critic 1's beside critic 2's whole step, then critic 1's weight gradient
        // and step beside the policy's. (Three whole steps as three tasks left one core idle a
        // third of the time.) Each half computes what the whole backward pass does, bit for bit.
        let PolicyWork { act_s, eps, a_new, d_a, d_log_pi, d_head, grad, y, .. } = w;
        let (q1_loss, q2_loss) = rayon::join(
            || {
                squashed::backward(act_s.output(), eps, a_new, d_a, d_log_pi, act, d_head);
                policy.backward_deltas(phi, act_s, 0..n, d_head, None);
                c1.step_deltas(critic, y)
            },
            || {
                let loss = c2.step_deltas(critic, y);
                c2.step_finish(critic, cfg);
                loss
            },
        );
        rayon::join(
            || c1.step_finish(critic, cfg),
            || {
                policy.weight_gradient(&b.obs, act_s, grad);
                if cfg.grad_clamp > 0.0 {
                    clamp_elementwise(grad, cfg.grad_clamp);
                }
                phi_adam.step(phi, grad);
            },
        );
        self.updates += 1;
        SacLosses {
            q1: q1_loss,
            q2: q2_loss,
            policy: policy_loss / n as f32,
            alpha: alpha_loss,
            log_pi: mean_log_pi,
            heads: head_loss,
            conservative_gap: gap,
            conservative_weight: cons_weight,
        }
    }

    #[doc(hidden)]
    /// Test hook: the update with given noise `eps` (at s) and `eps_next` (at s').
    pub fn update_with_given_noise(&mut self, b: &Batch, eps: &[f32], eps_next: &[f32]) -> SacLosses {
        self.work.eps.clear();
        self.work.eps.extend_from_slice(eps);
        self.work.eps_next.clear();
        self.work.eps_next.extend_from_slice(eps_next);
        self.update_with_noise(b)
    }

    #[doc(hidden)]
    /// Test hook: overwrites ensemble head `i`'s parameters.
    pub fn set_head_params(&mut self, i: usize, theta: &[f32]) {
        self.heads[i].theta.copy_from_slice(theta);
    }

    #[doc(hidden)]
    /// Test hook: the last update's gradients of the policy and of critic 1 (clamped).
    pub fn last_gradients(&self) -> (&[f32], &[f32]) {
        (&self.work.grad, &self.critics[0].grad)
    }
}
