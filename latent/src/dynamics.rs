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

/// Plans `H + 1` actions from a latent state through a frozen model and critic (Eq. 4.11).
#[derive(Debug)]
pub struct Planner<'a> {
    pub model: &'a LatentDynamics,
    pub model_params: &'a [f32],
    /// `Q([z; a])`: `[frames * latent + act] -> ... -> 1`.
    pub critic: &'a Mlp,
    pub critic_params: &'a [f32],
    pub horizon: usize,
    /// Scratch: the rolled-out states and the networks' activations, one per step.
    states: Vec<Vec<f32>>,
    inputs: Vec<Vec<f32>>,
    model_act: Vec<Activations>,
    critic_act: Vec<Activations>,
    dz: Vec<f32>,
    dz_prev: Vec<f32>,
    din: Vec<f32>,
    x32: Vec<f32>,
    g32: Vec<f32>,
    x64: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl<'a> Planner<'a> {
    pub fn new(model: &'a LatentDynamics, model_params: &'a [f32], critic: &'a Mlp, critic_params: &'a [f32], horizon: usize) -> Self {
        let h = horizon + 1;
        Self {
            model,
            model_params,
            critic,
            critic_params,
            horizon,
            states: vec![Vec::new(); h],
            inputs: vec![Vec::new(); h],
            model_act: vec![Activations::default(); h],
            critic_act: vec![Activations::default(); h],
            dz: Vec::new(),
            dz_prev: Vec::new(),
            din: Vec::new(),
            x32: Vec::new(),
            g32: Vec::new(),
            x64: Vec::new(),
            lo: Vec::new(),
            hi: Vec::new(),
        }
    }

    /// Alg. 3's optimisation: maximises f_Q over the actions (`(H + 1) x act`, warm-started
    /// with the actor's rollout by the caller) within `[low, high]` per action, for
    /// `iterations` of L-BFGS; `actions` holds the result, the return is its f_Q.
    pub fn plan(&mut self, z0: &[f32], actions: &mut [f32], low: f32, high: f32, iterations: usize, opt: &mut crate::Lbfgsb) -> f32 {
        let n = actions.len();
        self.x64.clear();
        self.x64.extend(actions.iter().map(|&a| f64::from(a)));
        self.lo.clear();
        self.lo.resize(n, f64::from(low));
        self.hi.clear();
        self.hi.resize(n, f64::from(high));
        let (mut x, lo, hi) = (std::mem::take(&mut self.x64), std::mem::take(&mut self.lo), std::mem::take(&mut self.hi));
        let mut x32 = std::mem::take(&mut self.x32);
        let mut g32 = std::mem::take(&mut self.g32);
        g32.resize(n, 0.0);
        let r = opt.minimize(&mut x, &lo, &hi, iterations, |x, g| {
            x32.clear();
            x32.extend(x.iter().map(|&v| v as f32));
            let f = self.value_and_grad(z0, &x32, &mut g32);
            // Minimise -f_Q.
            g.iter_mut().zip(&g32).for_each(|(a, b)| *a = -f64::from(*b));
            -f64::from(f)
        });
        actions.iter_mut().zip(&x).for_each(|(a, v)| *a = *v as f32);
        (self.x64, self.lo, self.hi, self.x32, self.g32) = (x, lo, hi, x32, g32);
        -r.value as f32
    }

    /// `f_Q` of `actions` (`(H + 1) x act`, row j the action at t + j) from `z0`, and its
    /// gradient with respect to every action, written into `grad` (same shape).
    pub fn value_and_grad(&mut self, z0: &[f32], actions: &[f32], grad: &mut [f32]) -> f32 {
        let (m, a_dim, s) = (self.model, self.model.act, self.model.state_len());
        let (l, h) = (m.latent, self.horizon);
        let w = 1.0 / h.max(1) as f32;
        assert_eq!(actions.len(), (h + 1) * a_dim, "actions: (H + 1) x act");
        // Forward: states z_0..z_H, and Q at each.
        let mut f = 0.0;
        for j in 0..=h {
            let (done, rest) = self.states.split_at_mut(j);
            let z = &mut rest[0];
            z.clear();
            if j == 0 {
                z.extend_from_slice(z0);
            } else {
                let prev_in = &self.inputs[j - 1];
                let next = m.net.forward(self.model_params, prev_in, 1, &mut self.model_act[j - 1]);
                z.extend_from_slice(&done[j - 1][l..]);
                z.extend_from_slice(next);
            }
            let input = &mut self.inputs[j];
            input.clear();
            input.extend_from_slice(z);
            input.extend_from_slice(&actions[j * a_dim..(j + 1) * a_dim]);
            f += w * self.critic.forward(self.critic_params, input, 1, &mut self.critic_act[j])[0];
        }
        // Backward from the last step: dz carries df/dz_j (from later steps).
        grad.fill(0.0);
        self.dz.clear();
        self.dz.resize(s, 0.0);
        self.din.resize(s + a_dim, 0.0);
        for j in (0..=h).rev() {
            // Q's own term: df/d[z_j; a_j] = w dQ/d[z_j; a_j].
            self.critic.backward(self.critic_params, &self.inputs[j], &mut self.critic_act[j], 0..1, &[w], None, Some(&mut self.din));
            for (g, v) in grad[j * a_dim..(j + 1) * a_dim].iter_mut().zip(&self.din[s..]) {
                *g += v;
            }
            for (d, v) in self.dz.iter_mut().zip(&self.din[..s]) {
                *d += v;
            }
            if j == 0 {
                break;
            }
            // Through z_j = [z_j-1[l..]; psi_bar(z_j-1, a_j-1)].
            self.dz_prev.clear();
            self.dz_prev.resize(s, 0.0);
            for i in 0..s - l {
                self.dz_prev[l + i] += self.dz[i];
            }
            m.net.backward(
                self.model_params,
                &self.inputs[j - 1],
                &mut self.model_act[j - 1],
                0..1,
                &self.dz[s - l..],
                None,
                Some(&mut self.din),
            );
            for (d, v) in self.dz_prev.iter_mut().zip(&self.din[..s]) {
                *d += v;
            }
            // The model's action gradient joins a_j-1's (its Q term is added at step j-1).
            for (g, v) in grad[(j - 1) * a_dim..j * a_dim].iter_mut().zip(&self.din[s..]) {
                *g += v;
            }
            std::mem::swap(&mut self.dz, &mut self.dz_prev);
        }
        f
    }
}
