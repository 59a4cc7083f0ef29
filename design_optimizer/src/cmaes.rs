//! CMA-ES: the standard `(mu/mu_w, lambda)` evolution strategy with cumulative step-size
//! adaptation and rank-one plus rank-mu covariance updates, exactly as in Hansen, "The CMA
//! Evolution Strategy: A Tutorial" (arXiv:1604.00772, Table 1 and Fig. 6, positive weights
//! only), maximising a [`SwarmObjective`] over a box. Each generation's `lambda` candidates are
//! scored in one batched call.
//!
//! The algorithm is the ask/tell state machine [`Cmaes`] (one generation per `ask` and `tell`,
//! the state persisting in between, as the ES baselines of [`crate::es`] run it, one generation
//! per design); [`maximise`] drives it to convergence.
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
use std::ops::ControlFlow;

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
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
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
pub(crate) fn reflect(u: f64) -> f64 {
    let t = u.rem_euclid(2.0);
    if t > 1.0 { 2.0 - t } else { t }
}

/// CMA-ES as an ask/tell state machine, one generation per [`Cmaes::ask`] and [`Cmaes::tell`]:
/// `ask` draws `lambda` candidates from the current distribution (reflected into the box),
/// the caller scores them, `tell` ranks them (a NaN score last) and updates the mean, the step
/// size, the evolution paths and the covariance. The state persists between calls, so the
/// strategy can run one generation each time a co-adaptation loop needs a design (Ha's
/// population-based ES baseline); [`maximise`] runs it to convergence instead.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Cmaes {
    p: Params,
    n: usize,
    lambda: usize,
    rng: coadapt_core::Rng64,
    low: Vec<f64>,
    high: Vec<f64>,
    width: Vec<f64>,
    /// Generations told so far.
    generation: usize,
    mean: Vec<f64>,
    sigma: f64,
    cov: Vec<f64>,
    /// C = B diag(d)^2 B^T; B row-major, column k the k-th eigenvector.
    b: Vec<f64>,
    d: Vec<f64>,
    p_sigma: Vec<f64>,
    p_c: Vec<f64>,
    /// The last asked generation's raw steps `y_k = B D z_k` (candidate `mean + sigma y_k`).
    ys: Vec<f64>,
    /// The same candidates in design units, reflected into the box.
    designs: Vec<f32>,
    /// Whether `designs` awaits its scores.
    asked: bool,
    /// False once an eigendecomposition of the covariance failed (sampling then keeps the last
    /// good one).
    eigen_ok: bool,
    order: Vec<usize>,
    z: Vec<f64>,
    y_w: Vec<f64>,
    tmp: Vec<f64>,
}

