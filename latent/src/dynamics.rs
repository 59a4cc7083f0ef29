//! The latent dynamics (thesis Eq. 4.3-4.5) and the planning objective of Alg. 3 (Eq. 4.11).
//!
//! The latent state stacks the codes of the last `frames` images, oldest first:
//! `z_t = [E(x_t-2); E(x_t-1); E(x_t)]` (60 values for 3 frames of 20). The network `psi_bar`
//! (an MLP, 400-400-20 in the thesis) predicts only the newest code from `[z_t; a_t]`; the stack
//! shifts: `Psi(z_t, a_t) = [z_t-1 part; z_t part; psi_bar(z_t, a_t)]` (Eq. 4.4), trained on
//! `|psi_bar(z_t, a_t) - E(x_t+1)|^2` (Eq. 4.5).
//!
//! The planning objective `f_Q` (Eq. 4.11) scores actions `a_t .. a_t+H` from `z_t` by rolling
//! the model forward, `z_t+j = Psi(z_t+j-1, a_t+j-1)`, and weighing the critic along the way:
//! `f = sum_{j=0..H} w_j Q(z_t+j, a_t+j)` with `w_j = 1 / H`. Its gradient with respect to every
//! action flows back through the frozen critic and model ([`Planner::value_and_grad`]).
//! [`Objective`] also gives Eq. 4.12's `f_{r+Q}` (a learned latent reward along the way, the
//! critic at the end) and Fig. 4.8's last-Q only; [`CriticKind::V`] scores a step by the value
//! critic of where the model says it leads, `V(Psi(z, a))`.

use coadapt_nn::{Activations, Mlp, NnError};

/// The latent dynamics' shapes.
#[derive(Clone, Debug)]
pub struct LatentDynamics {
    pub latent: usize,
    pub frames: usize,
    pub act: usize,
    /// `psi_bar`: `[frames * latent + act] -> hidden... -> latent`.
    pub net: Mlp,
}

impl LatentDynamics {
    pub fn new(latent: usize, frames: usize, act: usize, hidden: &[usize]) -> Result<Self, NnError> {
        let mut sizes = vec![frames * latent + act];
        sizes.extend_from_slice(hidden);
        sizes.push(latent);
        Ok(Self { latent, frames, act, net: Mlp::new(&sizes)? })
    }

    /// Values of a stacked latent state.
    pub fn state_len(&self) -> usize {
        self.frames * self.latent
    }

    /// Eq. 4.5's loss over a batch of `n` rows of `input` (`[z_t; a_t]` each) and the next codes
    /// `target` (`n x latent`): the mean over rows of the squared error; the gradient with
    /// respect to the parameters is written into `grad`.
    pub fn loss_and_grad(
        &self,
        params: &[f32],
        input: &[f32],
        target: &[f32],
        n: usize,
        grad: &mut [f32],
        act: &mut Activations,
        dy: &mut Vec<f32>,
    ) -> f32 {
        let out = self.net.forward(params, input, n, act);
        dy.clear();
        let mut loss = 0.0;
        let inv = 1.0 / n as f32;
        for (o, t) in out.iter().zip(target) {
            let e = o - t;
            loss += e * e * inv;
            dy.push(2.0 * e * inv);
        }
        self.net.backward(params, input, act, 0..n, dy, Some(grad), None);
        loss
    }
}

/// What the planner maximises over `a_t .. a_t+H` (thesis Eq. 4.11, 4.12 and Fig. 4.8's third).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Objective {
    /// f_Q (Eq. 4.11): `sum_{j=0..H} Q(z_t+j, a_t+j) / H`.
    SumQ,
    /// f_{r+Q} (Eq. 4.12): `sum_{j=1..H-1} r(z_t+j) / H + Q(z_t+H, a_t+H) / H`, with a learned
    /// latent reward model `r(z)`.
    RewardPlusQ,
    /// The last step's critic only: `Q(z_t+H, a_t+H) / H`.
    LastQ,
}

