//! Population-based evolution strategies run one generation per design, the baselines of Ha,
//! "Reinforcement learning for improving agent design" (thesis 5.5.2): each time the
//! co-adaptation needs a new design, the strategy samples a population of candidate designs
//! around its current distribution, the caller scores them all in simulation (rollouts of the
//! current population policy) through one batched [`SwarmObjective`] call, the strategy makes
//! ONE update of its distribution, and the best candidate of that generation is the design
//! trained on next. The strategy's state persists from one design to the next.
//!
//! Two strategies share the [`AskTell`] interface: [`OpenAiEs`] (here; 256 candidates) and
//! [`Cmaes`] (Hansen's CMA-ES, [`crate::cmaes`]; lambda 9 for 6 dimensions).
//! [`one_generation`] is the whole baseline step over either.
//!
//! # OpenAI-ES
//!
//! Salimans et al., "Evolution Strategies as a Scalable Alternative to Reinforcement Learning"
//! (2017), with the settings of estool's `OpenES` (github.com/hardmaru/estool, `es.py`), the
//! library of Ha's experiments, whose defaults [`OpenAiEsConfig`] copies:
//!
//! - candidates `u_k = m + sigma eps_k`, `eps_k ~ N(0, I)`; antithetic (mirrored) sampling
//!   draws the first half and negates it for the second (`[eps, -eps]`, estool's order);
//! - fitness shaping: centred ranks, `rank / (population - 1) - 0.5` in `[-0.5, 0.5]` (ties
//!   share their mean rank, NaN ranks last), minus the weight decay
//!   `weight_decay * mean_i (u_ki - 0.5)^2`, then standardised to mean 0 and standard
//!   deviation 1 (a generation whose shaped fitness is constant, all ties, has zero gradient);
//! - the gradient estimate `g = sum_k F_k eps_k / (population sigma)` is ascended with estool's
//!   Adam (`beta1 = 0.99`, `beta2 = 0.999`, `epsilon = 1e-8`, bias-corrected step size);
//! - after each update `sigma <- sigma * sigma_decay` while `sigma > sigma_limit`, and the
//!   learning rate likewise.
//!
//! Adam's step is at most about the learning rate per coordinate, so with estool's 0.01 the mean
//! moves at most about 0.01 of the box width per generation (one generation per design): from
//! the box centre to a face takes at least 50 designs, and the momentum 0.99 overshoots. On the
//! weighted quadratics of `tests/es.rs` over the HalfCheetah box `[0.8, 2.0]^6`, the worst
//! coordinate error of the mean (design units, 20 seeds, over every generation from the one
//! named up to 1000):
//!
//! | strategy | optimum | from 100 | from 400 | from 600 |
//! |---|---|---|---|---|
//! | OpenAI-ES, estool's settings | inside | 0.15 | 0.036 | 0.015 |
//! | OpenAI-ES, estool's settings | a corner | 0.26 | 0.057 | 0.021 |
//! | OpenAI-ES, `adam-beta1 = 0.9` | inside | 0.10 | 0.020 | 0.012 |
//! | OpenAI-ES, `adam-beta1 = 0.9` | a corner | 0.012 | 0.0013 | 0.0013 |
//! | CMA-ES, lambda 9, `sigma0 = 0.3` | inside | 4e-4 | < 1e-4 | < 1e-4 |
//! | CMA-ES, lambda 9, `sigma0 = 0.3` | a corner | 8e-4 | < 1e-4 | < 1e-4 |
//!
//! (A learning rate of 0.05 is no faster: the momentum overshoots further.)
//!
//! **Coordinates and bounds** are CMA-ES's ([`crate::cmaes`]): the strategy runs in
//! box-normalised coordinates `u = (x - low) / width`, the mean starts at the box centre
//! `u = 0.5` (estool starts at the origin of its parameters, which the weight decay pulls
//! towards; here the decay pulls towards the centre, the starting point, so it favours no
//! face of the box), `sigma` is a fraction of each width, and each candidate is mapped into
//! the box by reflection at the bounds before it is scored. The strategy's own mean and samples
//! stay unbounded and the update sees the raw noise, so `f(reflect(u))` is what it climbs:
//! continuous, with a maximum on the boundary a peak it can settle on (clipping would make it
//! flat outside the box, a plateau on which a rank-based gradient has nothing to follow).

use coadapt_core::BoxSpace;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::cmaes::{Cmaes, reflect};
use crate::swarm::{SearchError, SearchResult, SwarmObjective, check_bounds, key};

/// The random stream of OpenAI-ES under a seed (`coadapt_core::rng(seed, OPENAI_ES_STREAM)`).
pub const OPENAI_ES_STREAM: u64 = 0x4f45_5300;

