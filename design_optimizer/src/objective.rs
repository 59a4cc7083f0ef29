//! The design objective over the critic, batched over particles x start states.
//!
//! Rows are (particle, start state) pairs. Each core takes a contiguous share of the particles
//! and pushes them through actor and critic in chunks of whole particles small enough to stay in
//! cache, with its own preallocated workspace: no allocation and no synchronisation inside a
//! pass. Single-threaded products of this size run near a core's peak, so splitting rows across
//! cores beats threading inside each product.

use coadapt_nn::{Activations, Mlp};

/// Which critic value scores a design.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QMode {
    /// Q1 alone (the reference).
    First,
    /// min(Q1, Q2), as the SAC targets use.
    MinOfTwin,
}

#[derive(Debug, thiserror::Error)]
pub enum ObjectiveError {
    #[error("{what}: {why}")]
    Shape { what: &'static str, why: String },
}

/// Eq. 5.6 for a fixed policy, critic(s) and start-state batch.
#[derive(Clone, Debug)]
pub struct DesignObjective {
    /// The policy restricted to its mean head: `obs -> hidden -> act`.
    mean_policy: Mlp,
    mean_phi: Vec<f32>,
    critic: Mlp,
    thetas: Vec<Vec<f32>>,
    start_states: Vec<f32>,
    n_states: usize,
    obs_dim: usize,
    act_dim: usize,
    design_at: usize,
    design_dim: usize,
}

/// One core's scratch.
#[derive(Clone, Debug, Default)]
pub struct ObjectiveWorkspace {
    x_actor: Vec<f32>,
    x_critic: Vec<f32>,
    q: Vec<f32>,
    act_pi: Activations,
    act_q: Activations,
}

impl DesignObjective {
    /// `policy` outputs `[mean, log_std]` (the SAC head); `thetas` holds one critic (Q1) or two
    /// (Q1, Q2). `start_states` is `n_states x obs_dim`; the design occupies the observation
    /// columns `design_at..design_at + design_dim`.
    pub fn new(
        policy: &Mlp,
        phi: &[f32],
        critic: &Mlp,
        thetas: &[&[f32]],
        start_states: &[f32],
        design_at: usize,
        design_dim: usize,
    ) -> Result<Self, ObjectiveError> {
        let shape = |what, why: String| Err(ObjectiveError::Shape { what, why });
        let obs_dim = policy.n_in();
        if !policy.n_out().is_multiple_of(2) {
            return shape("policy", format!("output width {} is not [mean, log_std]", policy.n_out()));
        }
        let act_dim = policy.n_out() / 2;
        if critic.n_in() != obs_dim + act_dim || critic.n_out() != 1 {
            return shape("critic", format!("sizes {:?} do not take [obs {obs_dim}, act {act_dim}] to 1", critic.sizes()));
        }
        if thetas.is_empty() || thetas.len() > 2 || thetas.iter().any(|t| t.len() != critic.n_params()) {
            return shape("critic parameters", "need one or two parameter vectors of the critic's size".into());
        }
        if phi.len() != policy.n_params() {
            return shape("policy parameters", format!("{} values, expected {}", phi.len(), policy.n_params()));
        }
        if start_states.is_empty() || !start_states.len().is_multiple_of(obs_dim) {
            return shape("start states", format!("{} values is not a positive multiple of obs {obs_dim}", start_states.len()));
        }
        if design_at + design_dim > obs_dim {
            return shape("design columns", format!("{design_at}..{} beyond obs {obs_dim}", design_at + design_dim));
        }
        // Keep only the mean rows of the last layer: the log-std head does not enter Eq. 5.6.
        let mut sizes = policy.sizes().to_vec();
        *sizes.last_mut().expect("an MLP has layers") = act_dim;
        let mean_policy = Mlp::new(&sizes).map_err(|e| ObjectiveError::Shape { what: "policy", why: e.to_string() })?;
        let mut mean_phi = Vec::with_capacity(mean_policy.n_params());
        let last = policy.layers().len() - 1;
        for (i, l) in policy.layers().iter().enumerate() {
            let out = if i == last { act_dim } else { l.n_out };
            mean_phi.extend_from_slice(&phi[l.w..l.w + out * l.n_in]);
            mean_phi.extend_from_slice(&phi[l.b..l.b + out]);
        }
        Ok(Self {
            mean_policy,
            mean_phi,
            critic: critic.clone(),
            thetas: thetas.iter().map(|t| t.to_vec()).collect(),
            n_states: start_states.len() / obs_dim,
            start_states: start_states.to_vec(),
            obs_dim,
            act_dim,
            design_at,
            design_dim,
        })
    }