/// Which critic scores a step of the plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CriticKind {
    /// `Q(z, a)` on `[z; a]` (Eq. 4.6, 4.7).
    Q,
    /// The value critic (Eq. 4.9, 4.10): a step `(z, a)` is worth `V(Psi(z, a))`, the value of
    /// where the model says it leads (as the actor's loss, Eq. 4.10, scores it).
    V,
}

/// The reward-plus-Q objective asked of a [`Planner`] without a reward model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("planner: the reward-plus-q objective needs a reward model")]
pub struct NoRewardModel;

/// Plans `H + 1` actions from a latent state through a frozen model and critic (Eq. 4.11, 4.12).
#[derive(Debug)]
pub struct Planner<'a> {
    pub model: &'a LatentDynamics,
    pub model_params: &'a [f32],
    /// `Q([z; a])` (`[frames * latent + act] -> ... -> 1`) or `V(z)` (`[frames * latent] -> 1`).
    pub critic: &'a Mlp,
    pub critic_params: &'a [f32],
    pub horizon: usize,
    pub objective: Objective,
    pub kind: CriticKind,
    /// The latent reward model `r(z)` (`[frames * latent] -> ... -> 1`), for f_{r+Q}.
    pub reward: Option<(&'a Mlp, &'a [f32])>,
    /// Scratch, kept between plans with [`Planner::reuse`] / [`Planner::into_work`].
    w: PlanWork,
}

