#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

//! The population-based ES baselines, one generation per call as the co-adaptation runs them:
//! OpenAI-ES (estool's settings, 256 candidates) and CMA-ES (lambda 9) converge on weighted
//! quadratics over the HalfCheetah design box with the optimum inside and at a corner;
//! `one_generation` returns the generation's best, inside the box, never a NaN; the same seed
//! gives the same candidates.
//!
//! Tolerances are stated per test with the worst error measured over seeds 0..20 (release
//! build): the largest coordinate error, in design units, of the distribution's mean over every
//! generation from the one tested up to generation 1000.

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::{AskTell, Cmaes, CmaesConfig, OpenAiEs, OpenAiEsConfig, SearchError, one_generation};

/// `-sum_i w_i (x_i - c_i)^2`, in f64.
fn quadratic(c: [f64; 6]) -> impl FnMut(&[f32], &mut [f32]) {
    move |designs: &[f32], scores: &mut [f32]| {
        for (s, x) in scores.iter_mut().zip(designs.chunks_exact(6)) {
            *s = -x.iter().zip(&c).zip(&WEIGHTS).map(|((x, c), w)| w * (f64::from(*x) - c).powi(2)).sum::<f64>() as f32;
        }
    }
}

fn max_error(x: &[f32], target: &[f64]) -> f64 {
    x.iter().zip(target).map(|(a, b)| (f64::from(*a) - b).abs()).fold(0.0, f64::max)
}

/// The HalfCheetah design box.
fn design_box() -> BoxSpace {
    BoxSpace::uniform(6, 0.8, 2.0)
}

fn in_box(x: &[f32], b: &BoxSpace) -> bool {
    x.iter().zip(b.low.iter().zip(&b.high)).all(|(v, (lo, hi))| lo <= v && v <= hi)
}

const WEIGHTS: [f64; 6] = [1.0, 2.0, 0.5, 3.0, 1.5, 0.7];
/// An optimum well inside the design box (at least 0.15 from every bound).
const INSIDE: [f64; 6] = [1.1, 1.0, 1.73, 1.41, 1.6, 0.95];
/// An optimum outside the box in every coordinate: the answer is the corner `CORNER`.
const BEYOND_CORNER: [f64; 6] = [2.6, 0.3, 2.4, 0.5, 3.0, 0.2];
const CORNER: [f64; 6] = [2.0, 0.8, 2.0, 0.8, 2.0, 0.8];

fn openai_es(seed: u64) -> OpenAiEs {
    OpenAiEs::new(&design_box(), &OpenAiEsConfig::default(), seed).unwrap()
}

fn cmaes(seed: u64) -> Cmaes {
    Cmaes::new(&design_box(), &CmaesConfig::default(), seed).unwrap()
}

/// Runs `generations` calls of `one_generation`, checking each result, and returns the mean.
fn run(es: &mut dyn AskTell, optimum: [f64; 6], generations: usize) -> Vec<f32> {
    let b = design_box();
    let mut f = quadratic(optimum);
    for _ in 0..generations {
        let r = one_generation(es, &mut f).unwrap();
        assert!(in_box(&r.design, &b), "{:?}", r.design);
        assert_eq!((r.evaluations, r.history.as_slice()), (es.population(), [r.score].as_slice()));
    }
    es.mean_design()
}

#[test]
fn default_config_is_estools_openes_with_256_candidates_and_parses_from_kebab_case_toml() {
    let c = OpenAiEsConfig::default();
    assert_eq!((c.population, c.sigma, c.sigma_decay, c.sigma_limit), (256, 0.1, 0.999, 0.01));
    assert_eq!((c.learning_rate, c.learning_rate_decay, c.learning_rate_limit), (0.01, 0.9999, 0.001));
    assert_eq!((c.adam_beta1, c.adam_beta2, c.antithetic, c.weight_decay), (0.99, 0.999, true, 0.01));
    let c: OpenAiEsConfig = toml::from_str("population = 64\nlearning-rate = 0.02\nantithetic = false\nweight-decay = 0.0").unwrap();
    assert_eq!((c.population, c.learning_rate, c.antithetic, c.weight_decay, c.sigma), (64, 0.02, false, 0.0, 0.1));
    assert!(toml::from_str::<OpenAiEsConfig>("learning_rate = 0.02").is_err(), "unknown fields are rejected");
    // The CMA-ES baseline: Hansen's default lambda for 6 dimensions.
    assert_eq!(cmaes(0).lambda(), 9);
    assert_eq!(AskTell::population(&openai_es(0)), 256);
    assert_eq!(AskTell::dim(&openai_es(0)), 6);
}