    pub fn n_states(&self) -> usize {
        self.n_states
    }

    pub fn design_dim(&self) -> usize {
        self.design_dim
    }

    /// Floating-point operations of one row through actor and critic(s).
    pub fn flops_per_row(&self) -> usize {
        2 * (self.mean_policy.macs_per_row() + self.thetas.len() * self.critic.macs_per_row())
    }

    /// Scores `designs` (`particles x design_dim`) into `out` (`particles`), splitting the
    /// particles across `workspaces.len()` cores, in chunks of about `chunk_rows` rows.
    pub fn evaluate(&self, designs: &[f32], mode: QMode, chunk_rows: usize, out: &mut [f32], workspaces: &mut [ObjectiveWorkspace]) {
        let p = out.len();
        assert_eq!(designs.len(), p * self.design_dim, "designs are not particles x design_dim");
        assert!(!workspaces.is_empty(), "need at least one workspace");
        let per_core = p.div_ceil(workspaces.len()).max(1);
        let per_chunk = (chunk_rows / self.n_states).max(1);
        rayon::scope(|s| {
            for ((out, designs), ws) in out.chunks_mut(per_core).zip(designs.chunks(per_core * self.design_dim)).zip(workspaces.iter_mut())
            {
                s.spawn(move |_| {
                    for (o, d) in out.chunks_mut(per_chunk).zip(designs.chunks(per_chunk * self.design_dim)) {
                        self.evaluate_chunk(d, mode, o, ws);
                    }
                });
            }
        });
    }

    fn evaluate_chunk(&self, designs: &[f32], mode: QMode, out: &mut [f32], ws: &mut ObjectiveWorkspace) {
        let (n, obs, act) = (self.n_states, self.obs_dim, self.act_dim);
        let rows = out.len() * n;
        let w = obs + act;
        ws.x_actor.resize(rows * obs, 0.0);
        ws.x_critic.resize(rows * w, 0.0);
        for (k, xi) in designs.chunks_exact(self.design_dim).enumerate() {
            for (s, state) in self.start_states.chunks_exact(obs).enumerate() {
                let row = &mut ws.x_actor[(k * n + s) * obs..(k * n + s + 1) * obs];
                row.copy_from_slice(state);
                row[self.design_at..self.design_at + self.design_dim].copy_from_slice(xi);
            }
        }
        let mean = self.mean_policy.forward(&self.mean_phi, &ws.x_actor, rows, &mut ws.act_pi);
        for ((xc, o), m) in ws.x_critic.chunks_exact_mut(w).zip(ws.x_actor.chunks_exact(obs)).zip(mean.chunks_exact(act)) {
            xc[..obs].copy_from_slice(o);
            for (a, m) in xc[obs..].iter_mut().zip(m) {
                *a = m.tanh();
            }
        }
        ws.q.resize(rows, 0.0);
        let q1 = self.critic.forward(&self.thetas[0], &ws.x_critic, rows, &mut ws.act_q);
        ws.q.copy_from_slice(q1);
        if mode == QMode::MinOfTwin && self.thetas.len() == 2 {
            let q2 = self.critic.forward(&self.thetas[1], &ws.x_critic, rows, &mut ws.act_q);
            for (q, q2) in ws.q.iter_mut().zip(q2) {
                *q = q.min(*q2);
            }
        }
        for (o, qs) in out.iter_mut().zip(ws.q.chunks_exact(n)) {
            *o = qs.iter().sum::<f32>() / n as f32;
        }
    }
}
