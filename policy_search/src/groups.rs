//! GrouPS, Group Factor Policy Search (thesis Alg. 1, Eq. 2.10-2.29, in the implementable form
//! of `thesis-notes.md` 1.3-1.4), with the synergy prior of Alg. 2 (Eq. 3.15-3.17: W centred on
//! a previously learned W-hat; W-hat = 0 is chapter 2 exactly) and Gamma-distributed alpha.
//!
//! Actions of group m: `a_t^(m) = (W^(m) Z_t + M^(m) + E_t^(m)) phi_t`, with `Z_t` (K x p)
//! standard normal, drawn once per rollout (default, as the reference port) or per step, and
//! `E_t^(m)` of variance 1/tau_m. With `z_t = Z_t phi_t` and `s_t = phi_t' phi_t` the policy is
//! `N(a^(m) | W^(m) z_t + M^(m) phi_t, s_t / tau_m)`. The mean-field posterior
//! q(M) q(W) q(z) q(alpha) q(tau) is fitted to the best rollouts, weighted by their returns
//! (`w_i = R_i / sum R`), in the order M, W, z, alpha, tau, with E[tau] throughout; z is not
//! reward-weighted.

use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use crate::features::TimeFeatures;
use crate::linalg::{dot, matvec, spd_inverse};
use crate::{RolloutError, RolloutRunner};

/// GrouPS's settings (the thesis's planar task).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct GroupsConfig {
    /// Latent factors K (synergies per group).
    pub latent: usize,
    pub rollouts: usize,
    /// Rollouts of an iteration the update uses (the best by return).
    pub best: usize,
    /// Variational iterations per update.
    pub inner: usize,
    pub a_tau: f64,
    pub b_tau: f64,
    pub a_alpha: f64,
    pub b_alpha: f64,
    /// Prior variance of M around the previous iteration's M.
    pub sigma2: f64,
    /// After each update W <- resize E[W], tau <- E[tau] / resize (against collapse).
    pub resize: f64,
    /// Initial noise variance 1/tau.
    pub initial_variance: f64,
    /// Draw Z every step (false: once per rollout, the reference port's choice).
    pub z_per_step: bool,
    /// The priors on M, W and tau and the posterior covariances of M and W (GrouPS). Without
    /// (PePPER, Luck et al. 2014): expectation-maximisation of the factor model, point
    /// estimates of M, W and tau and the posterior of z only.
    pub priors: bool,
    /// The model of alpha: 0 for independent Gamma factors (ch. 2, Eq. 2.15-2.17); a rank R >= 1
    /// for the log-linear model of ch. 3 (Eq. 3.4), fitted by L-BFGS with prior precision
    /// `alpha-lambda` on U and V.
    pub alpha_rank: usize,
    /// lambda of the log-linear model (the thesis leaves it open).
    pub alpha_lambda: f64,
    /// Rollouts kept from iteration to iteration (ch. 3's Baxter protocol: a pool of 20 of the
    /// best so far, joined by `rollouts` new ones; old samples are not importance-weighted).
    /// 0: every iteration starts afresh (ch. 2).
    pub pool: usize,
    /// Rollouts of the first iteration when a pool is kept (ch. 3: 20); 0: `rollouts`.
    pub first_rollouts: usize,
}

impl Default for GroupsConfig {
    fn default() -> Self {
        Self {
            latent: 6,
            rollouts: 30,
            best: 15,
            inner: 20,
            a_tau: 1000.0,
            b_tau: 1000.0,
            a_alpha: 1.0,
            b_alpha: 1.0,
            sigma2: 100.0,
            resize: 1.5,
            initial_variance: 10f64.powf(1.5),
            z_per_step: false,
            priors: true,
            alpha_rank: 0,
            alpha_lambda: 0.1,
            pool: 0,
            first_rollouts: 0,
        }
    }
}

impl GroupsConfig {
    /// PePPER's settings (thesis ch. 2.4: no priors, no groups, resize sqrt(1.09)).
    pub fn pepper() -> Self {
        Self { priors: false, resize: 1.09f64.sqrt(), ..Self::default() }
    }
}

/// One sampled rollout: its actions (`T x D`), the latent draws `z_t` (`T x K`), return, cost.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    pub actions: Vec<f64>,
    pub z: Vec<f64>,
    pub ret: f64,
    pub cost: f64,
}

