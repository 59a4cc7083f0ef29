//! Network shapes of the agents: a critic reads `[obs, action]`, a policy reads `obs`.

use coadapt_nn::{Mlp, NnError};

fn sizes(n_in: usize, hidden: &[usize], n_out: usize) -> Vec<usize> {
    let mut s = Vec::with_capacity(hidden.len() + 2);
    s.push(n_in);
    s.extend_from_slice(hidden);
    s.push(n_out);
    s
}

/// `Q(s, a)`: `obs + act -> hidden -> 1`.
pub fn critic(obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Result<Mlp, NnError> {
    Mlp::new(&sizes(obs_dim + act_dim, hidden, 1))
}

/// The SAC policy head: `obs -> hidden -> [mean (act), log_std (act)]`.
pub fn gaussian_policy(obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Result<Mlp, NnError> {
    Mlp::new(&sizes(obs_dim, hidden, 2 * act_dim))
}

/// The DDPG actor: `obs -> hidden -> act`, squashed by tanh.
pub fn deterministic_policy(obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Result<Mlp, NnError> {
    Mlp::new(&sizes(obs_dim, hidden, act_dim))
}

/// Writes rows `[obs_r, act_r]` into `x` (`rows x (obs_dim + act_dim)`).
pub fn concat_rows(obs: &[f32], obs_dim: usize, act: &[f32], act_dim: usize, x: &mut [f32]) {
    let w = obs_dim + act_dim;
    for ((row, o), a) in x.chunks_exact_mut(w).zip(obs.chunks_exact(obs_dim)).zip(act.chunks_exact(act_dim)) {
        row[..obs_dim].copy_from_slice(o);
        row[obs_dim..].copy_from_slice(a);
    }
}

/// Sizes a scratch buffer for this batch; a no-op (no allocation) once warm.
pub(crate) fn resize(v: &mut Vec<f32>, n: usize) {
    if v.len() != n {
        v.resize(n, 0.0);
    }
}
