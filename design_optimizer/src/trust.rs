//! A trust region around the designs trained so far (issue 28 section 3; beyond the thesis).
//!
//! Where the population critic has seen few bodies it extrapolates, and upwards more often
//! than not: FEAR's chosen coordinates gather at the box's faces far from every design tried
//! (EXPERIMENTS 5.7d). The trust region lets a search over the critic look only where the
//! critic has data: within a radius of some design already trained on, the radius growing
//! with the number of designs seen,
//!
//! `r(n) = trust-radius * (n / 5)^trust-growth`   (box-normalised Euclidean distance),
//!
//! so the region is small at the first chosen design (after the five random ones of the
//! reference schedule) and covers the whole box once enough bodies have been trained.
//!
//! A design outside the region is *projected* onto it (moved along the line towards its
//! nearest trained design until it is `r` from it) before it is scored, and the search's
//! answer is projected the same way. Scoring outside designs minus infinity instead would
//! leave almost the whole swarm without a score at the start (in six dimensions five balls of
//! radius 0.2 fill 0.2 % of the box); projection gives every particle the score of a design
//! the region allows. The segment from a design in the box to a trained design in the box
//! stays in the box (it is convex), so a projected design is always a valid body.

use coadapt_core::BoxSpace;

use crate::SwarmObjective;

/// The designs seen so far and the radius around them, in box-normalised coordinates.
#[derive(Clone, Debug)]
pub struct TrustRegion {
    dim: usize,
    low: Vec<f32>,
    /// Per dimension the box's width (0 for a pinned one).
    width: Vec<f32>,
    /// The trained designs, box-normalised (`k x dim`).
    centres: Vec<f32>,
    radius: f32,
}

/// The number of designs at which the radius is `trust-radius` (the reference's random
/// designs before the first chosen one).
pub const REFERENCE_DESIGNS: f32 = 5.0;

impl TrustRegion {
    /// The region around `seen` (`k x bounds.dim()`, row-major) with
    /// `r = radius * (k / 5)^growth`; `None` when `radius` is 0 (no region) or nothing has been
    /// seen yet (the first design has no data to stay near).
    pub fn new(seen: &[f32], bounds: &BoxSpace, radius: f32, growth: f32) -> Option<Self> {
        let dim = bounds.dim();
        let k = seen.len().checked_div(dim).unwrap_or(0);
        if radius <= 0.0 || k == 0 {
            return None;
        }
        let width: Vec<f32> = bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| (hi - lo).max(0.0)).collect();
        let norm = |v: f32, d: usize| if width[d] > 0.0 { (v - bounds.low[d]) / width[d] } else { 0.0 };
        let centres = seen[..k * dim].chunks_exact(dim).flat_map(|c| c.iter().enumerate().map(|(d, &v)| norm(v, d))).collect();
        let radius = radius * (k as f32 / REFERENCE_DESIGNS).powf(growth);
        Some(Self { dim, low: bounds.low.clone(), width, centres, radius })
    }

    /// The radius at this number of designs.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Moves `design` (in design units) into the region, in place: unchanged when it is within
    /// the radius of a trained design, else pulled towards the nearest one until it is on the
    /// radius.
    pub fn project(&self, design: &mut [f32]) {
        let dim = self.dim;
        let mut best = (f32::INFINITY, 0);
        for (i, c) in self.centres.chunks_exact(dim).enumerate() {
            let mut d2 = 0.0;
            for d in 0..dim {
                if self.width[d] > 0.0 {
                    let u = (design[d] - self.low[d]) / self.width[d];
                    d2 += (u - c[d]).powi(2);
                }
            }
            if d2 < best.0 {
                best = (d2, i);
            }
        }
        let dist = best.0.sqrt();
        if dist <= self.radius {
            return;
        }
        let c = &self.centres[best.1 * dim..(best.1 + 1) * dim];
        let t = self.radius / dist;
        for d in 0..dim {
            if self.width[d] > 0.0 {
                let u = (design[d] - self.low[d]) / self.width[d];
                let projected = c[d] + (u - c[d]) * t;
                design[d] = self.low[d] + projected * self.width[d];
            }
        }
    }

    /// `objective` scoring every design at its projection into the region.
    pub fn wrap<'a, O: SwarmObjective + ?Sized>(&'a self, objective: &'a mut O) -> Projected<'a, O> {
        Projected { region: self, inner: objective, buffer: Vec::new() }
    }
}

/// An objective that scores each design at its projection into a [`TrustRegion`]
/// ([`TrustRegion::wrap`]).
#[derive(Debug)]
pub struct Projected<'a, O: ?Sized> {
    region: &'a TrustRegion,
    inner: &'a mut O,
    /// The projected swarm (allocated at the first call, reused after).
    buffer: Vec<f32>,
}

impl<O: SwarmObjective + ?Sized> SwarmObjective for Projected<'_, O> {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]) {
        self.buffer.clear();
        self.buffer.extend_from_slice(designs);
        for d in self.buffer.chunks_exact_mut(self.region.dim.max(1)) {
            self.region.project(d);
        }
        self.inner.evaluate(&self.buffer, scores);
    }
}
