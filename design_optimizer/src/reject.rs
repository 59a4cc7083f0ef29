//! Designs an operator rejected as prototypes (`coadapt confirm --reject`): the optimiser's
//! next proposal must be a different body, not the same one again.
//!
//! "Near" is the Euclidean distance in box-normalised coordinates (each dimension divided by
//! its width, a pinned dimension ignored), so `optimizer.reject-radius = 0.05` keeps every new
//! design at least 5 % of the box's width (in that sense) away from every rejected one. The
//! searches over the critic see a rejected neighbourhood as scoring minus infinity
//! ([`Guarded`]), which PSO and CMA-ES rank below every finite score, so they settle on the best
//! design elsewhere: the critic's next-best.

use coadapt_core::BoxSpace;

use crate::SwarmObjective;

/// `random` drew `draws` designs and every one fell near a rejected design.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("{draws} random designs all fell within optimizer.reject-radius ({radius}) of a rejected design; lower the radius")]
pub struct AllRejected {
    pub draws: usize,
    pub radius: f32,
}

/// The rejected designs of a run, with the radius around each that no proposal may enter.
#[derive(Clone, Debug)]
pub struct Rejected {
    dim: usize,
    /// Per dimension `1 / width`, 0 for a pinned one.
    scale: Vec<f32>,
    designs: Vec<f32>,
    radius: f32,
}

impl Rejected {
    /// `designs` is `k x bounds.dim()`, row-major (a ragged tail is ignored; requests are
    /// validated before they get here).
    pub fn new(designs: &[f32], bounds: &BoxSpace, radius: f32) -> Self {
        let scale = bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| if hi > lo { 1.0 / (hi - lo) } else { 0.0 }).collect();
        let dim = bounds.dim();
        let whole = designs.len().checked_div(dim).map_or(0, |k| k * dim);
        Self { dim, scale, designs: designs[..whole].to_vec(), radius }
    }

    pub fn is_empty(&self) -> bool {
        self.designs.is_empty()
    }

    /// The box-normalised distance from `design` to the nearest rejected design (infinite when
    /// there is none).
    pub fn distance(&self, design: &[f32]) -> f32 {
        self.designs
            .chunks_exact(self.dim.max(1))
            .map(|r| r.iter().zip(design).zip(&self.scale).map(|((r, x), s)| ((x - r) * s).powi(2)).sum::<f32>().sqrt())
            .fold(f32::INFINITY, f32::min)
    }

    /// Whether `design` lies within the radius of a rejected design.
    pub fn near(&self, design: &[f32]) -> bool {
        self.distance(design) <= self.radius
    }

    /// `objective` with every design near a rejected one scoring minus infinity.
    pub fn guard<'a, O: SwarmObjective + ?Sized>(&'a self, objective: &'a mut O) -> Guarded<'a, O> {
        Guarded { rejected: self, inner: objective }
    }
}

/// An objective that scores designs near a rejected one minus infinity ([`Rejected::guard`]).
#[derive(Debug)]
pub struct Guarded<'a, O: ?Sized> {
    rejected: &'a Rejected,
    inner: &'a mut O,
}

impl<O: SwarmObjective + ?Sized> SwarmObjective for Guarded<'_, O> {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]) {
        self.inner.evaluate(designs, scores);
        if self.rejected.is_empty() {
            return;
        }
        for (s, d) in scores.iter_mut().zip(designs.chunks_exact(self.rejected.dim.max(1))) {
            if self.rejected.near(d) {
                *s = f32::NEG_INFINITY;
            }
        }
    }
}