/// Why [`Groups::new`] refuses its groups or settings.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum GroupsError {
    /// A group names an action index beyond the `actions` there are.
    #[error("group action {action} is beyond the {actions} actions")]
    ActionBeyond { action: usize, actions: usize },
    /// An action in no group or in several (`groups` is how many).
    #[error("action {action} is in {groups} groups; every action belongs to exactly one")]
    NotAPartition { action: usize, groups: usize },
    #[error("initial-variance, resize and sigma2 must be positive")]
    NotPositive,
    #[error("best = {best}: between 1 and the rollouts an iteration has (rollouts {rollouts} + pool {pool})")]
    Best { best: usize, rollouts: usize, pool: usize },
}

/// The learner's state: the posterior means and covariances, per group.
#[derive(Clone, Debug)]
pub struct Groups {
    pub cfg: GroupsConfig,
    /// Action indices of each group.
    pub groups: Vec<Vec<usize>>,
    /// Actions D and features p.
    pub d: usize,
    pub p: usize,
    /// E[M] (`D x p`) and each group's row covariance (`p x p`).
    pub m: Vec<f64>,
    pub sigma_m: Vec<Vec<f64>>,
    /// E[W] (`D x K`), each group's row covariance (`K x K`), the prior centre W-hat.
    pub w: Vec<f64>,
    pub sigma_w: Vec<Vec<f64>>,
    pub w_hat: Vec<f64>,
    /// E[alpha] per group (`K` each) and E[tau] per group.
    pub alpha: Vec<Vec<f64>>,
    pub tau: Vec<f64>,
    /// The log-linear model of alpha, when `alpha-rank` > 0.
    pub alpha_model: Option<crate::alpha::LogLinearAlpha>,
    /// The rollouts kept for the next iteration (`pool` > 0).
    pub kept: Vec<Sample>,
    rng: rand::rngs::StdRng,
}

impl Groups {
    /// A learner for `d` actions in `groups` (each action in exactly one), `p` features: M = 0,
    /// W ~ N(0, 1), alpha = 1, tau = 1 / initial variance.
    pub fn new(cfg: GroupsConfig, groups: Vec<Vec<usize>>, d: usize, p: usize, seed: u64) -> Result<Self, GroupsError> {
        let mut seen = vec![0usize; d];
        for g in &groups {
            for &j in g {
                *seen.get_mut(j).ok_or(GroupsError::ActionBeyond { action: j, actions: d })? += 1;
            }
        }
        if let Some(j) = seen.iter().position(|&c| c != 1) {
            return Err(GroupsError::NotAPartition { action: j, groups: seen[j] });
        }
        if !(cfg.initial_variance > 0.0 && cfg.resize > 0.0 && cfg.sigma2 > 0.0) {
            return Err(GroupsError::NotPositive);
        }
        if cfg.best == 0 || cfg.best > cfg.rollouts + cfg.pool {
            return Err(GroupsError::Best { best: cfg.best, rollouts: cfg.rollouts, pool: cfg.pool });
        }
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let k = cfg.latent;
        let w: Vec<f64> = (0..d * k).map(|_| StandardNormal.sample(&mut rng)).collect();
        let n = groups.len();
        Ok(Self {
            m: vec![0.0; d * p],
            sigma_m: vec![identity(p); n],
            w,
            sigma_w: vec![identity(k); n],
            w_hat: vec![0.0; d * k],
            alpha: vec![vec![1.0; k]; n],
            tau: vec![1.0 / cfg.initial_variance; n],
            kept: Vec::new(),
            alpha_model: (cfg.alpha_rank > 0).then(|| crate::alpha::LogLinearAlpha::new(n, k, cfg.alpha_rank, cfg.alpha_lambda)),
            cfg,
            groups,
            d,
            p,
            rng,
        })
    }

