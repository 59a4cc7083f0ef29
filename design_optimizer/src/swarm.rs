//! What every design search shares: the batched objective it maximises, the box it searches,
//! its result and its per-iteration progress report.

use coadapt_core::BoxSpace;

/// A function to MAXIMISE, scored for a whole swarm of designs at once.
///
/// `designs` is `scores.len()` designs of the search's dimension, row-major; each score goes to
/// the same row of `scores`. A NaN score never becomes a best. Any
/// `FnMut(&[f32], &mut [f32])` closure is one; [`crate::CriticObjective`] adapts the batched
/// Eq. 5.6 [`crate::DesignObjective`].
pub trait SwarmObjective {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]);
}

impl<F: FnMut(&[f32], &mut [f32])> SwarmObjective for F {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]) {
        self(designs, scores)
    }
}

/// The outcome of a search.
#[derive(Clone, Debug, PartialEq)]
pub struct SearchResult {
    /// The best design scored (always inside the bounds).
    pub design: Vec<f32>,
    /// Its score.
    pub score: f32,
    /// The best score so far after each iteration (PSO) or generation (CMA-ES).
    pub history: Vec<f32>,
    /// Designs scored in all.
    pub evaluations: usize,
}

/// The state of a search after one iteration, for progress reports.
#[derive(Clone, Copy, Debug)]
pub struct Progress<'a> {
    /// 0-based iteration (PSO) or generation (CMA-ES).
    pub iteration: usize,
    /// Designs scored so far.
    pub evaluations: usize,
    /// The best score so far.
    pub best_score: f32,
    /// The best design so far.
    pub best: &'a [f32],
}

#[derive(Debug, thiserror::Error)]
pub enum SearchError {
    #[error("bounds: {0}")]
    Bounds(String),
    #[error("config: {0}")]
    Config(String),
}

/// Bounds a search can use: at least one dimension, every bound finite, `low <= high`
/// (`low == high` pins that coordinate).
pub(crate) fn check_bounds(bounds: &BoxSpace) -> Result<(), SearchError> {
    if bounds.dim() == 0 || bounds.low.len() != bounds.high.len() {
        return Err(SearchError::Bounds(format!("{} lower and {} upper bounds", bounds.low.len(), bounds.high.len())));
    }
    for (i, (lo, hi)) in bounds.low.iter().zip(&bounds.high).enumerate() {
        if !lo.is_finite() || !hi.is_finite() || lo > hi {
            return Err(SearchError::Bounds(format!("dimension {i}: [{lo}, {hi}] is not a finite interval")));
        }
    }
    Ok(())
}

/// A score as a maximisation key: NaN ranks below everything.
pub(crate) fn key(score: f32) -> f32 {
    if score.is_nan() { f32::NEG_INFINITY } else { score }
}
