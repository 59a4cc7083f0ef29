//! SAC's critics: the twin (each with its target, optimiser and scratch, what one core owns
//! during an update) and the ensemble heads that regress on the twin's target, with
//! [`crate::conservative`]'s term when it is on.

use coadapt_core::{Batch, Rng64};
use coadapt_nn::{Activations, Adam, AdamConfig, Mlp, clamp_elementwise, polyak};

use crate::config::SacConfig;
use crate::conservative::{Conservative, ConservativeWork};
use crate::networks::{concat_rows, resize};

/// One critic with its target, optimiser and scratch: what one core owns during an update.
#[derive(Clone, Debug)]
pub(super) struct Critic {
    pub(super) theta: Vec<f32>,
    pub(super) theta_bar: Vec<f32>,
    pub(super) adam: Adam,
    pub(super) grad: Vec<f32>,
    pub(super) act: Activations,
    pub(super) act_bar: Activations,
    /// Rows `[s, a]` then rows `[s, a~]`.
    pub(super) x: Vec<f32>,
    pub(super) x_next: Vec<f32>,
    /// Q(s, a) then Q(s, a~).
    pub(super) q: Vec<f32>,
    pub(super) q_next: Vec<f32>,
    pub(super) dx: Vec<f32>,
    pub(super) dq_da: Vec<f32>,
    pub(super) dy: Vec<f32>,
}

/// An ensemble head: a critic of the twin's shape that regresses on the twin's Bellman target
/// and is never used by the policy or the target, so that the heads' spread at a state-action
/// (or, for FEAR's population critic, a design) far from the data measures how little the data
/// pins Q down there (a deep ensemble of independently initialised regressors). With the
/// conservative term on, each head also learns COMs' push down at the designs its own ascent
/// reaches: a critic that scores designs and nothing else.
#[derive(Clone, Debug)]
pub(super) struct Head {
    pub(super) theta: Vec<f32>,
    pub(super) adam: Adam,
    pub(super) grad: Vec<f32>,
    pub(super) act: Activations,
    pub(super) x: Vec<f32>,
    pub(super) dy: Vec<f32>,
    /// Scratch of the conservative term (empty while it is off).
    pub(super) cons: ConservativeWork,
}

impl Head {
    pub(super) fn new(critic: &Mlp, cfg: &SacConfig, rng: &mut Rng64) -> Self {
        let mut theta = critic.zeros();
        critic.init_with(cfg.hidden_init, &mut theta, cfg.critic_final_init, rng);
        Self {
            adam: Adam::new(critic.n_params(), AdamConfig { lr: cfg.critic_lr, ..AdamConfig::default() }),
            grad: critic.zeros(),
            theta,
            act: Activations::default(),
            x: vec![],
            dy: vec![],
            cons: ConservativeWork::default(),
        }
    }

    /// J_Q(theta_h) = mean_b (Q_h(s_b, a_b) - y_b)^2, plus the conservative term when `cons` is
    /// on: gradient, clamp, Adam (no target network: the twin's target `y` is the head's, so the
    /// term's push is not bootstrapped into the head's own targets). Returns the loss and the
    /// conservative gap and the sd of the head's Q over the batch (both 0 when off).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fit(
        &mut self,
        critic: &Mlp,
        b: &Batch,
        y: &[f32],
        obs_dim: usize,
        act_dim: usize,
        cfg: &SacConfig,
        cons: Option<&Conservative>,
    ) -> (f32, f32, f32) {
        let n = b.rows;
        resize(&mut self.x, n * (obs_dim + act_dim));
        resize(&mut self.dy, n);
        concat_rows(&b.obs, obs_dim, &b.act, act_dim, &mut self.x);
        let q = critic.forward(&self.theta, &self.x, n, &mut self.act);
        let mut loss = 0.0;
        for ((d, q), y) in self.dy.iter_mut().zip(q).zip(y) {
            loss += (q - y) * (q - y);
            *d = 2.0 * (q - y) / n as f32;
        }
        critic.backward(&self.theta, &self.x, &mut self.act, 0..n, &self.dy, Some(&mut self.grad), None);
        let (mut gap, mut sd) = (0.0, 0.0);
        if let Some(c) = cons {
            c.adversary(critic, &self.theta, &self.x, n, &mut self.cons);
            (gap, sd) = c.gradient(critic, &self.theta, n, &mut self.cons);
            for (g, d) in self.grad.iter_mut().zip(&self.cons.grad) {
                *g += d;
            }
        }
        if cfg.grad_clamp > 0.0 {
            clamp_elementwise(&mut self.grad, cfg.grad_clamp);
        }
        self.adam.step(&mut self.theta, &self.grad);
        (loss / n as f32, gap, sd)
    }
}