/// A planner's scratch: the rolled-out states and the networks' activations, one per step, and
/// the optimiser's buffers. An agent keeps one across steps so planning allocates nothing once
/// warm.
#[derive(Clone, Debug, Default)]
pub struct PlanWork {
    states: Vec<Vec<f32>>,
    inputs: Vec<Vec<f32>>,
    model_act: Vec<Activations>,
    critic_act: Vec<Activations>,
    reward_act: Vec<Activations>,
    dz: Vec<f32>,
    dz_prev: Vec<f32>,
    din: Vec<f32>,
    ds: Vec<f32>,
    x32: Vec<f32>,
    g32: Vec<f32>,
    x64: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl<'a> Planner<'a> {
    /// f_Q with the Q critic; see [`Planner::with`] for the other objectives and critics.
    pub fn new(model: &'a LatentDynamics, model_params: &'a [f32], critic: &'a Mlp, critic_params: &'a [f32], horizon: usize) -> Self {
        let mut p = Self {
            model,
            model_params,
            critic,
            critic_params,
            horizon,
            objective: Objective::SumQ,
            kind: CriticKind::Q,
            reward: None,
            w: PlanWork::default(),
        };
        p.fit_work();
        p
    }

    /// One scratch slot per step of this horizon.
    fn fit_work(&mut self) {
        let n = self.horizon + 2;
        let w = &mut self.w;
        for v in [&mut w.states, &mut w.inputs] {
            v.resize(n, Vec::new());
        }
        for v in [&mut w.model_act, &mut w.critic_act, &mut w.reward_act] {
            v.resize(n, Activations::default());
        }
    }

    /// The same planner with the scratch of an earlier one (no allocation once it has grown).
    pub fn reuse(mut self, work: PlanWork) -> Self {
        self.w = work;
        self.fit_work();
        self
    }

    /// The scratch, to give the next planner.
    pub fn into_work(self) -> PlanWork {
        self.w
    }

    /// The same planner with another objective, critic kind and (for f_{r+Q}) reward model.
    /// Fails when f_{r+Q} has no reward model.
    pub fn with(mut self, objective: Objective, kind: CriticKind, reward: Option<(&'a Mlp, &'a [f32])>) -> Result<Self, NoRewardModel> {
        if objective == Objective::RewardPlusQ && reward.is_none() {
            return Err(NoRewardModel);
        }
        self.objective = objective;
        self.kind = kind;
        self.reward = reward;
        Ok(self)
    }

    /// The weight of the critic's term of step `j` (Q(z_j, a_j), or V(z_j+1)).
    fn q_weight(&self, j: usize) -> f32 {
        let (h, w) = (self.horizon, 1.0 / self.horizon.max(1) as f32);
        match self.objective {
            Objective::SumQ => w,
            Objective::RewardPlusQ | Objective::LastQ => {
                if j == h {
                    w
                } else {
                    0.0
                }
            }
        }
    }

    /// The weight of the reward model's term `r(z_j)`.
    fn r_weight(&self, j: usize) -> f32 {
        let (h, w) = (self.horizon, 1.0 / self.horizon.max(1) as f32);
        match self.objective {
            Objective::RewardPlusQ if j >= 1 && j < h => w,
            _ => 0.0,
        }
    }

    /// Alg. 3's optimisation: maximises the objective over the actions (`(H + 1) x act`,
    /// warm-started with the actor's rollout by the caller) within `[low, high]` per action, for
    /// `iterations` of L-BFGS; `actions` holds the result, the return is its objective.
    pub fn plan(&mut self, z0: &[f32], actions: &mut [f32], low: f32, high: f32, iterations: usize, opt: &mut crate::Lbfgsb) -> f32 {
        let n = actions.len();
        self.w.x64.clear();
        self.w.x64.extend(actions.iter().map(|&a| f64::from(a)));
        self.w.lo.clear();
        self.w.lo.resize(n, f64::from(low));
        self.w.hi.clear();
        self.w.hi.resize(n, f64::from(high));
        let (mut x, lo, hi) = (std::mem::take(&mut self.w.x64), std::mem::take(&mut self.w.lo), std::mem::take(&mut self.w.hi));
        let mut x32 = std::mem::take(&mut self.w.x32);
        let mut g32 = std::mem::take(&mut self.w.g32);
        g32.resize(n, 0.0);
        let r = opt.minimize(&mut x, &lo, &hi, iterations, |x, g| {
            x32.clear();
            x32.extend(x.iter().map(|&v| v as f32));
            let f = self.value_and_grad(z0, &x32, &mut g32);
            // Minimise -f.
            g.iter_mut().zip(&g32).for_each(|(a, b)| *a = -f64::from(*b));
            -f64::from(f)
        });
        actions.iter_mut().zip(&x).for_each(|(a, v)| *a = *v as f32);
        (self.w.x64, self.w.lo, self.w.hi, self.w.x32, self.w.g32) = (x, lo, hi, x32, g32);
        -r.value as f32
    }

    /// The objective of `actions` (`(H + 1) x act`, row j the action at t + j) from `z0`, and
    /// its gradient with respect to every action, written into `grad` (same shape).
    pub fn value_and_grad(&mut self, z0: &[f32], actions: &[f32], grad: &mut [f32]) -> f32 {
        let (m, a_dim, s) = (self.model, self.model.act, self.model.state_len());
        let (l, h) = (m.latent, self.horizon);
        assert_eq!(actions.len(), (h + 1) * a_dim, "actions: (H + 1) x act");
        // States z_0 .. z_H (z_H+1 too for V: the last step is worth V(Psi(z_H, a_H))).
        let n_states = match self.kind {
            CriticKind::Q => h + 1,
            CriticKind::V => h + 2,
        };
        let mut f = 0.0;
        for j in 0..n_states {
            let (done, rest) = self.w.states.split_at_mut(j);
            let z = &mut rest[0];
            z.clear();
            if j == 0 {
                z.extend_from_slice(z0);
            } else {
                let next = m.net.forward(self.model_params, &self.w.inputs[j - 1], 1, &mut self.w.model_act[j - 1]);
                z.extend_from_slice(&done[j - 1][l..]);
                z.extend_from_slice(next);
            }
            if j <= h {
                let input = &mut self.w.inputs[j];
                input.clear();
                input.extend_from_slice(z);
                input.extend_from_slice(&actions[j * a_dim..(j + 1) * a_dim]);
            }
            match self.kind {
                CriticKind::Q if j <= h && self.q_weight(j) != 0.0 => {
                    f += self.q_weight(j) * self.critic.forward(self.critic_params, &self.w.inputs[j], 1, &mut self.w.critic_act[j])[0];
                }
                CriticKind::V if j >= 1 && self.q_weight(j - 1) != 0.0 => {
                    f += self.q_weight(j - 1) * self.critic.forward(self.critic_params, &self.w.states[j], 1, &mut self.w.critic_act[j])[0];
                }
                _ => {}
            }
            if let (Some((net, p)), w) = (self.reward, self.r_weight(j))
                && w != 0.0
            {
                f += w * net.forward(p, &self.w.states[j], 1, &mut self.w.reward_act[j])[0];
            }
        }
        // Backward from the last state: dz carries df/dz_j (from z_j's own terms and later steps).
        grad.fill(0.0);
        self.w.dz.clear();
        self.w.dz.resize(s, 0.0);
        self.w.din.resize(s + a_dim, 0.0);
        self.w.ds.resize(s, 0.0);
        for j in (0..n_states).rev() {
            match self.kind {
                CriticKind::Q if j <= h && self.q_weight(j) != 0.0 => {
                    let w = self.q_weight(j);
                    self.critic.backward(
                        self.critic_params,
                        &self.w.inputs[j],
                        &mut self.w.critic_act[j],
                        0..1,
                        &[w],
                        None,
                        Some(&mut self.w.din),
                    );
                    for (g, v) in grad[j * a_dim..(j + 1) * a_dim].iter_mut().zip(&self.w.din[s..]) {
                        *g += v;
                    }
                    for (d, v) in self.w.dz.iter_mut().zip(&self.w.din[..s]) {
                        *d += v;
                    }
                }
                CriticKind::V if j >= 1 && self.q_weight(j - 1) != 0.0 => {
                    let w = self.q_weight(j - 1);
                    self.critic.backward(
                        self.critic_params,
                        &self.w.states[j],
                        &mut self.w.critic_act[j],
                        0..1,
                        &[w],
                        None,
                        Some(&mut self.w.ds),
                    );
                    for (d, v) in self.w.dz.iter_mut().zip(&self.w.ds) {
                        *d += v;
                    }
                }
                _ => {}
            }
            if let (Some((net, p)), w) = (self.reward, self.r_weight(j))
                && w != 0.0
            {
                net.backward(p, &self.w.states[j], &mut self.w.reward_act[j], 0..1, &[w], None, Some(&mut self.w.ds));
                for (d, v) in self.w.dz.iter_mut().zip(&self.w.ds) {
                    *d += v;
                }
            }
            if j == 0 {
                break;
            }
            // Through z_j = [z_j-1[l..]; psi_bar(z_j-1, a_j-1)].
            self.w.dz_prev.clear();
            self.w.dz_prev.resize(s, 0.0);
            for i in 0..s - l {
                self.w.dz_prev[l + i] += self.w.dz[i];
            }
            m.net.backward(
                self.model_params,
                &self.w.inputs[j - 1],
                &mut self.w.model_act[j - 1],
                0..1,
                &self.w.dz[s - l..],
                None,
                Some(&mut self.w.din),
            );
            for (d, v) in self.w.dz_prev.iter_mut().zip(&self.w.din[..s]) {
                *d += v;
            }
            // The model's action gradient joins a_j-1's (its own terms are added at step j-1).
            for (g, v) in grad[(j - 1) * a_dim..j * a_dim].iter_mut().zip(&self.w.din[s..]) {
                *g += v;
            }
            std::mem::swap(&mut self.w.dz, &mut self.w.dz_prev);
        }
        f
    }
}
