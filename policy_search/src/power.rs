//! PoWER (Kober and Peters, "Policy search for motor primitives in robotics"): policy learning
//! by weighted exploration with the returns, in its episodic form. Each rollout perturbs every
//! parameter once, `theta_i = M + eps_i` with `eps_i ~ N(0, sigma^2)` and a **static** variance
//! (the thesis's baseline: 10^1.5); the best `k` of the iteration's rollouts by return update the
//! mean by the return-weighted average of their perturbations,
//! `M <- M + sum_i R_i eps_i / sum_i R_i`.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::EpisodicTask;
use crate::features::TimeFeatures;
use crate::policy::{LinearPolicy, Rollout};

/// PoWER's settings (the thesis's planar task: 30 rollouts, the best 15, variance 10^1.5).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct PowerConfig {
    pub rollouts: usize,
    pub best: usize,
    pub variance: f64,
}

impl Default for PowerConfig {
    fn default() -> Self {
        Self { rollouts: 30, best: 15, variance: 10f64.powf(1.5) }
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
    pub fn iterate(&mut self, task: &dyn EpisodicTask, phi: &TimeFeatures) -> Vec<Rollout> {
        let sd = self.cfg.variance.sqrt();
        let noise = Normal::new(0.0, sd).unwrap_or_else(|_| Normal::new(0.0, 1.0).expect("N(0, 1)"));
        let mut actions = Vec::new();
        let mut rollouts: Vec<Rollout> = (0..self.cfg.rollouts)
            .map(|_| {
                let params: Vec<f64> = self.policy.m.iter().map(|m| m + noise.sample(&mut self.rng)).collect();
                LinearPolicy::actions_of(&params, self.policy.actions, phi, &mut actions);
                let (ret, cost) = task.evaluate(&actions);
                Rollout { params, ret, cost }
            })
            .collect();
        rollouts.sort_by(|a, b| b.ret.total_cmp(&a.ret));
        self.update(&rollouts[..self.cfg.best.min(rollouts.len())]);
        rollouts
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
        let mut power = Power::new(LinearPolicy::zeros(dim, p), PowerConfig { rollouts: 30, best: 15, variance: 0.5 }, 3);
        let mut a = Vec::new();
        LinearPolicy::actions_of(&power.policy.m, dim, &phi, &mut a);
        let before = task.evaluate(&a).1;
        for _ in 0..150 {
            power.iterate(&task, &phi);
        }
        LinearPolicy::actions_of(&power.policy.m, dim, &phi, &mut a);
        let after = task.evaluate(&a).1;
        assert!(after < 0.05 * before, "squared action error {before} -> {after}");
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
            power.iterate(&task, &phi);
            costs.push(cost(&power, &mut a));
        }
        eprintln!("PoWER on the planar task, summed distance of the mean policy: {before:.1} -> {costs:.1?}");
        // Measured: 184 -> 91 (seed 1); steadily down.
        assert!(costs[39] < 0.6 * before, "{before} -> {costs:?}");
        assert!(costs[39] < costs[19] && costs[19] < costs[0], "{costs:?}");
    }
}