impl Critic {
    pub(super) fn new(critic: &Mlp, cfg: &SacConfig, rng: &mut Rng64) -> Self {
        let (lr, final_init) = (cfg.critic_lr, cfg.critic_final_init);
        let mut theta = critic.zeros();
        critic.init_with(cfg.hidden_init, &mut theta, final_init, rng);
        Self {
            theta_bar: theta.clone(),
            adam: Adam::new(critic.n_params(), AdamConfig { lr, ..AdamConfig::default() }),
            grad: critic.zeros(),
            theta,
            act: Activations::default(),
            act_bar: Activations::default(),
            x: vec![],
            x_next: vec![],
            q: vec![],
            q_next: vec![],
            dx: vec![],
            dq_da: vec![],
            dy: vec![],
        }
    }

    /// Q_bar(s', a~'), Q(s, a), Q(s, a~) and dQ(s, a~)/da~.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn evaluate(&mut self, critic: &Mlp, b: &Batch, a_new: &[f32], a_next: &[f32], obs_dim: usize, act_dim: usize) {
        let n = b.rows;
        let w = obs_dim + act_dim;
        resize(&mut self.x_next, n * w);
        resize(&mut self.x, 2 * n * w);
        resize(&mut self.dx, n * w);
        resize(&mut self.dq_da, n * act_dim);
        resize(&mut self.dy, n);
        concat_rows(&b.next_obs, obs_dim, a_next, act_dim, &mut self.x_next);
        let q_next = critic.forward(&self.theta_bar, &self.x_next, n, &mut self.act_bar);
        self.q_next.clear();
        self.q_next.extend_from_slice(q_next);

        let (x_data, x_new) = self.x.split_at_mut(n * w);
        concat_rows(&b.obs, obs_dim, &b.act, act_dim, x_data);
        concat_rows(&b.obs, obs_dim, a_new, act_dim, x_new);
        let q = critic.forward(&self.theta, &self.x, 2 * n, &mut self.act);
        self.q.clear();
        self.q.extend_from_slice(q);

        self.dy.fill(1.0);
        critic.backward(&self.theta, &self.x, &mut self.act, n..2 * n, &self.dy, None, Some(&mut self.dx));
        for (g, row) in self.dq_da.chunks_exact_mut(act_dim).zip(self.dx.chunks_exact(w)) {
            g.copy_from_slice(&row[obs_dim..]);
        }
    }

    /// J_Q(theta) = mean_b (Q(s_b, a_b) - y_b)^2 and the first half of its gradient (the
    /// layers' deltas); [`Critic::step_finish`] takes the step.
    pub(super) fn step_deltas(&mut self, critic: &Mlp, y: &[f32]) -> f32 {
        let n = y.len();
        let mut loss = 0.0;
        for ((d, q), y) in self.dy.iter_mut().zip(&self.q[..n]).zip(y) {
            loss += (q - y) * (q - y);
            *d = 2.0 * (q - y) / n as f32;
        }
        critic.backward_deltas(&self.theta, &mut self.act, 0..n, &self.dy, None);
        loss / n as f32
    }

    /// The weight gradient from [`Critic::step_deltas`], clamp, Adam, then the Polyak target.
    pub(super) fn step_finish(&mut self, critic: &Mlp, cfg: &SacConfig) {
        critic.weight_gradient(&self.x, &mut self.act, &mut self.grad);
        if cfg.grad_clamp > 0.0 {
            clamp_elementwise(&mut self.grad, cfg.grad_clamp);
        }
        self.adam.step(&mut self.theta, &self.grad);
        polyak(&mut self.theta_bar, &self.theta, cfg.tau);
    }
}