impl Cmaes {
    /// A strategy over `bounds` with `config`'s population and `sigma0` (its `generations` and
    /// `tol-x` are [`maximise`]'s); the mean starts at the box centre. The same `seed` gives
    /// the same candidates for the same scores.
    pub fn new(bounds: &BoxSpace, config: &CmaesConfig, seed: u64) -> Result<Self, SearchError> {
        check_bounds(bounds)?;
        let n = bounds.dim();
        let lambda = config.population.unwrap_or(4 + (3.0 * (n as f64).ln()).floor() as usize);
        if lambda < 2 {
            return Err(SearchError::Config(format!("cmaes: population {lambda} (need >= 2)")));
        }
        if !(config.sigma0.is_finite() && config.sigma0 > 0.0) {
            return Err(SearchError::Config(format!("cmaes: sigma0 {} must be > 0", config.sigma0)));
        }
        let low: Vec<f64> = bounds.low.iter().map(|&v| f64::from(v)).collect();
        let high: Vec<f64> = bounds.high.iter().map(|&v| f64::from(v)).collect();
        let width = bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| f64::from(hi - lo)).collect();
        Ok(Self {
            p: Params::new(n, lambda),
            n,
            lambda,
            rng: coadapt_core::rng(seed, CMAES_STREAM),
            low,
            high,
            width,
            generation: 0,
            mean: vec![0.5; n],
            sigma: config.sigma0,
            cov: identity(n),
            b: identity(n),
            d: vec![1.0; n],
            p_sigma: vec![0.0; n],
            p_c: vec![0.0; n],
            ys: vec![0.0; lambda * n],
            designs: vec![0.0; lambda * n],
            asked: false,
            eigen_ok: true,
            order: (0..lambda).collect(),
            z: vec![0.0; n],
            y_w: vec![0.0; n],
            tmp: vec![0.0; n],
        })
    }

    /// Candidates per generation.
    pub fn lambda(&self) -> usize {
        self.lambda
    }

    /// The design dimension.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Generations told so far.
    pub fn generation(&self) -> usize {
        self.generation
    }

    /// The step size, as a fraction of each dimension's width.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// The largest standard deviation of the search distribution as a fraction of the width,
    /// `sigma * max_i sqrt(C_ii)` ([`CmaesConfig::tol_x`] compares it); NaN or infinite if the
    /// strategy diverged.
    pub fn spread(&self) -> f64 {
        self.sigma * (0..self.n).map(|i| self.cov[i * self.n + i]).fold(0.0f64, f64::max).sqrt()
    }

    /// False once an eigendecomposition of the covariance failed (it then samples from the last
    /// good one; [`maximise`] stops).
    pub fn is_healthy(&self) -> bool {
        self.eigen_ok
    }

    /// The distribution's mean in design units, reflected into the box.
    pub fn mean_design(&self) -> Vec<f32> {
        (0..self.n).map(|i| self.to_design(self.mean[i], i)).collect()
    }

    fn to_design(&self, u: f64, i: usize) -> f32 {
        (self.low[i] + reflect(u) * self.width[i]).clamp(self.low[i], self.high[i]) as f32
    }

    /// Draws a new generation: `lambda` designs of [`Cmaes::dim`] values, row-major, each inside
    /// the box. A generation asked but not told is discarded.
    pub fn ask(&mut self) -> &[f32] {
        let n = self.n;
        for k in 0..self.lambda {
            for zi in self.z.iter_mut() {
                *zi = StandardNormal.sample(&mut self.rng);
            }
            for i in 0..n {
                let y: f64 = (0..n).map(|j| self.b[i * n + j] * self.d[j] * self.z[j]).sum();
                self.ys[k * n + i] = y;
                self.designs[k * n + i] = self.to_design(self.mean[i] + self.sigma * y, i);
            }
        }
        self.asked = true;
        &self.designs
    }

    /// Updates the distribution from the scores (higher is better, NaN ranks last) of the
    /// generation [`Cmaes::ask`] returned last.
    pub fn tell(&mut self, scores: &[f32]) -> Result<(), SearchError> {
        if !self.asked {
            return Err(SearchError::Config("cmaes: tell without a generation asked".into()));
        }
        if scores.len() != self.lambda {
            return Err(SearchError::Config(format!("cmaes: {} scores for {} candidates", scores.len(), self.lambda)));
        }
        self.asked = false;
        let (n, p) = (self.n, &self.p);
        let (b, d, ys) = (&self.b, &self.d, &self.ys);
        // (Ties keep the previous generation's order: the sort is stable.)
        self.order.sort_by(|&i, &j| key(scores[j]).total_cmp(&key(scores[i])));
        let order = &self.order;

        // Selection and recombination: m <- m + sigma y_w.
        let y_w = &mut self.y_w;
        y_w.fill(0.0);
        for (w, &k) in p.weights.iter().zip(order) {
            for i in 0..n {
                y_w[i] += w * ys[k * n + i];
            }
        }
        for i in 0..n {
            self.mean[i] += self.sigma * y_w[i];
        }
        // Step-size path: p_sigma <- (1 - c_s) p_sigma + sqrt(c_s (2 - c_s) mu_eff) C^{-1/2} y_w,
        // with C^{-1/2} = B D^{-1} B^T.
        for j in 0..n {
            self.tmp[j] = (0..n).map(|i| b[i * n + j] * y_w[i]).sum::<f64>() / d[j];
        }
        let cs = (p.c_sigma * (2.0 - p.c_sigma) * p.mu_eff).sqrt();
        for i in 0..n {
            self.p_sigma[i] = (1.0 - p.c_sigma) * self.p_sigma[i] + cs * (0..n).map(|j| b[i * n + j] * self.tmp[j]).sum::<f64>();
        }
        let ps_norm = self.p_sigma.iter().map(|v| v * v).sum::<f64>().sqrt();
        let g = self.generation as i32;
        let h_sigma = ps_norm / (1.0 - (1.0 - p.c_sigma).powi(2 * (g + 1))).sqrt() < (1.4 + 2.0 / (n as f64 + 1.0)) * p.chi_n;
        let cc = (p.c_c * (2.0 - p.c_c) * p.mu_eff).sqrt();
        for i in 0..n {
            self.p_c[i] = (1.0 - p.c_c) * self.p_c[i] + if h_sigma { cc * y_w[i] } else { 0.0 };
        }
        // Covariance: rank-one (p_c p_c^T) and rank-mu (sum w_i y_i y_i^T) updates.
        let delta_h = if h_sigma { 0.0 } else { p.c_c * (2.0 - p.c_c) };
        let keep = 1.0 - p.c_1 - p.c_mu + p.c_1 * delta_h;
        for i in 0..n {
            for j in 0..=i {
                let rank_mu: f64 = p.weights.iter().zip(order).map(|(w, &k)| w * ys[k * n + i] * ys[k * n + j]).sum();
                let c = keep * self.cov[i * n + j] + p.c_1 * self.p_c[i] * self.p_c[j] + p.c_mu * rank_mu;
                self.cov[i * n + j] = c;
                self.cov[j * n + i] = c;
            }
        }
        self.sigma *= ((p.c_sigma / p.d_sigma) * (ps_norm / p.chi_n - 1.0)).exp();
        self.generation += 1;
        // The next generation's B and D; on failure keep sampling from the last good ones.
        let (mut b, mut d) = (self.b.clone(), self.d.clone());
        if eigen(&self.cov, &mut b, &mut d) {
            (self.b, self.d) = (b, d);
        } else {
            self.eigen_ok = false;
        }
        Ok(())
    }
}

