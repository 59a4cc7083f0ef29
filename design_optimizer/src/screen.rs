//! Critic-screened rollouts (issue 28 section 3; beyond the thesis): the critic proposes, a
//! few short rollouts decide.
//!
//! FEAR trusts the critic's best design outright (0 rollouts); the simulation baseline
//! ignores the critic and spends 1,050 rollouts of the population policy per design. Between
//! the two: PSO over Eq. 5.6 as FEAR runs it, but every design the swarm scores is remembered,
//! and the best `candidates` of them that lie at least `separation` apart (box-normalised
//! Euclidean distance; greedy, best first, so the first is FEAR's own answer) each get
//! `rollouts` rollouts of at most `steps` steps with the population policy, all candidates
//! from the same reset seeds so that they are compared on the same start states. The
//! candidate with the highest mean return is chosen. `candidates x rollouts` is the dial from
//! FEAR (1 candidate: no rollout at all) towards the simulation baseline.
//!
//! The return over a fixed number of steps, not the mean reward per step of the simulation
//! baselines: a body that falls (Walker, Hopper end the episode) has fewer steps to earn from,
//! and that should count against it.

use serde::{Deserialize, Serialize};

use crate::SwarmObjective;

/// The settings of `exploit = "screened"`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct ScreenConfig {
    /// Candidates the critic proposes (1 = FEAR, no rollouts).
    pub candidates: usize,
    /// Rollouts per candidate, from the same reset seeds for every candidate.
    pub rollouts: usize,
    /// Steps per rollout at most (0: the whole episode).
    pub steps: usize,
    /// Least box-normalised distance between two candidates (0.1 = a tenth of the box).
    pub separation: f32,
}

impl Default for ScreenConfig {
    fn default() -> Self {
        Self { candidates: 4, rollouts: 2, steps: 250, separation: 0.1 }
    }
}

/// A setting of `[optimizer.screen]` that cannot work; the message names its key.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum ScreenConfigError {
    #[error("optimizer.screen.candidates: 0; at least 1 (1 is FEAR without rollouts)")]
    NoCandidates,
    /// Several candidates and no rollout to choose between them.
    #[error("optimizer.screen.rollouts: 0 cannot decide between {candidates} candidates; at least 1")]
    NoRollouts { candidates: usize },
    #[error("optimizer.screen.separation: {0} is not a finite number >= 0")]
    Separation(f32),
}

impl ScreenConfig {
    pub fn check(&self) -> Result<(), ScreenConfigError> {
        if self.candidates == 0 {
            return Err(ScreenConfigError::NoCandidates);
        }
        if self.candidates > 1 && self.rollouts == 0 {
            return Err(ScreenConfigError::NoRollouts { candidates: self.candidates });
        }
        if !(self.separation.is_finite() && self.separation >= 0.0) {
            return Err(ScreenConfigError::Separation(self.separation));
        }
        Ok(())
    }

    /// Rollouts per design request.
    pub fn budget(&self) -> usize {
        if self.candidates > 1 { self.candidates * self.rollouts } else { 0 }
    }
}

/// An objective that remembers every design it scores and its score.
#[derive(Debug)]
pub struct Recorded<'a, O: ?Sized> {
    inner: &'a mut O,
    pub designs: Vec<f32>,
    pub scores: Vec<f32>,
}

impl<'a, O: SwarmObjective + ?Sized> Recorded<'a, O> {
    pub fn new(inner: &'a mut O) -> Self {
        Self { inner, designs: Vec::new(), scores: Vec::new() }
    }
}

impl<O: SwarmObjective + ?Sized> SwarmObjective for Recorded<'_, O> {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]) {
        self.inner.evaluate(designs, scores);
        self.designs.extend_from_slice(designs);
        self.scores.extend_from_slice(scores);
    }
}

/// The best `k` of the scored `designs` (`scores.len() x dim`) that are pairwise at least
/// `separation` apart in box-normalised distance (`scale` = 1 / width per dimension, 0 for a
/// pinned one): greedy, best score first, so the first is the best design scored. Designs
/// scoring NaN or minus infinity are never picked. Fewer than `k` when the scored designs
/// are not that spread out.
pub fn diverse_best(designs: &[f32], scores: &[f32], dim: usize, scale: &[f32], k: usize, separation: f32) -> Vec<Vec<f32>> {
    let mut order: Vec<usize> = (0..scores.len()).filter(|&i| scores[i].is_finite()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    let mut picked: Vec<Vec<f32>> = Vec::with_capacity(k);
    for i in order {
        if picked.len() == k {
            break;
        }
        let d = &designs[i * dim..(i + 1) * dim];
        let far = picked.iter().all(|p| {
            let d2: f32 = p.iter().zip(d).zip(scale).map(|((a, b), s)| ((a - b) * s).powi(2)).sum();
            d2.sqrt() >= separation
        });
        if far {
            picked.push(d.to_vec());
        }
    }
    picked
}