    /// Samples one rollout's actions from the current policy (noise included).
    pub fn sample(&mut self, phi: &TimeFeatures) -> Sample {
        let (d, p, k, t_max) = (self.d, self.p, self.cfg.latent, phi.steps());
        let mut zmat: Vec<f64> = (0..k * p).map(|_| StandardNormal.sample(&mut self.rng)).collect();
        let (mut actions, mut z) = (Vec::with_capacity(t_max * d), Vec::with_capacity(t_max * k));
        let mut sd = vec![0.0; d];
        for (g, idx) in self.groups.iter().enumerate() {
            for &j in idx {
                sd[j] = (1.0 / self.tau[g]).sqrt();
            }
        }
        let mut zt = vec![0.0; k];
        for t in 0..t_max {
            if self.cfg.z_per_step && t > 0 {
                for v in zmat.iter_mut() {
                    *v = StandardNormal.sample(&mut self.rng);
                }
            }
            let f = phi.at(t);
            matvec(&zmat, k, p, f, &mut zt);
            for j in 0..d {
                let e: f64 = f
                    .iter()
                    .map(|fi| {
                        let n: f64 = StandardNormal.sample(&mut self.rng);
                        fi * sd[j] * n
                    })
                    .sum();
                let a = dot(&self.w[j * k..(j + 1) * k], &zt) + dot(&self.m[j * p..(j + 1) * p], f) + e;
                actions.push(a);
            }
            z.extend_from_slice(&zt);
        }
        Sample { actions, z, ret: 0.0, cost: 0.0 }
    }

    /// One iteration: samples, evaluates, updates from the best; the samples, best first.
    /// With a pool, the new rollouts join the kept ones; the best `pool` of them are kept for
    /// the next iteration. Returns the new rollouts, best first.
    pub fn iterate(&mut self, task: &dyn RolloutRunner, phi: &TimeFeatures) -> Result<Vec<Sample>, RolloutError> {
        let n = if self.cfg.pool > 0 && self.kept.is_empty() && self.cfg.first_rollouts > 0 {
            self.cfg.first_rollouts
        } else {
            self.cfg.rollouts
        };
        let mut samples: Vec<Sample> = (0..n).map(|_| self.sample(phi)).collect();
        let actions: Vec<Vec<f32>> = samples.iter().map(|s| s.actions.iter().map(|&v| v as f32).collect()).collect();
        for (s, (ret, cost)) in samples.iter_mut().zip(crate::run_all(task, &actions)?) {
            (s.ret, s.cost) = (ret, cost);
        }
        samples.sort_by(|a, b| b.ret.total_cmp(&a.ret));
        let mut all = samples.clone();
        if self.cfg.pool > 0 {
            all.append(&mut self.kept);
            all.sort_by(|a, b| b.ret.total_cmp(&a.ret));
            self.kept = all.iter().take(self.cfg.pool).cloned().collect();
        }
        let best = &all[..self.cfg.best.min(all.len())];
        let total: f64 = best.iter().map(|s| s.ret.max(0.0)).sum();
        if total > 0.0 && total.is_finite() {
            let weights: Vec<f64> = best.iter().map(|s| s.ret.max(0.0) / total).collect();
            self.update(best, &weights, phi);
            self.resize();
        }
        Ok(samples)
    }

    /// W <- resize E[W], tau <- E[tau] / resize.
    pub fn resize(&mut self) {
        let r = self.cfg.resize;
        self.w.iter_mut().for_each(|v| *v *= r);
        self.tau.iter_mut().for_each(|v| *v /= r);
    }

