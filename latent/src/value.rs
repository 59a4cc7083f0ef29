//! The thesis's value critic through the learned model (Eq. 4.9, 4.10), for DDPG on the latent
//! state. The actor is `mu(z) = tanh(f(z))` as in the learner's DDPG.
//!
//! - Critic (Eq. 4.9): `L_V = mean_i (V(z_i) - y_i)^2` with the target
//!   `y_i = r_i + gamma (1 - done_i) V'(Psi(z_i, mu'(z_i)))`: off-policy (the stored action is not
//!   used; only the model's loss sees it), and it assumes the reward depends on the state only.
//!   The target is a constant: its networks (V', mu', Psi) are not trained by this loss.
//! - Actor (Eq. 4.10): `L_mu = -mean_i V(Psi(z_i, mu(z_i)))`, the gradient flowing back through
//!   the frozen V and Psi into mu.

use coadapt_nn::{Activations, Mlp};

use crate::LatentDynamics;

/// The networks of the value critic's losses (parameters passed per call).
#[derive(Debug)]
pub struct ValueLosses<'a> {
    pub v: &'a Mlp,
    pub actor: &'a Mlp,
    pub model: &'a LatentDynamics,
    pub gamma: f32,
    act_a: Activations,
    act_m: Activations,
    act_v: Activations,
    mu: Vec<f32>,
    input: Vec<f32>,
    next: Vec<f32>,
    dy: Vec<f32>,
    dx: Vec<f32>,
    dm: Vec<f32>,
    din: Vec<f32>,
}

impl<'a> ValueLosses<'a> {
    pub fn new(v: &'a Mlp, actor: &'a Mlp, model: &'a LatentDynamics, gamma: f32) -> Self {
        Self {
            v,
            actor,
            model,
            gamma,
            act_a: Activations::default(),
            act_m: Activations::default(),
            act_v: Activations::default(),
            mu: Vec::new(),
            input: Vec::new(),
            next: Vec::new(),
            dy: Vec::new(),
            dx: Vec::new(),
            dm: Vec::new(),
            din: Vec::new(),
        }
    }

    /// `mu(z)` for `n` states into `self.mu`, and `[z; mu(z)]` into `self.input`.
    fn act(&mut self, actor_params: &[f32], z: &[f32], n: usize) {
        let (s, a) = (self.model.state_len(), self.model.act);
        let out = self.actor.forward(actor_params, z, n, &mut self.act_a);
        self.mu.clear();
        self.mu.extend(out.iter().map(|v| v.tanh()));
        self.input.clear();
        for i in 0..n {
            self.input.extend_from_slice(&z[i * s..(i + 1) * s]);
            self.input.extend_from_slice(&self.mu[i * a..(i + 1) * a]);
        }
    }

    /// `Psi(z, mu(z))` (the shifted stack) for `n` states into `self.next`, after [`Self::act`].
    fn predict(&mut self, model_params: &[f32], z: &[f32], n: usize) {
        let (s, l) = (self.model.state_len(), self.model.latent);
        let newest = self.model.net.forward(model_params, &self.input, n, &mut self.act_m);
        self.next.clear();
        for i in 0..n {
            self.next.extend_from_slice(&z[i * s + l..(i + 1) * s]);
            self.next.extend_from_slice(&newest[i * l..(i + 1) * l]);
        }
    }

    /// Eq. 4.9: the critic's loss on a batch of `n` (state, reward, done) and its gradient with
    /// respect to V's parameters (written into `grad_v`).
    #[allow(clippy::too_many_arguments)]
    pub fn critic(
        &mut self,
        v_params: &[f32],
        v_target: &[f32],
        actor_target: &[f32],
        model_params: &[f32],
        z: &[f32],
        reward: &[f32],
        done: &[bool],
        n: usize,
        grad_v: &mut [f32],
    ) -> f32 {
        self.act(actor_target, z, n);
        self.predict(model_params, z, n);
        // The target, kept in `dm` (free until the actor's pass).
        let v_next = self.v.forward(v_target, &self.next, n, &mut self.act_v);
        self.dm.clear();
        self.dm.extend((0..n).map(|i| reward[i] + if done[i] { 0.0 } else { self.gamma * v_next[i] }));
        let v = self.v.forward(v_params, z, n, &mut self.act_v);
        let inv = 1.0 / n as f32;
        let mut loss = 0.0;
        self.dy.clear();
        for (vi, yi) in v.iter().zip(&self.dm) {
            let e = vi - yi;
            loss += e * e * inv;
            self.dy.push(2.0 * e * inv);
        }
        self.v.backward(v_params, z, &mut self.act_v, 0..n, &self.dy, Some(grad_v), None);
        loss
    }

    /// Eq. 4.10: the actor's loss `-mean V(Psi(z, mu(z)))` on `n` states and its gradient with
    /// respect to the actor's parameters (written into `grad_actor`), through the frozen V and
    /// model.
    pub fn actor_loss(
        &mut self,
        actor_params: &[f32],
        v_params: &[f32],
        model_params: &[f32],
        z: &[f32],
        n: usize,
        grad_actor: &mut [f32],
    ) -> f32 {
        let (s, a, l) = (self.model.state_len(), self.model.act, self.model.latent);
        self.act(actor_params, z, n);
        self.predict(model_params, z, n);
        let v = self.v.forward(v_params, &self.next, n, &mut self.act_v);
        let inv = 1.0 / n as f32;
        let loss = -v.iter().sum::<f32>() * inv;
        // dL/dV = -1/n per row; back to the predicted stack.
        self.dy.clear();
        self.dy.resize(n, -inv);
        self.dx.resize(n * s, 0.0);
        self.v.backward(v_params, &self.next, &mut self.act_v, 0..n, &self.dy, None, Some(&mut self.dx));
        // Only the newest code of the stack depends on the action: through psi_bar.
        self.dm.clear();
        for i in 0..n {
            self.dm.extend_from_slice(&self.dx[i * s + s - l..(i + 1) * s]);
        }
        self.din.resize(n * (s + a), 0.0);
        self.model.net.backward(model_params, &self.input, &mut self.act_m, 0..n, &self.dm, None, Some(&mut self.din));
        // d/d(pre-tanh) = d/da * (1 - mu^2), then into the actor.
        self.dy.clear();
        for i in 0..n {
            for k in 0..a {
                let m = self.mu[i * a + k];
                self.dy.push(self.din[i * (s + a) + s + k] * (1.0 - m * m));
            }
        }
        self.actor.backward(actor_params, z, &mut self.act_a, 0..n, &self.dy, Some(grad_actor), None);
        loss
    }
}