#[test]
fn invalid_configs_and_calls_are_errors() {
    let b = design_box();
    let bad = [
        OpenAiEsConfig { population: 255, ..OpenAiEsConfig::default() }, // odd, antithetic
        OpenAiEsConfig { population: 1, antithetic: false, ..OpenAiEsConfig::default() },
        OpenAiEsConfig { sigma: 0.0, ..OpenAiEsConfig::default() },
        OpenAiEsConfig { learning_rate: f64::NAN, ..OpenAiEsConfig::default() },
        OpenAiEsConfig { sigma_decay: 1.5, ..OpenAiEsConfig::default() },
        OpenAiEsConfig { adam_beta1: 1.0, ..OpenAiEsConfig::default() },
        OpenAiEsConfig { weight_decay: -0.1, ..OpenAiEsConfig::default() },
    ];
    for c in &bad {
        assert!(matches!(OpenAiEs::new(&b, c, 0), Err(SearchError::Config(_))), "{c:?}");
    }
    assert!(OpenAiEs::new(&b, &OpenAiEsConfig { population: 255, antithetic: false, ..OpenAiEsConfig::default() }, 0).is_ok());
    assert!(matches!(OpenAiEs::new(&BoxSpace::uniform(0, 0.0, 1.0), &OpenAiEsConfig::default(), 0), Err(SearchError::Bounds(_))));
    assert!(Cmaes::new(&b, &CmaesConfig { population: Some(1), ..CmaesConfig::default() }, 0).is_err());

    // tell needs a generation asked, and one score per candidate.
    let (mut oes, mut cma) = (openai_es(0), cmaes(0));
    for es in [&mut oes as &mut dyn AskTell, &mut cma] {
        let n = es.population();
        assert!(es.tell(&vec![0.0; n]).is_err(), "tell before ask");
        es.ask();
        assert!(es.tell(&vec![0.0; n - 1]).is_err(), "too few scores");
        es.tell(&vec![0.0; n]).unwrap();
        assert!(es.tell(&vec![0.0; n]).is_err(), "the generation was told already");
    }
}

#[test]
fn openai_es_converges_on_an_optimum_inside_the_box_one_generation_at_a_time() {
    // estool's settings move the mean at most about 0.01 of the width per generation, and the
    // momentum 0.99 of its Adam overshoots, so convergence is slow. Measured worst mean error
    // from generation 500 on: 0.019 (0.036 from 400, 0.15 from 100 and 0.20 from 25).
    // Tolerance 0.05 at generation 500.
    for seed in 0..3 {
        let mean = run(&mut openai_es(seed), INSIDE, 500);
        assert!(max_error(&mean, &INSIDE) <= 0.05, "seed {seed}: {mean:?}");
    }
}

#[test]
fn openai_es_converges_on_an_optimum_at_a_corner_of_the_box() {
    // Reflection makes the corner a peak the mean settles on. Measured worst mean error from
    // generation 600 on: 0.021 (0.038 from 500, 0.26 from 100). Tolerance 0.05 at 600.
    for seed in 0..3 {
        let mean = run(&mut openai_es(seed), BEYOND_CORNER, 600);
        assert!(max_error(&mean, &CORNER) <= 0.05, "seed {seed}: {mean:?}");
    }
}

#[test]
fn cmaes_ask_tell_with_lambda_9_converges_inside_and_at_a_corner() {
    // Measured worst mean error from generation 100 on: 4e-4 inside, 8e-4 at the corner (from
    // generation 50: 0.066 and 0.18). Tolerance 0.01 at generation 100.
    for seed in 0..3 {
        let mean = run(&mut cmaes(seed), INSIDE, 100);
        assert!(max_error(&mean, &INSIDE) <= 0.01, "inside, seed {seed}: {mean:?}");
        let mean = run(&mut cmaes(seed), BEYOND_CORNER, 100);
        assert!(max_error(&mean, &CORNER) <= 0.01, "corner, seed {seed}: {mean:?}");
    }
}

