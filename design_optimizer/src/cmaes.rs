//! CMA-ES: the standard `(mu/mu_w, lambda)` evolution strategy with cumulative step-size
//! adaptation and rank-one plus rank-mu covariance updates, exactly as in Hansen, "The CMA
//! Evolution Strategy: A Tutorial" (arXiv:1604.00772, Table 1 and Fig. 6, positive weights
//! only), maximising a [`SwarmObjective`] over a box. Each generation's `lambda` candidates are
//! scored in one batched call.
//!
//! **Coordinates.** The strategy runs in box-normalised coordinates, `u = (x - low) / width`
//! per dimension, so one step size fits boxes of unequal widths: the initial mean is the box
//! centre (`u = 0.5`) and the initial step size `sigma0` is a fraction of each width.
//!
//! **Bounds: reflection.** The strategy's own state (mean, samples, paths) is unbounded; each
//! candidate `u` is mapped into `[0, 1]` by reflection at the bounds (the triangle wave of
//! period 2: `t = u mod 2`, `t > 1 -> 2 - t`) before it is scored, and that reflected design is
//! what is scored and reported. So every scored design is feasible, the sample distribution
//! stays Gaussian (the update sees the raw samples, as for an unconstrained problem), and
//! `f(reflect(u))` is continuous with its maxima exactly at the box's maxima: a maximum on the
//! boundary becomes a (kinked) peak the strategy converges on. Clamping instead would make
//! `f(clamp(u))` flat outside the box, a plateau on which the mean drifts; resampling would
//! truncate the Gaussian and bias the paths. pycma's default `BoundTransform` is a smoothed
//! version of the same idea.
//!
//! **Eigendecomposition** of the covariance every generation with faer's self-adjoint solver
//! (`Mat::self_adjoint_eigen`), in f64: `C = B D^2 B^T`. It allocates two `n x n` matrices per
//! generation, nothing next to a batched objective call.

use coadapt_core::BoxSpace;
use faer::{Mat, Side};
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::swarm::{Progress, SearchError, SearchResult, SwarmObjective, check_bounds, key};

/// The random stream of CMA-ES under a seed (`coadapt_core::rng(seed, CMAES_STREAM)`).
pub const CMAES_STREAM: u64 = 0x434d_4145;

/// CMA-ES settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct CmaesConfig {
    /// Candidates per generation, lambda; `None` is Hansen's default `4 + floor(3 ln n)`: 9 for
    /// the 6 HalfCheetah design parameters, the reference's CMA-ES baseline population.
    pub population: Option<usize>,
    /// Generations at most; each scores `lambda` candidates in one batched call.
    pub generations: usize,
    /// Initial step size as a fraction of each dimension's width.
    pub sigma0: f64,
    /// Stop once the largest standard deviation of the search distribution, as a fraction of
    /// the width (`sigma * max_i sqrt(C_ii)`), falls below this. 0 runs every generation.
    pub tol_x: f64,
}

impl Default for CmaesConfig {
    fn default() -> Self {
        Self { population: None, generations: 1000, sigma0: 0.3, tol_x: 1e-7 }
    }
}

/// Hansen's default parameters for dimension `n` and population `lambda`.
#[derive(Clone, Debug)]
struct Params {
    weights: Vec<f64>,
    mu_eff: f64,
    c_sigma: f64,
    d_sigma: f64,
    c_c: f64,
    c_1: f64,
    c_mu: f64,
    /// E||N(0, I)||.
    chi_n: f64,
}

impl Params {
    fn new(n: usize, lambda: usize) -> Self {
        let nf = n as f64;
        let mu = lambda / 2;
        let raw: Vec<f64> = (1..=mu).map(|i| ((lambda as f64 + 1.0) / 2.0).ln() - (i as f64).ln()).collect();
        let total: f64 = raw.iter().sum();
        let weights: Vec<f64> = raw.iter().map(|w| w / total).collect();
        let mu_eff = 1.0 / weights.iter().map(|w| w * w).sum::<f64>();
        let c_sigma = (mu_eff + 2.0) / (nf + mu_eff + 5.0);
        let d_sigma = 1.0 + 2.0 * (((mu_eff - 1.0) / (nf + 1.0)).sqrt() - 1.0).max(0.0) + c_sigma;
        let c_c = (4.0 + mu_eff / nf) / (nf + 4.0 + 2.0 * mu_eff / nf);
        let c_1 = 2.0 / ((nf + 1.3).powi(2) + mu_eff);
        let c_mu = (1.0 - c_1).min(2.0 * (mu_eff - 2.0 + 1.0 / mu_eff) / ((nf + 2.0).powi(2) + mu_eff));
        let chi_n = nf.sqrt() * (1.0 - 1.0 / (4.0 * nf) + 1.0 / (21.0 * nf * nf));
        Self { weights, mu_eff, c_sigma, d_sigma, c_c, c_1, c_mu, chi_n }
    }
}

