//! PoWER (Kober and Peters, "Policy search for motor primitives in robotics"): policy learning
//! by weighted exploration with the returns, in its episodic form. Each rollout perturbs every
//! parameter once, `theta_i = M + eps_i` with `eps_i ~ N(0, sigma^2)` and a **static** variance
//! (the thesis's baseline: 10^1.5); the best `k` of the iteration's rollouts by return update the
//! mean by the return-weighted average of their perturbations,
//! `M <- M + sum_i R_i eps_i / sum_i R_i`.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

#[cfg(test)]
use crate::EpisodicTask;
use crate::features::TimeFeatures;
use crate::policy::{LinearPolicy, Rollout};
use crate::{RolloutError, RolloutRunner};

/// PoWER's settings (the thesis's planar task: 30 rollouts, the best 15, variance 10^1.5).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct PowerConfig {
    pub rollouts: usize,
    pub best: usize,
    pub variance: f64,
    /// Draw the perturbation every step (Kober and Peters's state-dependent exploration: the
    /// update weighs each step's perturbation by `W_t = phi phi' / phi' phi`) instead of once per
    /// rollout.
    pub per_step: bool,
}

impl Default for PowerConfig {
    fn default() -> Self {
        Self { rollouts: 30, best: 15, variance: 10f64.powf(1.5), per_step: false }
    }
}

/// The learner: the mean policy and the random stream of its perturbations.
#[derive(Debug)]
pub struct Power {
    pub policy: LinearPolicy,
    pub cfg: PowerConfig,
    rng: rand::rngs::StdRng,
}

impl Power {
    pub fn new(policy: LinearPolicy, cfg: PowerConfig, seed: u64) -> Self {
        Self { policy, cfg, rng: rand::rngs::StdRng::seed_from_u64(seed) }
    }

    /// One iteration: samples the rollouts, evaluates them on `task`, updates the mean from
    /// the best; returns every rollout of the iteration (best first).
    pub fn iterate(&mut self, task: &dyn RolloutRunner, phi: &TimeFeatures) -> Result<Vec<Rollout>, RolloutError> {
        if self.cfg.per_step {
            return self.iterate_per_step(task, phi);
        }
        let sd = self.cfg.variance.sqrt();
        let noise = Normal::new(0.0, sd).unwrap_or_else(|_| Normal::new(0.0, 1.0).expect("N(0, 1)"));
        let mut rollouts: Vec<Rollout> = (0..self.cfg.rollouts)
            .map(|_| {
                let params: Vec<f64> = self.policy.m.iter().map(|m| m + noise.sample(&mut self.rng)).collect();
                Rollout { params, ret: 0.0, cost: 0.0 }
            })
            .collect();
        let actions: Vec<Vec<f32>> = rollouts
            .iter()
            .map(|r| {
                let mut a = Vec::new();
                LinearPolicy::actions_of(&r.params, self.policy.actions, phi, &mut a);
                a
            })
            .collect();
        for (r, (ret, cost)) in rollouts.iter_mut().zip(crate::run_all(task, &actions)?) {
            (r.ret, r.cost) = (ret, cost);
        }
        rollouts.sort_by(|a, b| b.ret.total_cmp(&a.ret));
        self.update(&rollouts[..self.cfg.best.min(rollouts.len())]);
        Ok(rollouts)
    }

    /// Per-step exploration: `a_t = (M + eps_t) phi_t`; the update solves
    /// `(sum_i R_i sum_t W_t) dM_j = sum_i R_i sum_t W_t eps_itj` for every action j.
    fn iterate_per_step(&mut self, task: &dyn RolloutRunner, phi: &TimeFeatures) -> Result<Vec<Rollout>, RolloutError> {
        let (d, p, t_max) = (self.policy.actions, self.policy.features, phi.steps());
        let sd = self.cfg.variance.sqrt();
        let noise = Normal::new(0.0, sd).unwrap_or_else(|_| Normal::new(0.0, 1.0).expect("N(0, 1)"));
        // Each rollout: its perturbations (T x D x p) in `params`, return and cost.
        let mut actions: Vec<Vec<f32>> = Vec::with_capacity(self.cfg.rollouts);
        let mut rollouts: Vec<Rollout> = (0..self.cfg.rollouts)
            .map(|_| {
                let eps: Vec<f64> = (0..t_max * d * p).map(|_| noise.sample(&mut self.rng)).collect();
                let mut a = Vec::with_capacity(t_max * d);
                for t in 0..t_max {
                    let f = phi.at(t);
                    for j in 0..d {
                        let e = &eps[(t * d + j) * p..(t * d + j + 1) * p];
                        a.push((0..p).map(|i| (self.policy.m[j * p + i] + e[i]) * f[i]).sum::<f64>() as f32);
                    }
                }
                actions.push(a);
                Rollout { params: eps, ret: 0.0, cost: 0.0 }
            })
            .collect();
        for (r, (ret, cost)) in rollouts.iter_mut().zip(crate::run_all(task, &actions)?) {
            (r.ret, r.cost) = (ret, cost);
        }
        rollouts.sort_by(|a, b| b.ret.total_cmp(&a.ret));
        let best = &rollouts[..self.cfg.best.min(rollouts.len())];
        let mut lhs = vec![0.0; p * p];
        let mut rhs = vec![0.0; d * p];
        for r in best {
            let q = r.ret.max(0.0);
            for t in 0..t_max {
                let f = phi.at(t);
                let ff: f64 = f.iter().map(|v| v * v).sum();
                for a in 0..p {
                    for b in 0..p {
                        lhs[a * p + b] += q * f[a] * f[b] / ff;
                    }
                }
                for j in 0..d {
                    let e = &r.params[(t * d + j) * p..(t * d + j + 1) * p];
                    // W_t eps = phi (phi' eps) / phi' phi.
                    let fe: f64 = f.iter().zip(e).map(|(x, y)| x * y).sum::<f64>() / ff;
                    for a in 0..p {
                        rhs[j * p + a] += q * f[a] * fe;
                    }
                }
            }
        }
        // sum_t W_t has rank min(T, p): regularise lightly so it inverts.
        let scale = (0..p).map(|a| lhs[a * p + a]).fold(0.0, f64::max).max(1e-300);
        (0..p).for_each(|a| lhs[a * p + a] += 1e-9 * scale);
        if let Some(inv) = crate::linalg::spd_inverse(&lhs, p) {
            for j in 0..d {
                let mut step = vec![0.0; p];
                crate::linalg::matvec(&inv, p, p, &rhs[j * p..(j + 1) * p], &mut step);
                self.policy.m[j * p..(j + 1) * p].iter_mut().zip(step).for_each(|(m, s)| *m += s);
            }
        }
        Ok(rollouts)
    }

