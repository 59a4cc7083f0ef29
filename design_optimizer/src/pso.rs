//! Global-best Particle Swarm Optimisation (Kennedy and Eberhart 1995) that maximises a
//! [`SwarmObjective`] over a box, as pyswarms' `GlobalBestPSO` does, which the reference FEAR
//! implementation calls with 700 particles, 250 iterations and `c1 = 0.5, c2 = 0.3, w = 0.9`.
//!
//! Each iteration (pyswarms' order):
//! 1. score the whole swarm in one batched call;
//! 2. update each particle's personal best `p_i` and the global best `g`;
//! 3. `v_i <- w v_i + c1 r1 (p_i - x_i) + c2 r2 (g - x_i)` with `r1, r2 ~ U[0, 1)` drawn per
//!    particle and per coordinate, then `x_i <- x_i + v_i`, then the bound rule
//!    ([`BoundHandling`]: clamping by default). The last iteration skips step 3 (pyswarms
//!    moves the swarm once more but never scores it), so a run scores exactly
//!    `particles x iterations` designs.
//!
//! Positions start uniform in the box. Velocities start as pyswarms starts them when no
//! velocity clamp is given, each coordinate uniform in `[0, 1)` design units (positive only,
//! whatever the bounds): `init-velocity = [0, 1]`; `[0, 0]` starts the swarm at rest.
//!
//! All buffers are allocated once per run; an iteration allocates nothing.

use coadapt_core::BoxSpace;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;

use crate::swarm::{Progress, SearchError, SearchResult, SwarmObjective, check_bounds, key};

/// The random stream of PSO under a seed (`coadapt_core::rng(seed, PSO_STREAM)`).
pub const PSO_STREAM: u64 = 0x0050_534f;

/// What happens to a coordinate that a velocity step takes out of the box.
///
/// The default is [`BoundHandling::Periodic`], the reference's rule as far as it can be told.
/// Its requirements pin no pyswarms version; its call passes 0.x's `print_step` and `verbose`
/// arguments, but its objective is written `f_qval(x_input, **kwargs)`, which is what pyswarms
/// 1.x needs (1.x forwards unknown `optimize` arguments such as `print_step` to the objective,
/// and an objective without `**kwargs` raises), and the code was published in October 2019,
/// when `pip install pyswarms` gave 1.1 (0.4.0 was January 2019, 1.1.0 May 2019). So the
/// reference most likely ran 1.x's default `periodic` wrap. [`BoundHandling::Hold`] is 0.x's
/// rule; [`BoundHandling::Clamp`] is ours (an option, not the reference).
///
/// How the rules differ, with the reference settings (700 x 250, pyswarms' initial velocities)
/// on a weighted quadratic over the HalfCheetah box `[0.8, 2.0]^6`, over 20 seeds (worst
/// coordinate error of the returned design):
///
/// | optimum | Clamp | Periodic | Hold |
/// |---|---|---|---|
/// | inside, 0.03 from a bound | 6e-8 | 0.04 | 0.05 |
/// | outside (answer on the boundary) | 0 | 0.32 | 0.75 |
///
/// A wrapped particle re-enters at the far side with its velocity still pointing out of the
/// box and keeps looping, and a held particle is stuck short of the wall until its velocity
/// turns inwards, so neither settles near a bound. Clamping puts the particle on the bound and
/// zeroes the offending velocity, so the swarm converges there: it finds a boundary optimum
/// exactly, and it also parks particles on faces and corners wherever a learned critic
/// extrapolates upwards past the data, which is where FEAR's designs ended up under clamping
/// (docs/EXPERIMENTS.md counts chosen designs on a face or corner under each rule). The
/// inertia 0.9 and initial speeds up to one design unit overshoot the 1.2-wide box often
/// enough for the rule to matter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BoundHandling {
    /// pyswarms' `nearest`, plus a velocity reset: the coordinate is clamped to the bound it
    /// crossed and its velocity set to zero, so the particle does not keep pushing outwards.
    Clamp,
    /// pyswarms 1.x's default `periodic`: the box tiles space; `x < low` becomes
    /// `high - (low - x) mod width` and `x > high` becomes `low + (x - high) mod width`.
    /// The velocity is unchanged.
    #[default]
    Periodic,
    /// pyswarms 0.x's rule: a particle whose step would leave the box in any coordinate stays
    /// where it is (all coordinates), keeping its velocity for the next update.
    Hold,
}

/// PSO settings; the defaults are the reference's (DESIGN.md section 2; the bound rule as
/// [`BoundHandling`] argues).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct PsoConfig {
    /// Swarm size.
    pub particles: usize,
    /// Iterations; each scores the whole swarm once.
    pub iterations: usize,
    /// Cognitive coefficient c1: pull towards each particle's own best.
    pub c1: f32,
    /// Social coefficient c2: pull towards the swarm's best.
    pub c2: f32,
    /// Inertia weight w.
    pub w: f32,
    /// Initial velocity range `[lo, hi]` in design units, each coordinate uniform in it;
    /// pyswarms' `[0, 1]` by default.
    pub init_velocity: [f32; 2],
    /// What happens to a step that leaves the box: `clamp`, `periodic` or `hold`.
    pub bounds: BoundHandling,
}

impl Default for PsoConfig {
    fn default() -> Self {
        Self { particles: 700, iterations: 250, c1: 0.5, c2: 0.3, w: 0.9, init_velocity: [0.0, 1.0], bounds: BoundHandling::Periodic }
    }
}

