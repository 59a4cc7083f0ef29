//! A conservative design critic (beyond the thesis, issue 28 section 3), after COMs
//! (Trabucco, Kumar, Geng, Levine, "Conservative Objective Models for Effective Offline
//! Model-Based Optimization", ICML 2021): a model searched for its best input is driven to
//! inputs far from the data where it is wrong and high. COMs trains the model to be low there:
//!
//!   L(theta) = L_regression(theta) + lambda (E_{x ~ mu_theta}[f_theta(x)] - E_{x ~ D}[f_theta(x)]),
//!
//! where mu_theta is where a few steps of gradient ascent on f_theta from the data's inputs end
//! (held fixed in the gradient). For FEAR the model is a population critic Q(s, a, xi) and the
//! search is over the design xi: from each batch row `(s, a, xi)` the design alone climbs
//! `steps` normalised steps of `step` box widths uphill on Q (clamped to the box), giving
//! `xi'`; the critic's gradient gains lambda (grad mean Q(s, a, xi') - grad mean Q(s, a, xi)).
//! So the critic is pushed down where its own search would go and up on the bodies trained,
//! which is what the design optimiser's PSO over Q (Eq. 5.6) exploits. As in COMs, lambda is a
//! Lagrange multiplier, not a constant: dual ascent on log lambda grows it while the gap is
//! above tau (`limit`, in standard deviations of Q over the batch; 0 by default) and shrinks it
//! below, so the term holds the search's optimism at tau instead of pushing Q down without end
//! (a fixed lambda drove the gap to -200 on Hopper). Unlike COMs the step is a plain gradient
//! step on the excess in sd units, not Adam's (see [`ConservativeConfig::weight_lr`]).
//!
//! The term trains the population pair's ensemble heads only (`learner.population-critics`
//! above 2), which regress on the twin's Bellman target and which the optimiser's
//! `q = "heads"` scores designs with; the twin, the policy and every action stay FEAR's. A
//! first form put it on the twin critics themselves (runs `*-conservative`, EXPERIMENTS 5.13):
//! there the term's push entered the critics' own bootstrapped targets (compounding to about
//! lambda / (2 (1 - gamma)) in Q) and the policies trained on those critics learnt worse from
//! the first body on. A head with the twin's target carries the push once and acts on nothing.

use std::ops::Range;

use coadapt_nn::{Activations, Mlp};
use serde::{Deserialize, Serialize};

use crate::networks::resize;

/// `[learner.conservative]`: the conservative term on the population ensemble heads; off by
/// default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct ConservativeConfig {
    /// lambda, the weight of the term against the regression loss at the start; 0 (the default)
    /// turns the term off, else within [0.001, 100] (the dual ascent's bounds). With `weight-lr`
    /// above 0 it then follows the dual ascent.
    pub weight: f32,
    /// tau, how far the adversarial designs' mean Q may sit above the trained designs' before
    /// the weight grows, in standard deviations of the head's Q over the batch's trained rows.
    /// 0 (the default): no lead at all, the one setting free of Q's units, which differ by
    /// robot (single digits on Hopper, hundreds on HalfCheetah). COMs allows 0.5 sd of its
    /// normalised scores, but its sd is over designs; over a batch's rows Q's spread is mostly
    /// the states', so 0.5 of it lets the search's lead grow to a third of a design's score
    /// before the term acts (seen on Walker and Hopper: the weight fell from 1 to under 1e-4 by
    /// the end of design 3 while the search's lead still grew).
    pub limit: f32,
    /// Step size of the dual ascent on log lambda: each population update adds `weight-lr`
    /// (gap / sd - limit), so lambda grows while the search's lead is above tau, in proportion
    /// to the excess, and shrinks below it, within [0.001, 100]. 0.05 doubles lambda over an
    /// episode's 250 updates at a lead of 5 % of an sd. 0 keeps lambda at `weight`, a fixed push
    /// that grows the gap without bound (a first form did: -200 Q below the data on Hopper
    /// within 3 designs).
    pub weight_lr: f32,
    /// Gradient-ascent steps from each batch row's design to its adversarial design.
    pub steps: usize,
    /// Length of each step, in box widths (the design normalised to [0, 1] per coordinate). With
    /// `steps` the reach: 5 x 0.1 = half the box from each trained body, enough to reach the
    /// edges PSO over Q goes to from bodies spread over the box. Each step is one more forward
    /// and input-backward pass of each population critic on the batch.
    pub step: f32,
}