    /// The M-step on `best`: the return-weighted mean of their perturbations.
    pub fn update(&mut self, best: &[Rollout]) {
        let total: f64 = best.iter().map(|r| r.ret.max(0.0)).sum();
        if !(total > 0.0 && total.is_finite()) {
            return;
        }
        let mut step = vec![0.0; self.policy.m.len()];
        for r in best {
            let w = r.ret.max(0.0) / total;
            for ((s, p), m) in step.iter_mut().zip(&r.params).zip(&self.policy.m) {
                *s += w * (p - m);
            }
        }
        for (m, s) in self.policy.m.iter_mut().zip(step) {
            *m += s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Return `exp(-|a - a*|^2 / 50)` with `a* = M* phi`: the optimum is M*.
    struct Target {
        actions: Vec<f32>,
        steps: usize,
        dim: usize,
    }

    impl EpisodicTask for Target {
        fn steps(&self) -> usize {
            self.steps
        }
        fn action_dim(&self) -> usize {
            self.dim
        }
        fn evaluate(&self, actions: &[f32]) -> (f64, f64) {
            let d: f64 = actions.iter().zip(&self.actions).map(|(a, b)| f64::from(a - b).powi(2)).sum();
            ((-d / 50.0).exp(), d)
        }
    }

    #[test]
    fn the_update_is_the_return_weighted_mean_of_the_perturbations() {
        let mut p = Power::new(LinearPolicy { actions: 1, features: 2, m: vec![1.0, 2.0] }, PowerConfig::default(), 0);
        let best = [Rollout { params: vec![3.0, 2.0], ret: 3.0, cost: 0.0 }, Rollout { params: vec![1.0, 6.0], ret: 1.0, cost: 0.0 }];
        p.update(&best);
        // (3/4)(2, 0) + (1/4)(0, 4) = (1.5, 1).
        assert_eq!(p.policy.m, vec![2.5, 3.0]);
    }

    #[test]
    fn power_finds_a_known_optimum() {
        let phi = TimeFeatures::thesis(25);
        let (dim, p) = (2, phi.len());
        let star: Vec<f64> = (0..dim * p).map(|i| ((i as f64) * 0.7).sin() * 2.0).collect();
        let mut target = Vec::new();
        LinearPolicy::actions_of(&star, dim, &phi, &mut target);
        let task = Target { actions: target, steps: 25, dim };
        let mut power = Power::new(LinearPolicy::zeros(dim, p), PowerConfig { rollouts: 30, best: 15, variance: 0.5, per_step: false }, 3);
        let mut a = Vec::new();
        LinearPolicy::actions_of(&power.policy.m, dim, &phi, &mut a);
        let before = task.evaluate(&a).1;
        for _ in 0..150 {
            power.iterate(&task, &phi).unwrap();
        }
        LinearPolicy::actions_of(&power.policy.m, dim, &phi, &mut a);
        let after = task.evaluate(&a).1;
        assert!(after < 0.05 * before, "squared action error {before} -> {after}");
        // Per-step exploration reaches it too.
        let mut power = Power::new(LinearPolicy::zeros(dim, p), PowerConfig { rollouts: 30, best: 15, variance: 0.5, per_step: true }, 3);
        for _ in 0..150 {
            power.iterate(&task, &phi).unwrap();
        }
        LinearPolicy::actions_of(&power.policy.m, dim, &phi, &mut a);
        let per_step = task.evaluate(&a).1;
        assert!(per_step < 0.1 * before, "per step: squared action error {before} -> {per_step}");
    }
}

#[cfg(test)]
mod planar_tests {
    use super::*;
    use crate::PlanarReaching;

    #[test]
    fn power_brings_the_arms_nearer_their_goal_paths() {
        let phi = TimeFeatures::thesis(25);
        let task = PlanarReaching::default();
        let mut power = Power::new(LinearPolicy::zeros(12, phi.len()), PowerConfig::default(), 1);
        let mut a = Vec::new();
        let cost = |p: &Power, a: &mut Vec<f32>| {
            LinearPolicy::actions_of(&p.policy.m, 12, &phi, a);
            task.evaluate(a).1
        };
        let before = cost(&power, &mut a);
        let mut costs = Vec::new();
        for _ in 0..40 {
            power.iterate(&task, &phi).unwrap();
            costs.push(cost(&power, &mut a));
        }
        coadapt_log::logln!("PoWER on the planar task, summed distance of the mean policy: {before:.1} -> {costs:.1?}");
        // Measured: 184 -> 91 (seed 1); steadily down.
        assert!(costs[39] < 0.6 * before, "{before} -> {costs:?}");
        assert!(costs[39] < costs[19] && costs[19] < costs[0], "{costs:?}");
    }
}