/// estool's Adam: the denominator's epsilon.
const ADAM_EPSILON: f64 = 1e-8;

/// OpenAI-ES settings; the defaults are estool's `OpenES` (the module documentation has the
/// algorithm), with the population of the thesis's baseline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct OpenAiEsConfig {
    /// Candidates per generation (256, the thesis's baseline and estool's default); even when
    /// `antithetic`.
    pub population: usize,
    /// Initial noise standard deviation, as a fraction of each dimension's width (estool's
    /// `sigma_init` 0.1).
    pub sigma: f64,
    /// Factor applied to `sigma` after each generation while it exceeds `sigma-limit`
    /// (estool: 0.999).
    pub sigma_decay: f64,
    /// `sigma` stops decaying once at or below this (estool: 0.01).
    pub sigma_limit: f64,
    /// Adam's step size, in box-normalised units (estool: 0.01): about the most the mean moves
    /// per coordinate per generation.
    pub learning_rate: f64,
    /// Factor applied to the learning rate after each generation while it exceeds
    /// `learning-rate-limit` (estool: 0.9999).
    pub learning_rate_decay: f64,
    /// The learning rate stops decaying once at or below this (estool: 0.001).
    pub learning_rate_limit: f64,
    /// Adam's first-moment (momentum) decay (estool: 0.99, where PyTorch's Adam has 0.9).
    pub adam_beta1: f64,
    /// Adam's second-moment decay (estool: 0.999).
    pub adam_beta2: f64,
    /// Mirrored sampling, `eps` and `-eps` (Salimans et al. 2017; estool's option, off by default
    /// there): halves the variance of the gradient estimate on smooth objectives.
    pub antithetic: bool,
    /// L2 penalty on each candidate's distance from the box centre, subtracted from its centred
    /// rank (estool: 0.01, there towards the origin of its parameters). 0 disables it.
    pub weight_decay: f64,
}

impl Default for OpenAiEsConfig {
    fn default() -> Self {
        Self {
            population: 256,
            sigma: 0.1,
            sigma_decay: 0.999,
            sigma_limit: 0.01,
            learning_rate: 0.01,
            learning_rate_decay: 0.9999,
            learning_rate_limit: 0.001,
            adam_beta1: 0.99,
            adam_beta2: 0.999,
            antithetic: true,
            weight_decay: 0.01,
        }
    }
}

/// An evolution strategy driven one generation at a time: [`AskTell::ask`] draws a population of
/// candidate designs, the caller scores them, [`AskTell::tell`] updates the distribution.
pub trait AskTell {
    /// Draws a new generation: [`AskTell::population`] designs of [`AskTell::dim`] values,
    /// row-major, each inside the box. A generation asked but not told is discarded.
    fn ask(&mut self) -> &[f32];
    /// Updates the distribution from the scores (higher is better, NaN ranks last) of the
    /// generation asked last; an error without one or for a wrong number of scores.
    fn tell(&mut self, scores: &[f32]) -> Result<(), SearchError>;
    /// The design dimension.
    fn dim(&self) -> usize;
    /// Candidates per generation.
    fn population(&self) -> usize;
    /// The distribution's mean in design units, inside the box.
    fn mean_design(&self) -> Vec<f32>;
    /// The whole state (distribution, generator, counters) as JSON, for the optimiser's state
    /// file.
    fn save(&self) -> Result<String, serde_json::Error>;
    /// Restores what [`AskTell::save`] returned.
    fn load(&mut self, v: &str) -> Result<(), serde_json::Error>;
}

/// One generation of `es` over `objective` (Ha's baseline step): asks, scores every candidate in
/// one batched call, tells, and returns the generation's best candidate (`history` is its score
/// alone, `evaluations` the population). A NaN score never wins unless all are NaN (then the
/// first candidate is returned with score `-inf`).
pub fn one_generation(es: &mut dyn AskTell, objective: &mut dyn SwarmObjective) -> Result<SearchResult, SearchError> {
    let (n, population) = (es.dim(), es.population());
    let mut scores = vec![0.0f32; population];
    let designs = es.ask();
    objective.evaluate(designs, &mut scores);
    let top = (1..population).fold(0, |t, k| if key(scores[k]) > key(scores[t]) { k } else { t });
    let design = designs[top * n..(top + 1) * n].to_vec();
    es.tell(&scores)?;
    let score = key(scores[top]);
    Ok(SearchResult { design, score, history: vec![score], evaluations: population })
}