impl Default for ConservativeConfig {
    fn default() -> Self {
        Self { weight: 0.0, steps: 5, step: 0.1, limit: 0.0, weight_lr: 0.05 }
    }
}

impl ConservativeConfig {
    /// The settings that cannot work, named as a config file spells them.
    pub fn check(&self) -> Result<(), crate::ConfigError> {
        let bad = |field: &str, why: String| Err(crate::ConfigError::Invalid(format!("learner.conservative.{field}: {why}")));
        if !(self.weight == 0.0 || (MIN_WEIGHT..=MAX_WEIGHT).contains(&self.weight)) {
            return bad("weight", format!("{} is neither 0 (off) nor in [{MIN_WEIGHT}, {MAX_WEIGHT}]", self.weight));
        }
        if self.weight > 0.0 && self.steps == 0 {
            return bad("steps", "0 steps leave the designs where the data is: the term would be 0".into());
        }
        if !(self.step.is_finite() && self.step > 0.0 && self.step <= 1.0) {
            return bad("step", format!("{} is not in (0, 1] box widths", self.step));
        }
        if !self.limit.is_finite() {
            return bad("limit", format!("{} is not a finite number of standard deviations", self.limit));
        }
        if !(self.weight_lr.is_finite() && self.weight_lr >= 0.0) {
            return bad("weight-lr", format!("{} is not a finite number >= 0", self.weight_lr));
        }
        Ok(())
    }

    /// The term for critics whose input rows hold the design in columns `design`, over the box
    /// `low`..`high`, at lambda = `weight`; `None` at weight 0 (FEAR's critic).
    pub fn on_box(&self, design: Range<usize>, low: &[f32], high: &[f32]) -> Option<Conservative> {
        (self.weight > 0.0).then(|| Conservative {
            log_weight: self.weight.clamp(MIN_WEIGHT, MAX_WEIGHT).ln(),
            cfg: self.clone(),
            design,
            low: low.to_vec(),
            high: high.to_vec(),
        })
    }
}

/// Bounds of lambda under dual ascent: the term never quite off, and never so heavy that the
/// heads' regression on the twin's target stops counting (a head held flat over designs by a
/// weight of 5e8 fits nothing else).
pub const MIN_WEIGHT: f32 = 1e-3;
pub const MAX_WEIGHT: f32 = 100.0;

/// The term as one critic applies it: the settings and where the design sits in a critic's
/// input row (`[state, design, action]`: the observation is the state with the design
/// appended), with the design box.
#[derive(Clone, Debug, PartialEq)]
pub struct Conservative {
    /// The settings (`cfg.weight` is lambda at the start).
    pub cfg: ConservativeConfig,
    /// log lambda now, the dual ascent's state ([`Self::dual_step`]).
    pub log_weight: f32,
    /// Columns of the design in a critic input row.
    pub design: Range<usize>,
    pub low: Vec<f32>,
    pub high: Vec<f32>,
}

/// Scratch of one critic's conservative term (no allocation once warm).
#[derive(Clone, Debug, Default)]
pub struct ConservativeWork {
    /// Rows `[x_data; x_adv]`.
    x: Vec<f32>,
    dx: Vec<f32>,
    dy: Vec<f32>,
    act: Activations,
    /// d(term)/d(theta).
    pub grad: Vec<f32>,
}