/// Maps an unbounded normalised coordinate into `[0, 1]` by reflection at 0 and 1.
fn reflect(u: f64) -> f64 {
    let t = u.rem_euclid(2.0);
    if t > 1.0 { 2.0 - t } else { t }
}

/// Maximises `objective` over `bounds`; the same `seed` gives the same result.
pub fn maximise(
    objective: &mut (impl SwarmObjective + ?Sized),
    bounds: &BoxSpace,
    config: &CmaesConfig,
    seed: u64,
) -> Result<SearchResult, SearchError> {
    maximise_with(objective, bounds, config, seed, |_| {})
}

/// [`maximise`], calling `progress` after every generation.
pub fn maximise_with(
    objective: &mut (impl SwarmObjective + ?Sized),
    bounds: &BoxSpace,
    config: &CmaesConfig,
    seed: u64,
    mut progress: impl FnMut(&Progress<'_>),
) -> Result<SearchResult, SearchError> {
    check_bounds(bounds)?;
    let n = bounds.dim();
    let lambda = config.population.unwrap_or(4 + (3.0 * (n as f64).ln()).floor() as usize);
    if lambda < 2 || config.generations == 0 {
        return Err(SearchError::Config(format!("cmaes: population {lambda} (need >= 2) x {} generations", config.generations)));
    }
    let tol_ok = config.tol_x >= 0.0; // false for NaN
    if !(config.sigma0.is_finite() && config.sigma0 > 0.0 && tol_ok) {
        return Err(SearchError::Config(format!("cmaes: sigma0 {} must be > 0 and tol-x {} >= 0", config.sigma0, config.tol_x)));
    }
    let p = Params::new(n, lambda);
    let mut rng = coadapt_core::rng(seed, CMAES_STREAM);
    let width: Vec<f64> = bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| f64::from(hi - lo)).collect();
    let to_design = |u: f64, d: usize| -> f32 {
        (f64::from(bounds.low[d]) + reflect(u) * width[d]).clamp(f64::from(bounds.low[d]), f64::from(bounds.high[d])) as f32
    };

    let mut mean = vec![0.5f64; n];
    let mut sigma = config.sigma0;
    let mut cov = identity(n);
    // C = B diag(D)^2 B^T; B row-major, column k the k-th eigenvector.
    let mut b = identity(n);
    let mut d = vec![1.0f64; n];
    let (mut p_sigma, mut p_c) = (vec![0.0f64; n], vec![0.0f64; n]);
    let mut z = vec![0.0f64; n];
    let mut ys = vec![0.0f64; lambda * n];
    let mut designs = vec![0.0f32; lambda * n];
    let mut scores = vec![0.0f32; lambda];
    let mut order: Vec<usize> = (0..lambda).collect();
    let (mut y_w, mut tmp) = (vec![0.0f64; n], vec![0.0f64; n]);
    let mut best = designs[..n].to_vec();
    let mut best_score = f32::NEG_INFINITY;
    let mut history = Vec::with_capacity(config.generations);
    let mut evaluations = 0;

    for g in 0..config.generations {
        if g > 0 && !eigen(&cov, &mut b, &mut d) {
            break;
        }
        for k in 0..lambda {
            for zi in z.iter_mut() {
                *zi = StandardNormal.sample(&mut rng);
            }
            let y = &mut ys[k * n..(k + 1) * n];
            for i in 0..n {
                y[i] = (0..n).map(|j| b[i * n + j] * d[j] * z[j]).sum();
                designs[k * n + i] = to_design(mean[i] + sigma * y[i], i);
            }
        }
        objective.evaluate(&designs, &mut scores);
        evaluations += lambda;
        order.sort_by(|&i, &j| key(scores[j]).total_cmp(&key(scores[i])));
        if key(scores[order[0]]) > best_score {
            best_score = key(scores[order[0]]);
            best.copy_from_slice(&designs[order[0] * n..(order[0] + 1) * n]);
        }
        history.push(best_score);
        progress(&Progress { iteration: g, evaluations, best_score, best: &best });

        // Selection and recombination: m <- m + sigma y_w.
        y_w.fill(0.0);
        for (w, &k) in p.weights.iter().zip(&order) {
            for i in 0..n {
                y_w[i] += w * ys[k * n + i];
            }
        }
        for i in 0..n {
            mean[i] += sigma * y_w[i];
        }
        // Step-size path: p_sigma <- (1 - c_s) p_sigma + sqrt(c_s (2 - c_s) mu_eff) C^{-1/2} y_w,
        // with C^{-1/2} = B D^{-1} B^T.
        for j in 0..n {
            tmp[j] = (0..n).map(|i| b[i * n + j] * y_w[i]).sum::<f64>() / d[j];
        }
        let cs = (p.c_sigma * (2.0 - p.c_sigma) * p.mu_eff).sqrt();
        for i in 0..n {
            p_sigma[i] = (1.0 - p.c_sigma) * p_sigma[i] + cs * (0..n).map(|j| b[i * n + j] * tmp[j]).sum::<f64>();
        }
        let ps_norm = p_sigma.iter().map(|v| v * v).sum::<f64>().sqrt();
        let h_sigma = ps_norm / (1.0 - (1.0 - p.c_sigma).powi(2 * (g as i32 + 1))).sqrt() < (1.4 + 2.0 / (n as f64 + 1.0)) * p.chi_n;
        let cc = (p.c_c * (2.0 - p.c_c) * p.mu_eff).sqrt();
        for i in 0..n {
            p_c[i] = (1.0 - p.c_c) * p_c[i] + if h_sigma { cc * y_w[i] } else { 0.0 };
        }
        // Covariance: rank-one (p_c p_c^T) and rank-mu (sum w_i y_i y_i^T) updates.
        let delta_h = if h_sigma { 0.0 } else { p.c_c * (2.0 - p.c_c) };
        let keep = 1.0 - p.c_1 - p.c_mu + p.c_1 * delta_h;
        for i in 0..n {
            for j in 0..=i {
                let rank_mu: f64 = p.weights.iter().zip(&order).map(|(w, &k)| w * ys[k * n + i] * ys[k * n + j]).sum();
                let c = keep * cov[i * n + j] + p.c_1 * p_c[i] * p_c[j] + p.c_mu * rank_mu;
                cov[i * n + j] = c;
                cov[j * n + i] = c;
            }
        }
        sigma *= ((p.c_sigma / p.d_sigma) * (ps_norm / p.chi_n - 1.0)).exp();
        let spread = sigma * (0..n).map(|i| cov[i * n + i]).fold(0.0f64, f64::max).sqrt();
        if !spread.is_finite() || spread < config.tol_x {
            break;
        }
    }
    Ok(SearchResult { design: best, score: best_score, history, evaluations })
}

fn identity(n: usize) -> Vec<f64> {
    (0..n * n).map(|k| if k / n == k % n { 1.0 } else { 0.0 }).collect()
}

/// `C = B diag(d)^2 B^T` (row-major `n x n`); false when the decomposition fails or is not
/// finite. Eigenvalues are floored at `1e-20` times the largest, keeping `C^{-1/2}` finite.
fn eigen(cov: &[f64], b: &mut [f64], d: &mut [f64]) -> bool {
    let n = d.len();
    let c = Mat::<f64>::from_fn(n, n, |i, j| cov[i * n + j]);
    let Ok(evd) = c.self_adjoint_eigen(Side::Lower) else { return false };
    let (u, s) = (evd.U(), evd.S().column_vector());
    let top = (0..n).map(|k| s[k]).fold(0.0f64, f64::max);
    if !(top.is_finite() && top > 0.0) {
        return false;
    }
    for k in 0..n {
        d[k] = s[k].max(1e-20 * top).sqrt();
        for i in 0..n {
            b[i * n + k] = u[(i, k)];
        }
    }
    b.iter().all(|v| v.is_finite())
}