/// OpenAI-ES (Salimans et al. 2017) as estool's `OpenES` runs it, as an ask/tell state machine in
/// box-normalised coordinates; the module documentation has the algorithm.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct OpenAiEs {
    config: OpenAiEsConfig,
    n: usize,
    rng: coadapt_core::Rng64,
    low: Vec<f64>,
    high: Vec<f64>,
    width: Vec<f64>,
    /// The mean, box-normalised and unbounded.
    mean: Vec<f64>,
    sigma: f64,
    learning_rate: f64,
    /// Adam's moments and its step count (generations told).
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
    /// The last asked generation's noise, `population x n`.
    eps: Vec<f64>,
    /// The same candidates in design units, reflected into the box.
    designs: Vec<f32>,
    asked: bool,
    fitness: Vec<f64>,
    order: Vec<usize>,
    gradient: Vec<f64>,
}

impl OpenAiEs {
    /// A strategy over `bounds` with its mean at the box centre; the same `seed` gives the same
    /// candidates for the same scores.
    pub fn new(bounds: &BoxSpace, config: &OpenAiEsConfig, seed: u64) -> Result<Self, SearchError> {
        check_bounds(bounds)?;
        let c = config;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let non_negative = |v: f64| v.is_finite() && v >= 0.0;
        let factor = |v: f64| v > 0.0 && v <= 1.0;
        if c.population < 2 || (c.antithetic && !c.population.is_multiple_of(2)) {
            return Err(SearchError::Config(format!("openai-es: population {} (need >= 2, and even when antithetic)", c.population)));
        }
        if !(positive(c.sigma) && positive(c.learning_rate) && factor(c.sigma_decay) && factor(c.learning_rate_decay)) {
            return Err(SearchError::Config(format!(
                "openai-es: sigma {} and learning-rate {} must be > 0, their decays {} and {} in (0, 1]",
                c.sigma, c.learning_rate, c.sigma_decay, c.learning_rate_decay
            )));
        }
        if !((0.0..1.0).contains(&c.adam_beta1) && (0.0..1.0).contains(&c.adam_beta2)) {
            return Err(SearchError::Config(format!(
                "openai-es: adam-beta1 {} and adam-beta2 {} must be in [0, 1)",
                c.adam_beta1, c.adam_beta2
            )));
        }
        if !(non_negative(c.sigma_limit) && non_negative(c.learning_rate_limit) && non_negative(c.weight_decay)) {
            return Err(SearchError::Config(format!(
                "openai-es: sigma-limit {}, learning-rate-limit {} and weight-decay {} must be >= 0",
                c.sigma_limit, c.learning_rate_limit, c.weight_decay
            )));
        }
        let n = bounds.dim();
        let low: Vec<f64> = bounds.low.iter().map(|&v| f64::from(v)).collect();
        let high: Vec<f64> = bounds.high.iter().map(|&v| f64::from(v)).collect();
        let width = bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| f64::from(hi - lo)).collect();
        Ok(Self {
            config: c.clone(),
            n,
            rng: coadapt_core::rng(seed, OPENAI_ES_STREAM),
            low,
            high,
            width,
            mean: vec![0.5; n],
            sigma: c.sigma,
            learning_rate: c.learning_rate,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
            eps: vec![0.0; c.population * n],
            designs: vec![0.0; c.population * n],
            asked: false,
            fitness: vec![0.0; c.population],
            order: (0..c.population).collect(),
            gradient: vec![0.0; n],
        })
    }

    /// Candidates per generation.
    pub fn lambda(&self) -> usize {
        self.config.population
    }

    /// Generations told so far.
    pub fn generation(&self) -> usize {
        self.t as usize
    }

    /// The current noise standard deviation, as a fraction of each width.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// The current learning rate.
    pub fn learning_rate(&self) -> f64 {
        self.learning_rate
    }

    /// The distribution's mean in design units, reflected into the box.
    pub fn mean_design(&self) -> Vec<f32> {
        (0..self.n).map(|i| self.to_design(self.mean[i], i)).collect()
    }

    fn to_design(&self, u: f64, i: usize) -> f32 {
        (self.low[i] + reflect(u) * self.width[i]).clamp(self.low[i], self.high[i]) as f32
    }

    /// Draws a new generation ([`AskTell::ask`]).
    pub fn ask(&mut self) -> &[f32] {
        let (n, pop) = (self.n, self.config.population);
        let drawn = if self.config.antithetic { pop / 2 } else { pop };
        for e in self.eps[..drawn * n].iter_mut() {
            *e = StandardNormal.sample(&mut self.rng);
        }
        for k in drawn..pop {
            for i in 0..n {
                self.eps[k * n + i] = -self.eps[(k - drawn) * n + i];
            }
        }
        for k in 0..pop {
            for i in 0..n {
                self.designs[k * n + i] = self.to_design(self.mean[i] + self.sigma * self.eps[k * n + i], i);
            }
        }
        self.asked = true;
        &self.designs
    }

    /// Updates the mean from the last generation's scores ([`AskTell::tell`]).
    pub fn tell(&mut self, scores: &[f32]) -> Result<(), SearchError> {
        let (n, pop) = (self.n, self.config.population);
        if !self.asked {
            return Err(SearchError::Config("openai-es: tell without a generation asked".into()));
        }
        if scores.len() != pop {
            return Err(SearchError::Config(format!("openai-es: {} scores for {pop} candidates", scores.len())));
        }
        self.asked = false;
        // Centred ranks, ascending, ties (NaNs among them) sharing their mean rank.
        for (k, o) in self.order.iter_mut().enumerate() {
            *o = k;
        }
        self.order.sort_by(|&i, &j| key(scores[i]).total_cmp(&key(scores[j])));
        let mut start = 0;
        while start < pop {
            let tied = key(scores[self.order[start]]);
            let end = (start..pop).find(|&r| key(scores[self.order[r]]).total_cmp(&tied).is_ne()).unwrap_or(pop);
            let rank = (start + end - 1) as f64 / 2.0;
            for &k in &self.order[start..end] {
                self.fitness[k] = rank / (pop - 1) as f64 - 0.5;
            }
            start = end;
        }
        // Weight decay towards the box centre, on the raw (unreflected) candidates.
        if self.config.weight_decay > 0.0 {
            for k in 0..pop {
                let sq: f64 = (0..n).map(|i| (self.mean[i] + self.sigma * self.eps[k * n + i] - 0.5).powi(2)).sum::<f64>() / n as f64;
                self.fitness[k] -= self.config.weight_decay * sq;
            }
        }
        // Standardise; the gradient estimate g = sum_k F_k eps_k / (population sigma).
        let mean_f = self.fitness.iter().sum::<f64>() / pop as f64;
        let std_f = (self.fitness.iter().map(|f| (f - mean_f).powi(2)).sum::<f64>() / pop as f64).sqrt();
        self.gradient.fill(0.0);
        if std_f > 0.0 && std_f.is_finite() {
            for k in 0..pop {
                let f = (self.fitness[k] - mean_f) / std_f;
                for i in 0..n {
                    self.gradient[i] += f * self.eps[k * n + i];
                }
            }
            for g in self.gradient.iter_mut() {
                *g /= pop as f64 * self.sigma;
            }
        }
        // estool's Adam, ascending.
        self.t += 1;
        let (beta1, beta2) = (self.config.adam_beta1, self.config.adam_beta2);
        let a = self.learning_rate * (1.0 - beta2.powi(self.t)).sqrt() / (1.0 - beta1.powi(self.t));
        for i in 0..n {
            let g = self.gradient[i];
            self.m[i] = beta1 * self.m[i] + (1.0 - beta1) * g;
            self.v[i] = beta2 * self.v[i] + (1.0 - beta2) * g * g;
            self.mean[i] += a * self.m[i] / (self.v[i].sqrt() + ADAM_EPSILON);
        }
        if self.sigma > self.config.sigma_limit {
            self.sigma *= self.config.sigma_decay;
        }
        if self.learning_rate > self.config.learning_rate_limit {
            self.learning_rate *= self.config.learning_rate_decay;
        }
        Ok(())
    }
}

