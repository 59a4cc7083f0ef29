//! Novelty search, thesis Eq. 5.7: the next exploratory design maximises the mean Euclidean
//! distance to its `m` nearest neighbours among the designs chosen so far,
//! `max_xi (1/m) sum_{xi' in NN(xi, Xi)} ||xi - xi'||_2`, optimised with the same PSO as the
//! design objective (the novelty score is a [`SwarmObjective`] too).
//!
//! The thesis does not give `m`; the default is 5, the number of initial designs, so the first
//! exploratory design is scored against all of them. With fewer than `m` chosen designs, all
//! of them count. Distances are measured in box-normalised coordinates by default (each
//! dimension divided by its width), so a wide dimension does not dominate the novelty.

use coadapt_core::BoxSpace;
use serde::{Deserialize, Serialize};

use crate::pso::{self, BoundHandling, PsoConfig};
use crate::swarm::{Progress, SearchError, SearchResult, SwarmObjective, check_bounds};

/// Novelty-search settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct NoveltyConfig {
    /// m: nearest chosen designs whose mean distance is the novelty.
    pub neighbours: usize,
    /// Measure distances with each dimension divided by its width (false: in design units).
    pub normalise: bool,
    /// The PSO that maximises the novelty: the reference's swarm, with the `clamp` bound rule
    /// (novelty peaks on the box's faces and corners, far from the chosen designs, and clamping
    /// reaches them; the public reference has no novelty search to follow).
    pub pso: PsoConfig,
}

impl Default for NoveltyConfig {
    fn default() -> Self {
        Self { neighbours: 5, normalise: true, pso: PsoConfig { bounds: BoundHandling::Clamp, ..PsoConfig::default() } }
    }
}

/// The novelty score of Eq. 5.7 against a fixed set of chosen designs, as a swarm objective.
#[derive(Clone, Debug)]
pub struct Novelty {
    dim: usize,
    m: usize,
    /// Per-dimension scale: `1 / width` (normalised) or 1.
    scale: Vec<f32>,
    /// The chosen designs, scaled.
    chosen: Vec<f32>,
    /// Distances from one design to every chosen one.
    distances: Vec<f32>,
}

impl Novelty {
    /// `chosen` is `k x bounds.dim()` designs, row-major (at least one).
    pub fn new(chosen: &[f32], bounds: &BoxSpace, neighbours: usize, normalise: bool) -> Result<Self, SearchError> {
        check_bounds(bounds)?;
        let dim = bounds.dim();
        if chosen.is_empty() || !chosen.len().is_multiple_of(dim) || chosen.iter().any(|v| !v.is_finite()) {
            return Err(SearchError::Config(format!("novelty: {} values are not one or more finite designs of {dim}", chosen.len())));
        }
        if neighbours == 0 {
            return Err(SearchError::Config("novelty: neighbours must be at least 1".into()));
        }
        let scale: Vec<f32> =
            bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| if normalise && hi > lo { 1.0 / (hi - lo) } else { 1.0 }).collect();
        let chosen: Vec<f32> =
            chosen.chunks_exact(dim).flat_map(|c| c.iter().zip(&scale).map(|(v, s)| v * s).collect::<Vec<_>>()).collect();
        let k = chosen.len() / dim;
        Ok(Self { dim, m: neighbours.min(k), scale, chosen, distances: vec![0.0; k] })
    }

    /// The novelty of one design.
    pub fn score(&mut self, design: &[f32]) -> f32 {
        for (dist, c) in self.distances.iter_mut().zip(self.chosen.chunks_exact(self.dim)) {
            *dist = design.iter().zip(c).zip(&self.scale).map(|((x, c), s)| (x * s - c) * (x * s - c)).sum::<f32>().sqrt();
        }
        if self.m < self.distances.len() {
            self.distances.select_nth_unstable_by(self.m - 1, f32::total_cmp);
        }
        self.distances[..self.m].iter().sum::<f32>() / self.m as f32
    }
}

impl SwarmObjective for Novelty {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]) {
        for (s, x) in scores.iter_mut().zip(designs.chunks_exact(self.dim)) {
            *s = self.score(x);
        }
    }
}

/// The most novel design in `bounds` with respect to `chosen` (`k x dim`, row-major), found by
/// PSO; `score` is its novelty (in normalised units when `config.normalise`).
pub fn most_novel(chosen: &[f32], bounds: &BoxSpace, config: &NoveltyConfig, seed: u64) -> Result<SearchResult, SearchError> {
    most_novel_with(chosen, bounds, config, seed, |_| std::ops::ControlFlow::Continue(()))
}

/// [`most_novel`], calling `progress` after every PSO iteration.
pub fn most_novel_with(
    chosen: &[f32],
    bounds: &BoxSpace,
    config: &NoveltyConfig,
    seed: u64,
    progress: impl FnMut(&Progress<'_>) -> std::ops::ControlFlow<()>,
) -> Result<SearchResult, SearchError> {
    let mut novelty = Novelty::new(chosen, bounds, config.neighbours, config.normalise)?;
    pso::maximise_with(&mut novelty, bounds, &config.pso, seed, progress)
}