    /// The variational updates on `samples` with data weights `weights` (summing to 1, or all
    /// 0 for none), `inner` times in the order M, W, z, alpha, tau.
    pub fn update(&mut self, samples: &[Sample], weights: &[f64], phi: &TimeFeatures) {
        let (d, p, k, t_max) = (self.d, self.p, self.cfg.latent, phi.steps());
        let s: Vec<f64> = (0..t_max).map(|t| dot(phi.at(t), phi.at(t))).collect();
        let m_old = self.m.clone();
        // q(z): the sampled draws, unit covariance, to start.
        let mut mu_z: Vec<Vec<f64>> = samples.iter().map(|x| x.z.clone()).collect();
        let mut sigma_z: Vec<Vec<f64>> = vec![identity(k); t_max];
        // What the inner loop would otherwise recompute for every rollout (the same
        // arithmetic, done once: the results are bit for bit those of the direct loops):
        // M phi_t per action and step, and the tau step's per-step terms.
        let mut mphi = vec![0.0; d * t_max];
        for j in 0..d {
            for t in 0..t_max {
                mphi[j * t_max + t] = dot(&self.m[j * p..(j + 1) * p], phi.at(t));
            }
        }
        let (mut fsf, mut tr, mut wszw) = (vec![0.0; t_max], vec![0.0; t_max], vec![0.0; d * t_max]);
        let (mut tmp, mut zk, mut szw, mut rhs_z) = (vec![0.0; p], vec![0.0; k], vec![0.0; k], vec![0.0; k]);
        let priors = self.cfg.priors;
        let inv_s2 = if priors { 1.0 / self.cfg.sigma2 } else { 0.0 };
        // sum_t phi phi' / s: the same for every rollout, and the weights sum to 1 (or 0).
        let wsum: f64 = weights.iter().sum();
        let mut phiphi = vec![0.0; p * p];
        for t in 0..t_max {
            let f = phi.at(t);
            for a in 0..p {
                for b in 0..p {
                    phiphi[a * p + b] += wsum * f[a] * f[b] / s[t];
                }
            }
        }
        // sum_x w_x sum_t (mu_z mu_z' + Sigma_z) / s_t, refreshed after every z step.
        let mut zz = vec![0.0; k * k];
        for _ in 0..self.cfg.inner {
            zz.iter_mut().for_each(|v| *v = 0.0);
            for (wi, mz) in weights.iter().zip(&mu_z) {
                for (t, sz) in sigma_z.iter().enumerate() {
                    let z = &mz[t * k..(t + 1) * k];
                    let c = wi / s[t];
                    for a in 0..k {
                        for b in 0..k {
                            zz[a * k + b] += c * (z[a] * z[b] + sz[a * k + b]);
                        }
                    }
                }
            }
            for (g, idx) in self.groups.iter().enumerate() {
                let tau = self.tau[g];
                // q(M) (Eq. 2.19-2.21).
                let mut prec: Vec<f64> = phiphi.iter().map(|v| tau * v).collect();
                (0..p).for_each(|a| prec[a * p + a] += inv_s2);
                let Some(sig) = spd_inverse(&prec, p) else { continue };
                for &j in idx {
                    let mut rhs: Vec<f64> = m_old[j * p..(j + 1) * p].iter().map(|v| inv_s2 * v).collect();
                    let wj = &self.w[j * k..(j + 1) * k];
                    for (x, (wi, mz)) in samples.iter().zip(weights.iter().zip(&mu_z)) {
                        for t in 0..t_max {
                            let r = x.actions[t * d + j] - dot(wj, &mz[t * k..(t + 1) * k]);
                            let c = tau * wi * r / s[t];
                            rhs.iter_mut().zip(phi.at(t)).for_each(|(h, f)| *h += c * f);
                        }
                    }
                    matvec(&sig, p, p, &rhs, &mut self.m[j * p..(j + 1) * p]);
                    for t in 0..t_max {
                        mphi[j * t_max + t] = dot(&self.m[j * p..(j + 1) * p], phi.at(t));
                    }
                }
                self.sigma_m[g] = if priors { sig } else { vec![0.0; p * p] };
                // q(W) (Eq. 2.22-2.24, with the prior centre W-hat of Eq. 3.16): the precision
                // is tau times E[z z'] summed over the weighted data, the same for every group.
                let mut prec: Vec<f64> = zz.iter().map(|v| tau * v).collect();
                if priors {
                    (0..k).for_each(|a| prec[a * k + a] += self.alpha[g][a]);
                }
                let Some(sig) = spd_inverse(&prec, k) else { continue };
                for &j in idx {
                    let mut rhs: Vec<f64> = (0..k).map(|a| if priors { self.alpha[g][a] * self.w_hat[j * k + a] } else { 0.0 }).collect();
                    for (x, (wi, mz)) in samples.iter().zip(weights.iter().zip(&mu_z)) {
                        for t in 0..t_max {
                            let r = x.actions[t * d + j] - mphi[j * t_max + t];
                            let c = tau * wi * r / s[t];
                            rhs.iter_mut().zip(&mz[t * k..(t + 1) * k]).for_each(|(h, z)| *h += c * z);
                        }
                    }
                    matvec(&sig, k, k, &rhs, &mut self.w[j * k..(j + 1) * k]);
                }
                self.sigma_w[g] = if priors { sig } else { vec![0.0; k * k] };
            }
            // q(z) (Eq. 2.25-2.27), per rollout and step, not reward-weighted.
            let mut a = identity(k);
            for (g, idx) in self.groups.iter().enumerate() {
                for &j in idx {
                    let wj = &self.w[j * k..(j + 1) * k];
                    for r in 0..k {
                        for c in 0..k {
                            a[r * k + c] += self.tau[g] * (wj[r] * wj[c] + self.sigma_w[g][r * k + c]);
                        }
                    }
                }
            }
            let Some(a_inv) = spd_inverse(&a, k) else { continue };
            for (t, sz) in sigma_z.iter_mut().enumerate() {
                sz.iter_mut().zip(&a_inv).for_each(|(v, a)| *v = a * s[t]);
            }
            for (x, mz) in samples.iter().zip(mu_z.iter_mut()) {
                for t in 0..t_max {
                    rhs_z.iter_mut().for_each(|v| *v = 0.0);
                    for (g, idx) in self.groups.iter().enumerate() {
                        for &j in idx {
                            let r = x.actions[t * d + j] - mphi[j * t_max + t];
                            let c = self.tau[g] * r;
                            rhs_z.iter_mut().zip(&self.w[j * k..(j + 1) * k]).for_each(|(h, w)| *h += c * w);
                        }
                    }
                    matvec(&a_inv, k, k, &rhs_z, &mut mz[t * k..(t + 1) * k]);
                }
            }
            let mut gammas = vec![0.0; self.groups.len() * k];
            for (g, idx) in self.groups.iter().enumerate() {
                // q(alpha) (Eq. 2.15-2.17 with deviations from W-hat, Eq. 3.17); the log-linear
                // model is fitted to every group at once after this loop.
                let shape = self.cfg.a_alpha + idx.len() as f64 / 2.0;
                for c in 0..k {
                    let gamma: f64 =
                        idx.iter().map(|&j| (self.w[j * k + c] - self.w_hat[j * k + c]).powi(2) + self.sigma_w[g][c * k + c]).sum();
                    self.alpha[g][c] = shape / (self.cfg.b_alpha + 0.5 * gamma);
                    gammas[g * k + c] = gamma;
                }
                // q(tau) (Eq. 2.28-2.29): the expected squared residual, term by term.
                let (sm, sw) = (&self.sigma_m[g], &self.sigma_w[g]);
                // The terms that do not depend on the rollout: f' Sigma_M f, tr(Sigma_W
                // Sigma_z), w_j' Sigma_z w_j, per step.
                for t in 0..t_max {
                    let (f, sz) = (phi.at(t), &sigma_z[t]);
                    matvec(sm, p, p, f, &mut tmp);
                    fsf[t] = dot(f, &tmp);
                    tr[t] = (0..k).map(|r| (0..k).map(|c| sw[r * k + c] * sz[c * k + r]).sum::<f64>()).sum();
                    for &j in idx {
                        let wj = &self.w[j * k..(j + 1) * k];
                        matvec(sz, k, k, wj, &mut szw);
                        wszw[j * t_max + t] = dot(wj, &szw);
                    }
                }
                let mut b = 0.0;
                for (x, (wi, mz)) in samples.iter().zip(weights.iter().zip(&mu_z)) {
                    for t in 0..t_max {
                        let z = &mz[t * k..(t + 1) * k];
                        matvec(sw, k, k, z, &mut zk);
                        let z_sw_z = dot(z, &zk);
                        let mut e = 0.0;
                        for &j in idx {
                            let wj = &self.w[j * k..(j + 1) * k];
                            let r = x.actions[t * d + j] - dot(wj, z) - mphi[j * t_max + t];
                            e += r * r + wszw[j * t_max + t] + z_sw_z + tr[t] + fsf[t];
                        }
                        b += wi * e / s[t];
                    }
                }
                let (a_tau, b_tau) = if priors { (self.cfg.a_tau, self.cfg.b_tau) } else { (0.0, 0.0) };
                let shape = a_tau + 0.5 * idx.len() as f64 * t_max as f64 * wsum;
                if b > 0.0 || b_tau > 0.0 {
                    self.tau[g] = shape / (b_tau + 0.5 * b);
                }
            }
            // The log-linear alpha of ch. 3 (Eq. 3.4, 3.18-3.21), over every group at once.
            if priors && let Some(model) = self.alpha_model.as_mut() {
                let dims: Vec<usize> = self.groups.iter().map(Vec::len).collect();
                let alpha = model.fit(&dims, &gammas);
                for (g, row) in self.alpha.iter_mut().enumerate() {
                    row.copy_from_slice(&alpha[g * k..(g + 1) * k]);
                }
            }
        }
    }
}

fn identity(n: usize) -> Vec<f64> {
    let mut a = vec![0.0; n * n];
    (0..n).for_each(|i| a[i * n + i] = 1.0);
    a
}

#[cfg(test)]
mod tests;