impl AskTell for OpenAiEs {
    fn ask(&mut self) -> &[f32] {
        OpenAiEs::ask(self)
    }
    fn save(&self) -> Result<String, serde_json::Error> {
        // A string, not a `serde_json::Value`: the generator's state is a u128.
        serde_json::to_string(self)
    }
    fn load(&mut self, v: &str) -> Result<(), serde_json::Error> {
        *self = serde_json::from_str(v)?;
        Ok(())
    }
    fn tell(&mut self, scores: &[f32]) -> Result<(), SearchError> {
        OpenAiEs::tell(self, scores)
    }
    fn dim(&self) -> usize {
        self.n
    }
    fn population(&self) -> usize {
        self.config.population
    }
    fn mean_design(&self) -> Vec<f32> {
        OpenAiEs::mean_design(self)
    }
}

impl AskTell for Cmaes {
    fn ask(&mut self) -> &[f32] {
        Cmaes::ask(self)
    }
    fn save(&self) -> Result<String, serde_json::Error> {
        // A string, not a `serde_json::Value`: the generator's state is a u128.
        serde_json::to_string(self)
    }
    fn load(&mut self, v: &str) -> Result<(), serde_json::Error> {
        *self = serde_json::from_str(v)?;
        Ok(())
    }
    fn tell(&mut self, scores: &[f32]) -> Result<(), SearchError> {
        Cmaes::tell(self, scores)
    }
    fn dim(&self) -> usize {
        Cmaes::dim(self)
    }
    fn population(&self) -> usize {
        self.lambda()
    }
    fn mean_design(&self) -> Vec<f32> {
        Cmaes::mean_design(self)
    }
}