/// Maximises `objective` over `bounds`; the same `seed` gives the same result.
pub fn maximise(
    objective: &mut (impl SwarmObjective + ?Sized),
    bounds: &BoxSpace,
    config: &CmaesConfig,
    seed: u64,
) -> Result<SearchResult, SearchError> {
    maximise_with(objective, bounds, config, seed, |_| ControlFlow::Continue(()))
}

/// [`maximise`], calling `progress` after every generation; `ControlFlow::Break` ends the search
/// there with the best design so far.
///
/// It runs [`Cmaes`] for up to `config.generations` generations, stopping early once
/// [`Cmaes::spread`] falls below `config.tol_x` (or is not finite) or the covariance cannot be
/// decomposed, and reports the best design scored in any generation.
pub fn maximise_with(
    objective: &mut (impl SwarmObjective + ?Sized),
    bounds: &BoxSpace,
    config: &CmaesConfig,
    seed: u64,
    mut progress: impl FnMut(&Progress<'_>) -> ControlFlow<()>,
) -> Result<SearchResult, SearchError> {
    let tol_ok = config.tol_x >= 0.0; // false for NaN
    if config.generations == 0 || !tol_ok {
        return Err(SearchError::Config(format!(
            "cmaes: {} generations (need >= 1), tol-x {} (need >= 0)",
            config.generations, config.tol_x
        )));
    }
    let mut es = Cmaes::new(bounds, config, seed)?;
    let (n, lambda) = (es.dim(), es.lambda());
    let mut scores = vec![0.0f32; lambda];
    let mut best = vec![0.0f32; n];
    let mut best_score = f32::NEG_INFINITY;
    let mut history = Vec::with_capacity(config.generations);
    let mut evaluations = 0;

    for g in 0..config.generations {
        objective.evaluate(es.ask(), &mut scores);
        evaluations += lambda;
        es.tell(&scores)?;
        // The generation's best is the first the update ranked (a NaN never, unless all are).
        let top = es.order[0];
        if g == 0 || key(scores[top]) > best_score {
            best_score = key(scores[top]);
            best.copy_from_slice(&es.designs[top * n..(top + 1) * n]);
        }
        history.push(best_score);
        let go_on = progress(&Progress { iteration: g, evaluations, best_score, best: &best });
        let spread = es.spread();
        if go_on.is_break() || !es.is_healthy() || !spread.is_finite() || spread < config.tol_x {
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
