//! The episodic Natural Actor-Critic (eNAC; Peters and Schaal, "Natural Actor-Critic",
//! Neurocomputing 2008), the thesis's gradient baseline on the planar task (learning rate 0.5).
//!
//! The policy is Gaussian around the linear mean, `a_t = M phi_t + eps_t` with
//! `eps_t ~ N(0, sigma^2 I)` drawn every step and a static `sigma^2` (10^1.5, the thesis's
//! initial variance of every method). Each rollout's log-likelihood gradient is
//! `psi_i = sum_t d/dM log pi(a_t | t) = sum_t eps_t phi_t' / sigma^2`, and eNAC fits its return
//! linearly, `R_i ~ <psi_i, w> + J`: `w` is the natural gradient, `J` the baseline. The update
//! is `M <- M + eta w`.
//!
//! The fit has `D P + 1` unknowns (133 on the planar task) and one row per rollout (30): it is
//! underdetermined, so `w` is the minimum-norm solution with the baseline unpenalised, i.e.
//! centred data and `w = Psi_c' (Psi_c Psi_c' + lambda I)^-1 R_c` (a tiny `lambda` for rank
//! deficiency). With at least `D P + 1` independent rollouts this is the ordinary least-squares
//! eNAC. The thesis gives only the learning rate; the per-step noise, the static variance and
//! the minimum-norm fit are our choices.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

#[cfg(test)]
use crate::EpisodicTask;
use crate::features::TimeFeatures;
use crate::policy::{LinearPolicy, Rollout};
use crate::{RolloutError, RolloutRunner};

/// eNAC's settings (the thesis's planar task: 30 rollouts, learning rate 0.5, variance 10^1.5).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct NacConfig {
    pub rollouts: usize,
    /// The step along the natural gradient, `eta`.
    pub learning_rate: f64,
    /// The exploration noise's static variance `sigma^2`, per action and step.
    pub variance: f64,
}

impl Default for NacConfig {
    fn default() -> Self {
        Self { rollouts: 30, learning_rate: 0.5, variance: 10f64.powf(1.5) }
    }
}

/// A setting of `[nac]` that cannot work; the message names its key.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum NacConfigError {
    #[error("nac.rollouts = {0}: at least 2 (the fit has a baseline)")]
    Rollouts(usize),
    #[error("nac.variance = {0}: must be positive")]
    Variance(f64),
    #[error("nac.learning-rate = {0}: must be positive")]
    LearningRate(f64),
}

impl NacConfig {
    /// Refuses settings that cannot work, naming the key.
    pub fn check(&self) -> Result<(), NacConfigError> {
        if self.rollouts < 2 {
            return Err(NacConfigError::Rollouts(self.rollouts));
        }
        if !(self.variance > 0.0 && self.variance.is_finite()) {
            return Err(NacConfigError::Variance(self.variance));
        }
        if !(self.learning_rate > 0.0 && self.learning_rate.is_finite()) {
            return Err(NacConfigError::LearningRate(self.learning_rate));
        }
        Ok(())
    }
}

/// The learner: the mean policy and the random stream of its exploration.
#[derive(Debug)]
pub struct Nac {
    pub policy: LinearPolicy,
    pub cfg: NacConfig,
    rng: rand::rngs::StdRng,
}

impl Nac {
    pub fn new(policy: LinearPolicy, cfg: NacConfig, seed: u64) -> Result<Self, NacConfigError> {
        cfg.check()?;
        Ok(Self { policy, cfg, rng: rand::rngs::StdRng::seed_from_u64(seed) })
    }

