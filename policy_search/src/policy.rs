//! Linear policies over time features, and rollouts of them.

use crate::features::TimeFeatures;

/// `a_t = M phi_t`; `M` is `actions x features`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct LinearPolicy {
    pub actions: usize,
    pub features: usize,
    pub m: Vec<f64>,
}

impl LinearPolicy {
    pub fn zeros(actions: usize, features: usize) -> Self {
        Self { actions, features, m: vec![0.0; actions * features] }
    }

    /// The actions of parameters `m` (same shape as `self.m`) over every step of `phi`, as
    /// `steps x actions` f32 (what a task or an actor takes).
    pub fn actions_of(m: &[f64], actions: usize, phi: &TimeFeatures, out: &mut Vec<f32>) {
        out.clear();
        let p = phi.len();
        for t in 0..phi.steps() {
            let f = phi.at(t);
            for j in 0..actions {
                let row = &m[j * p..(j + 1) * p];
                out.push(row.iter().zip(f).map(|(a, b)| a * b).sum::<f64>() as f32);
            }
        }
    }
}

/// One rollout: the parameters it ran with, its return and cost.
#[derive(Clone, Debug, PartialEq)]
pub struct Rollout {
    pub params: Vec<f64>,
    pub ret: f64,
    pub cost: f64,
}