impl Conservative {
    /// Writes the adversarial rows into the second half of `work.x` (the first half a copy of
    /// `x_data`): each row's design climbs `steps` steps of `step` box widths along the
    /// normalised gradient of `Q_theta` with respect to the design (in box units), clamped to
    /// the box; the state and action columns stay the data's.
    pub fn adversary(&self, critic: &Mlp, theta: &[f32], x_data: &[f32], rows: usize, work: &mut ConservativeWork) {
        let w = critic.n_in();
        resize(&mut work.x, 2 * rows * w);
        resize(&mut work.dx, rows * w);
        resize(&mut work.dy, 2 * rows);
        let (data, adv) = work.x.split_at_mut(rows * w);
        data.copy_from_slice(x_data);
        adv.copy_from_slice(x_data);
        work.dy[..rows].fill(1.0);
        for _ in 0..self.cfg.steps {
            critic.forward(theta, adv, rows, &mut work.act);
            critic.backward_deltas(theta, &mut work.act, 0..rows, &work.dy[..rows], Some(&mut work.dx));
            for (row, g) in adv.chunks_exact_mut(w).zip(work.dx.chunks_exact(w)) {
                // dQ/du for the design in box units u = (xi - low) / (high - low).
                let norm = self
                    .design
                    .clone()
                    .zip(self.low.iter().zip(&self.high))
                    .map(|(c, (lo, hi))| (g[c] * (hi - lo)).powi(2))
                    .sum::<f32>()
                    .sqrt();
                if !(norm > 0.0 && norm.is_finite()) {
                    continue;
                }
                for (c, (lo, hi)) in self.design.clone().zip(self.low.iter().zip(&self.high)) {
                    let du = self.cfg.step * g[c] * (hi - lo) / norm;
                    row[c] = (row[c] + du * (hi - lo)).clamp(*lo, *hi);
                }
            }
        }
    }

    /// After [`Self::adversary`]: `weight (mean_b Q(x_adv_b) - mean_b Q(x_data_b))` (the
    /// adversarial rows held fixed) and its gradient with respect to theta in `work.grad`.
    /// Returns the gap `mean Q(x_adv) - mean Q(x_data)` (unweighted; COMs watches it) and the
    /// standard deviation of Q over the data rows (the scale of [`ConservativeConfig::limit`]).
    pub fn gradient(&self, critic: &Mlp, theta: &[f32], rows: usize, work: &mut ConservativeWork) -> (f32, f32) {
        resize(&mut work.grad, critic.n_params());
        let q = critic.forward(theta, &work.x, 2 * rows, &mut work.act);
        let gap = (q[rows..].iter().sum::<f32>() - q[..rows].iter().sum::<f32>()) / rows as f32;
        let mean = q[..rows].iter().map(|&v| f64::from(v)).sum::<f64>() / rows as f64;
        let sd = (q[..rows].iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / rows as f64).sqrt() as f32;
        let k = self.weight() / rows as f32;
        work.dy[..rows].fill(-k);
        work.dy[rows..].fill(k);
        critic.backward(theta, &work.x, &mut work.act, 0..2 * rows, &work.dy, Some(&mut work.grad), None);
        (gap, sd)
    }

    /// lambda now.
    pub fn weight(&self) -> f32 {
        self.log_weight.exp()
    }

    /// The dual step after an update whose term had `gap` and data-row spread `sd` (from
    /// [`Self::gradient`]): a plain gradient step on log lambda, `weight-lr` (gap / sd - limit),
    /// within the bounds, so lambda moves in proportion to the search's excess lead. (COMs steps
    /// log lambda with Adam, whose steps keep their size however small the excess; with
    /// tau = 0 a head held flat by the term leads by rounding noise, and Adam drove lambda up
    /// by 0.01 a step to 5e8.) Nothing moves with `weight-lr` 0 or a spread of 0.
    pub fn dual_step(&mut self, gap: f32, sd: f32) {
        if self.cfg.weight_lr > 0.0 && sd > 0.0 {
            let excess = gap / sd - self.cfg.limit;
            self.log_weight = (self.log_weight + self.cfg.weight_lr * excess).clamp(MIN_WEIGHT.ln(), MAX_WEIGHT.ln());
        }
    }

    /// The adversarial rows of the last [`Self::adversary`] (`rows x n_in`).
    pub fn adversarial_rows<'a>(&self, work: &'a ConservativeWork, rows: usize, n_in: usize) -> &'a [f32] {
        &work.x[rows * n_in..2 * rows * n_in]
    }
}