    /// One iteration: samples the rollouts (each rollout's `params` holds its noise, `T x D`),
    /// evaluates them on `task`, takes one natural-gradient step; returns the rollouts.
    pub fn iterate(&mut self, task: &dyn RolloutRunner, phi: &TimeFeatures) -> Result<Vec<Rollout>, RolloutError> {
        let (d, t_max) = (self.policy.actions, phi.steps());
        let noise = Normal::new(0.0, self.cfg.variance.sqrt()).expect("checked positive variance");
        let mut mean = Vec::new();
        LinearPolicy::actions_of(&self.policy.m, d, phi, &mut mean);
        let mut rollouts: Vec<Rollout> = (0..self.cfg.rollouts)
            .map(|_| Rollout { params: (0..t_max * d).map(|_| noise.sample(&mut self.rng)).collect(), ret: 0.0, cost: 0.0 })
            .collect();
        let actions: Vec<Vec<f32>> =
            rollouts.iter().map(|r| mean.iter().zip(&r.params).map(|(m, e)| (f64::from(*m) + e) as f32).collect()).collect();
        for (r, (ret, cost)) in rollouts.iter_mut().zip(crate::run_all(task, &actions)?) {
            (r.ret, r.cost) = (ret, cost);
        }
        let psi: Vec<Vec<f64>> = rollouts.iter().map(|r| self.psi(&r.params, phi)).collect();
        let returns: Vec<f64> = rollouts.iter().map(|r| r.ret).collect();
        if let Some(w) = natural_gradient(&psi, &returns) {
            for (m, g) in self.policy.m.iter_mut().zip(w) {
                *m += self.cfg.learning_rate * g;
            }
        }
        Ok(rollouts)
    }

    /// `psi = sum_t eps_t phi_t' / sigma^2`, as `D x P` row-major (the layout of M).
    pub fn psi(&self, eps: &[f64], phi: &TimeFeatures) -> Vec<f64> {
        let (d, p) = (self.policy.actions, self.policy.features);
        let mut g = vec![0.0; d * p];
        for t in 0..phi.steps() {
            let f = phi.at(t);
            for j in 0..d {
                let e = eps[t * d + j] / self.cfg.variance;
                for (gi, fi) in g[j * p..(j + 1) * p].iter_mut().zip(f) {
                    *gi += e * fi;
                }
            }
        }
        g
    }
}