#[test]
fn one_generation_returns_the_best_candidate_of_that_generation_inside_the_box() {
    let b = design_box();
    for es in [&mut openai_es(3) as &mut dyn AskTell, &mut cmaes(3)] {
        for _ in 0..5 {
            let mut inner = quadratic(BEYOND_CORNER);
            let mut seen: Vec<(Vec<f32>, f32)> = Vec::new();
            let mut spy = |designs: &[f32], scores: &mut [f32]| {
                inner(designs, scores);
                seen.extend(designs.chunks_exact(6).map(<[f32]>::to_vec).zip(scores.iter().copied()));
            };
            let r = one_generation(es, &mut spy).unwrap();
            assert_eq!(seen.len(), es.population(), "one batched call of the whole population");
            assert!(seen.iter().all(|(x, _)| in_box(x, &b)));
            let top = seen.iter().map(|(_, s)| *s).fold(f32::NEG_INFINITY, f32::max);
            assert_eq!(r.score, top);
            assert!(seen.iter().any(|(x, s)| *x == r.design && *s == top));
        }
    }
}

#[test]
fn nan_scores_never_become_the_best() {
    for es in [&mut openai_es(4) as &mut dyn AskTell, &mut cmaes(4)] {
        for _ in 0..20 {
            // The better half of every generation (by the true score) scores NaN.
            let mut inner = quadratic(INSIDE);
            let mut best_finite = f32::NEG_INFINITY;
            let mut f = |designs: &[f32], scores: &mut [f32]| {
                inner(designs, scores);
                let mut sorted = scores.to_vec();
                sorted.sort_by(|a, b| b.total_cmp(a));
                let cut = sorted[scores.len() / 2];
                for s in scores.iter_mut() {
                    if *s > cut {
                        *s = f32::NAN;
                    }
                }
                best_finite = scores.iter().copied().filter(|s| !s.is_nan()).fold(f32::NEG_INFINITY, f32::max);
            };
            let r = one_generation(es, &mut f).unwrap();
            assert!(!r.score.is_nan());
            assert_eq!(r.score, best_finite);
        }
        assert!(es.mean_design().iter().all(|v| v.is_finite()));
    }
    // A generation scored NaN throughout returns a design in the box with score -inf, and
    // gives OpenAI-ES no gradient: its mean stays at the box centre.
    let mut es = openai_es(5);
    let r = one_generation(&mut es, &mut |_: &[f32], s: &mut [f32]| s.fill(f32::NAN)).unwrap();
    assert!(in_box(&r.design, &design_box()));
    assert_eq!(r.score, f32::NEG_INFINITY);
    assert!(max_error(&es.mean_design(), &[1.4; 6]) <= 1e-6, "{:?}", es.mean_design());
}

#[test]
fn antithetic_sampling_mirrors_the_candidates_about_the_mean() {
    // The mean starts at the box centre 1.4; candidate k + 128 is candidate k mirrored.
    let mut es = openai_es(6);
    let x = es.ask().to_vec();
    let half = 128 * 6;
    for i in 0..half {
        assert!((x[i] + x[half + i] - 2.8).abs() <= 1e-6, "{} + {}", x[i], x[half + i]);
    }
}

#[test]
fn the_same_seed_gives_the_same_candidates() {
    let generations = |es: &mut dyn AskTell| -> Vec<Vec<f32>> {
        let mut f = quadratic(INSIDE);
        let mut out = Vec::new();
        for _ in 0..4 {
            let x = es.ask().to_vec();
            let mut s = vec![0.0; es.population()];
            f(&x, &mut s);
            es.tell(&s).unwrap();
            out.push(x);
        }
        out.push(es.mean_design());
        out
    };
    assert_eq!(generations(&mut openai_es(7)), generations(&mut openai_es(7)));
    assert_ne!(generations(&mut openai_es(7)), generations(&mut openai_es(8)));
    assert_eq!(generations(&mut cmaes(7)), generations(&mut cmaes(7)));
    assert_ne!(generations(&mut cmaes(7)), generations(&mut cmaes(8)));
}