impl PsoConfig {
    fn check(&self) -> Result<(), SearchError> {
        let bad = |why: String| Err(SearchError::Config(format!("pso: {why}")));
        if self.particles == 0 || self.iterations == 0 {
            return bad(format!("{} particles x {} iterations", self.particles, self.iterations));
        }
        if ![self.c1, self.c2, self.w].iter().all(|c| c.is_finite()) {
            return bad(format!("c1 {}, c2 {}, w {} are not all finite", self.c1, self.c2, self.w));
        }
        let [lo, hi] = self.init_velocity;
        if !lo.is_finite() || !hi.is_finite() || lo > hi {
            return bad(format!("init-velocity [{lo}, {hi}] is not a finite interval"));
        }
        Ok(())
    }
}

/// Maximises `objective` over `bounds`; the same `seed` gives the same result.
pub fn maximise(
    objective: &mut (impl SwarmObjective + ?Sized),
    bounds: &BoxSpace,
    config: &PsoConfig,
    seed: u64,
) -> Result<SearchResult, SearchError> {
    maximise_with(objective, bounds, config, seed, |_| ControlFlow::Continue(()))
}

/// [`maximise`], calling `progress` after every iteration; `ControlFlow::Break` ends the search
/// there with the best design so far (a client that cancelled).
pub fn maximise_with(
    objective: &mut (impl SwarmObjective + ?Sized),
    bounds: &BoxSpace,
    config: &PsoConfig,
    seed: u64,
    mut progress: impl FnMut(&Progress<'_>) -> ControlFlow<()>,
) -> Result<SearchResult, SearchError> {
    check_bounds(bounds)?;
    config.check()?;
    let (n, dim) = (config.particles, bounds.dim());
    let (low, high) = (&bounds.low, &bounds.high);
    let mut rng = coadapt_core::rng(seed, PSO_STREAM);

    let mut x = vec![0.0f32; n * dim];
    for xi in x.chunks_exact_mut(dim) {
        bounds.sample(&mut rng, xi);
    }
    let [v_lo, v_hi] = config.init_velocity;
    let mut v: Vec<f32> = (0..n * dim).map(|_| if v_lo < v_hi { rng.random_range(v_lo..v_hi) } else { v_lo }).collect();
    let mut scores = vec![0.0f32; n];
    let mut pbest = x.clone();
    let mut pbest_score = vec![f32::NEG_INFINITY; n];
    let mut gbest = x[..dim].to_vec();
    let mut gbest_score = f32::NEG_INFINITY;
    let mut history = Vec::with_capacity(config.iterations);
    let mut previous = vec![0.0f32; dim];

    for it in 0..config.iterations {
        objective.evaluate(&x, &mut scores);
        for i in 0..n {
            let s = key(scores[i]);
            if s > pbest_score[i] {
                pbest_score[i] = s;
                pbest[i * dim..(i + 1) * dim].copy_from_slice(&x[i * dim..(i + 1) * dim]);
            }
        }
        // The first particle with the highest personal best (numpy's argmin, on costs).
        let mut best_i = None;
        for i in 0..n {
            if pbest_score[i] > best_i.map_or(gbest_score, |j: usize| pbest_score[j]) {
                best_i = Some(i);
            }
        }
        if let Some(i) = best_i {
            gbest_score = pbest_score[i];
            gbest.copy_from_slice(&pbest[i * dim..(i + 1) * dim]);
        }
        history.push(gbest_score);
        let go_on = progress(&Progress { iteration: it, evaluations: (it + 1) * n, best_score: gbest_score, best: &gbest });
        if it + 1 == config.iterations || go_on.is_break() {
            break;
        }

        for ((xi, vi), pi) in x.chunks_exact_mut(dim).zip(v.chunks_exact_mut(dim)).zip(pbest.chunks_exact(dim)) {
            previous.copy_from_slice(xi);
            let mut left = false;
            for d in 0..dim {
                let (r1, r2): (f32, f32) = (rng.random(), rng.random());
                vi[d] = config.w * vi[d] + config.c1 * r1 * (pi[d] - xi[d]) + config.c2 * r2 * (gbest[d] - xi[d]);
                xi[d] += vi[d];
                let (lo, hi) = (low[d], high[d]);
                if xi[d] >= lo && xi[d] <= hi {
                    continue;
                }
                match config.bounds {
                    BoundHandling::Periodic => xi[d] = wrap(xi[d], lo, hi),
                    BoundHandling::Clamp => {
                        xi[d] = xi[d].clamp(lo, hi);
                        vi[d] = 0.0;
                    }
                    BoundHandling::Hold => left = true,
                }
            }
            if left {
                xi.copy_from_slice(&previous);
            }
        }
    }
    Ok(SearchResult { design: gbest, score: gbest_score, history, evaluations: n * config.iterations })
}

/// pyswarms' periodic rule for one coordinate outside `[lo, hi]` (or non-finite).
fn wrap(x: f32, lo: f32, hi: f32) -> f32 {
    let width = hi - lo;
    if !x.is_finite() || width <= 0.0 {
        return lo;
    }
    let y = if x < lo { hi - (lo - x).rem_euclid(width) } else { lo + (x - hi).rem_euclid(width) };
    // Rounding can leave `y` an ulp outside.
    y.clamp(lo, hi)
}