/// eNAC's fit `R_i ~ <psi_i, w> + J` over the rollouts: `w`, the minimum-norm solution with the
/// baseline `J` unpenalised (see the module doc). `None` when the returns do not vary or the
/// system cannot be solved.
pub fn natural_gradient(psi: &[Vec<f64>], returns: &[f64]) -> Option<Vec<f64>> {
    let n = psi.len();
    if n < 2 || returns.len() != n {
        return None;
    }
    let dim = psi[0].len();
    // Centring removes J: the intercept's least-squares value is mean(R) - <mean(psi), w>.
    let mean_psi: Vec<f64> = (0..dim).map(|k| psi.iter().map(|p| p[k]).sum::<f64>() / n as f64).collect();
    let mean_r = returns.iter().sum::<f64>() / n as f64;
    let c: Vec<Vec<f64>> = psi.iter().map(|p| p.iter().zip(&mean_psi).map(|(a, b)| a - b).collect()).collect();
    let rc: Vec<f64> = returns.iter().map(|r| r - mean_r).collect();
    if rc.iter().all(|r| r.abs() < 1e-300) {
        return None;
    }
    if n > dim {
        // Overdetermined: the normal equations (Psi_c' Psi_c) w = Psi_c' R_c.
        let mut a = vec![0.0; dim * dim];
        let mut b = vec![0.0; dim];
        for (ci, ri) in c.iter().zip(&rc) {
            for x in 0..dim {
                b[x] += ci[x] * ri;
                for y in 0..dim {
                    a[x * dim + y] += ci[x] * ci[y];
                }
            }
        }
        let scale = (0..dim).map(|x| a[x * dim + x]).sum::<f64>() / dim as f64;
        (0..dim).for_each(|x| a[x * dim + x] += 1e-12 * scale.max(1e-300));
        let inv = crate::linalg::spd_inverse(&a, dim)?;
        let mut w = vec![0.0; dim];
        crate::linalg::matvec(&inv, dim, dim, &b, &mut w);
        return Some(w);
    }
    // Underdetermined: w = Psi_c' (Psi_c Psi_c' + lambda I)^-1 R_c, an n x n system. Centring
    // makes the Gram matrix singular (its rows sum to zero), hence the small lambda.
    let mut gram = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            gram[i * n + j] = c[i].iter().zip(&c[j]).map(|(a, b)| a * b).sum();
        }
    }
    let scale = (0..n).map(|i| gram[i * n + i]).sum::<f64>() / n as f64;
    (0..n).for_each(|i| gram[i * n + i] += 1e-9 * scale.max(1e-300));
    let inv = crate::linalg::spd_inverse(&gram, n)?;
    let mut alpha = vec![0.0; n];
    crate::linalg::matvec(&inv, n, n, &rc, &mut alpha);
    let mut w = vec![0.0; dim];
    for (ci, ai) in c.iter().zip(&alpha) {
        for (wk, ck) in w.iter_mut().zip(ci) {
            *wk += ai * ck;
        }
    }
    w.iter().all(|v| v.is_finite()).then_some(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    #[test]
    fn with_enough_rollouts_the_fit_recovers_an_exactly_linear_return() {
        // R_i = <psi_i, w*> + J exactly: least squares must give back w*.
        let mut s = 7;
        let dim = 5;
        let w_star: Vec<f64> = (0..dim).map(|_| lcg(&mut s) * 3.0).collect();
        let psi: Vec<Vec<f64>> = (0..20).map(|_| (0..dim).map(|_| lcg(&mut s)).collect()).collect();
        let r: Vec<f64> = psi.iter().map(|p| p.iter().zip(&w_star).map(|(a, b)| a * b).sum::<f64>() + 4.2).collect();
        let w = natural_gradient(&psi, &r).unwrap();
        for (a, b) in w.iter().zip(&w_star) {
            assert!((a - b).abs() < 1e-8, "{w:?} vs {w_star:?}");
        }
    }

    #[test]
    fn with_few_rollouts_the_fit_is_the_minimum_norm_solution() {
        // Fewer rollouts than parameters: w fits the centred returns exactly and lies in the
        // span of the centred psi (so it has the least norm of all exact fits).
        let mut s = 3;
        let dim = 12;
        let psi: Vec<Vec<f64>> = (0..5).map(|_| (0..dim).map(|_| lcg(&mut s)).collect()).collect();
        let r: Vec<f64> = (0..5).map(|_| lcg(&mut s) * 10.0).collect();
        let w = natural_gradient(&psi, &r).unwrap();
        let n = psi.len() as f64;
        let mp: Vec<f64> = (0..dim).map(|k| psi.iter().map(|p| p[k]).sum::<f64>() / n).collect();
        let mr = r.iter().sum::<f64>() / n;
        for (p, ri) in psi.iter().zip(&r) {
            let fit: f64 = p.iter().zip(&mp).zip(&w).map(|((a, b), c)| (a - b) * c).sum();
            assert!((fit - (ri - mr)).abs() < 1e-6, "fit {fit} vs {}", ri - mr);
        }
        // In the span: w's component orthogonal to every centred psi is zero. Project w on the
        // span by least squares and compare.
        let c: Vec<Vec<f64>> = psi.iter().map(|p| p.iter().zip(&mp).map(|(a, b)| a - b).collect()).collect();
        let gram: Vec<f64> =
            (0..5).flat_map(|i| (0..5).map(|j| c[i].iter().zip(&c[j]).map(|(a, b)| a * b).sum::<f64>()).collect::<Vec<_>>()).collect();
        let cw: Vec<f64> = c.iter().map(|ci| ci.iter().zip(&w).map(|(a, b)| a * b).sum()).collect();
        let mut g = gram.clone();
        (0..5).for_each(|i| g[i * 5 + i] += 1e-9);
        let inv = crate::linalg::spd_inverse(&g, 5).unwrap();
        let mut coef = vec![0.0; 5];
        crate::linalg::matvec(&inv, 5, 5, &cw, &mut coef);
        let proj: Vec<f64> = (0..dim).map(|k| c.iter().zip(&coef).map(|(ci, a)| a * ci[k]).sum()).collect();
        let off: f64 = w.iter().zip(&proj).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
        let norm: f64 = w.iter().map(|a| a * a).sum::<f64>().sqrt();
        assert!(off < 1e-6 * norm.max(1.0), "w leaves the span by {off} (|w| = {norm})");
    }

    #[test]
    fn psi_is_the_log_likelihood_gradient() {
        // d/dM sum_t log N(a_t | M phi_t, s2) at a = M phi + eps, against central differences.
        let phi = TimeFeatures::thesis(15);
        let (d, p) = (2, phi.len());
        let mut s = 11;
        let m: Vec<f64> = (0..d * p).map(|_| lcg(&mut s)).collect();
        let nac = Nac::new(LinearPolicy { actions: d, features: p, m: m.clone() }, NacConfig { variance: 2.0, ..NacConfig::default() }, 0)
            .unwrap();
        let eps: Vec<f64> = (0..phi.steps() * d).map(|_| lcg(&mut s)).collect();
        let mut mean = Vec::new();
        LinearPolicy::actions_of(&m, d, &phi, &mut mean);
        let a: Vec<f64> = mean.iter().zip(&eps).map(|(x, e)| f64::from(*x) + e).collect();
        let loglik = |mm: &[f64]| {
            let mut mu = Vec::new();
            LinearPolicy::actions_of(mm, d, &phi, &mut mu);
            -a.iter().zip(&mu).map(|(x, y)| (x - f64::from(*y)).powi(2)).sum::<f64>() / (2.0 * 2.0)
        };
        let g = nac.psi(&eps, &phi);
        for k in 0..d * p {
            let h = 1e-3;
            let (mut up, mut dn) = (m.clone(), m.clone());
            up[k] += h;
            dn[k] -= h;
            let fd = (loglik(&up) - loglik(&dn)) / (2.0 * h);
            // The actions pass through f32: a loose tolerance.
            assert!((fd - g[k]).abs() < 2e-3 * (1.0 + g[k].abs()), "psi[{k}] = {} vs finite difference {fd}", g[k]);
        }
    }

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
    fn nac_finds_a_known_optimum() {
        let phi = TimeFeatures::thesis(25);
        let (dim, p) = (2, phi.len());
        let star: Vec<f64> = (0..dim * p).map(|i| ((i as f64) * 0.7).sin() * 2.0).collect();
        let mut target = Vec::new();
        LinearPolicy::actions_of(&star, dim, &phi, &mut target);
        let task = Target { actions: target, steps: 25, dim };
        for seed in 1..=3 {
            // The returns here are below 1 (the planar task's reach 50): a larger step. A fixed
            // step keeps jittering near the optimum (the gradient's noise does not vanish): measured
            // 61.8 -> 3.0, 6.0, 3.4 for seeds 1-3.
            let mut nac =
                Nac::new(LinearPolicy::zeros(dim, p), NacConfig { rollouts: 30, learning_rate: 20.0, variance: 0.5 }, seed).unwrap();
            let mut a = Vec::new();
            LinearPolicy::actions_of(&nac.policy.m, dim, &phi, &mut a);
            let before = task.evaluate(&a).1;
            for _ in 0..150 {
                nac.iterate(&task, &phi).unwrap();
            }
            LinearPolicy::actions_of(&nac.policy.m, dim, &phi, &mut a);
            let after = task.evaluate(&a).1;
            coadapt_log::logln!("seed {seed}: squared action error {before:.2} -> {after:.2}");
            assert!(after < 0.15 * before, "seed {seed}: squared action error {before} -> {after}");
        }
    }

    #[test]
    fn settings_that_cannot_work_are_refused_naming_the_key() {
        let bad = |c: NacConfig| Nac::new(LinearPolicy::zeros(1, 1), c, 0).unwrap_err().to_string();
        assert!(bad(NacConfig { variance: 0.0, ..NacConfig::default() }).contains("nac.variance"));
        assert!(bad(NacConfig { learning_rate: -1.0, ..NacConfig::default() }).contains("nac.learning-rate"));
        assert!(bad(NacConfig { rollouts: 1, ..NacConfig::default() }).contains("nac.rollouts"));
    }
}
