//! The batched, two-core design objective equals Eq. 5.6 computed one particle and one start
//! state at a time.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_design_optimizer::{DesignObjective, ObjectiveWorkspace, QMode};
use coadapt_nn::bf16::bf16_available;
use coadapt_nn::{Mlp, Precision, squashed};
use rand::Rng;

#[test]
fn batched_objective_equals_the_per_particle_definition() {
    let (obs, act, design_at, design_dim, n_states, particles) = (7, 2, 4, 3, 5, 13);
    let mut rng = coadapt_core::rng(1, 0);
    let policy = Mlp::new(&[obs, 16, 16, 2 * act]).unwrap();
    let critic = Mlp::new(&[obs + act, 16, 16, 1]).unwrap();
    let mut phi = policy.zeros();
    policy.init(&mut phi, 0.5, &mut rng);
    let mut q1 = critic.zeros();
    critic.init(&mut q1, 0.5, &mut rng);
    let mut q2 = critic.zeros();
    critic.init(&mut q2, 0.5, &mut rng);
    let start: Vec<f32> = (0..n_states * obs).map(|_| rng.random_range(-1.0..1.0)).collect();
    let designs: Vec<f32> = (0..particles * design_dim).map(|_| rng.random_range(0.5..1.5)).collect();
    let f = DesignObjective::new(&policy, &phi, &critic, &[&q1, &q2], &start, design_at, design_dim).unwrap();

    let naive = |xi: &[f32], mode: QMode| -> f32 {
        let mut total = 0.0;
        for s in start.chunks_exact(obs) {
            let mut o = s.to_vec();
            o[design_at..design_at + design_dim].copy_from_slice(xi);
            let mut a_pi = policy.activations(1);
            let mut a = vec![0.0; act];
            squashed::mean_action(policy.forward(&phi, &o, 1, &mut a_pi), act, &mut a);
            let x: Vec<f32> = o.iter().chain(&a).copied().collect();
            let mut aq = critic.activations(1);
            let v1 = critic.forward(&q1, &x, 1, &mut aq)[0];
            let v2 = critic.forward(&q2, &x, 1, &mut aq)[0];
            total += match mode {
                QMode::First => v1,
                QMode::MinOfTwin => v1.min(v2),
                QMode::MeanMinusKStd(k) => {
                    let mean = (v1 + v2) / 2.0;
                    let std = (((v1 - mean).powi(2) + (v2 - mean).powi(2)) / 2.0).sqrt();
                    mean - k * std
                }
                QMode::Heads => unreachable!("two critics have no heads beyond the twin"),
            };
        }
        total / n_states as f32
    };

    for (mode, chunk_rows, cores) in [
        (QMode::First, 1, 1),
        (QMode::First, 12, 2),
        (QMode::MinOfTwin, 64, 2),
        (QMode::MinOfTwin, 1000, 3),
        (QMode::MeanMinusKStd(2.0), 12, 2),
        (QMode::MeanMinusKStd(0.0), 64, 1),
    ] {
        let mut out = vec![0.0; particles];
        let mut ws = vec![ObjectiveWorkspace::default(); cores];
        f.evaluate(&designs, mode, chunk_rows, &mut out, &mut ws);
        for (k, xi) in designs.chunks_exact(design_dim).enumerate() {
            let expect = naive(xi, mode);
            assert!(
                (out[k] - expect).abs() <= 1e-5 * expect.abs().max(1.0),
                "{mode:?} chunk {chunk_rows} particle {k}: {} vs {expect}",
                out[k]
            );
        }
    }
    // k = 1 is the minimum of the twins.
    let (mut a, mut b) = (vec![0.0; particles], vec![0.0; particles]);
    f.evaluate(&designs, QMode::MeanMinusKStd(1.0), 64, &mut a, &mut [ObjectiveWorkspace::default()]);
    f.evaluate(&designs, QMode::MinOfTwin, 64, &mut b, &mut [ObjectiveWorkspace::default()]);
    assert!(a.iter().zip(&b).all(|(a, b)| (a - b).abs() <= 1e-5 * b.abs().max(1.0)), "{a:?} vs {b:?}");
    // The design columns matter: a different design gives a different score.
    let mut out = vec![0.0; 2];
    f.evaluate(&[0.5, 0.5, 0.5, 1.5, 1.5, 1.5], QMode::First, 64, &mut out, &mut [ObjectiveWorkspace::default()]);
    assert!(out[0] != out[1]);
}

#[test]
fn mismatched_shapes_are_refused() {
    let policy = Mlp::new(&[5, 8, 4]).unwrap();
    let critic = Mlp::new(&[7, 8, 1]).unwrap();
    let (phi, q) = (policy.zeros(), critic.zeros());
    assert!(DesignObjective::new(&policy, &phi, &critic, &[&q], &[0.0; 10], 3, 2).is_ok());
    assert!(DesignObjective::new(&policy, &phi, &critic, &[&q], &[0.0; 9], 3, 2).is_err());
    assert!(DesignObjective::new(&policy, &phi, &critic, &[&q], &[0.0; 10], 4, 2).is_err());
    assert!(DesignObjective::new(&policy, &phi[1..], &critic, &[&q], &[0.0; 10], 3, 2).is_err());
    let wrong_critic = Mlp::new(&[6, 8, 1]).unwrap();
    assert!(DesignObjective::new(&policy, &phi, &wrong_critic, &[&wrong_critic.zeros()], &[0.0; 10], 3, 2).is_err());
}

/// With more heads than the twin, `MeanMinusKStd` is the mean minus k population sd over every
/// head (an ensemble lower confidence bound), per row and then averaged over start states, and
/// `disagreement` is the mean sd; the twin's own score only uses the first two heads. Heads
/// offset by a large constant keep their spread's digits (Welford's update, not sum of squares).
#[test]
fn ensemble_heads_score_the_mean_minus_k_sd_over_every_head() {
    let (obs, act, design_at, design_dim, n_states, particles) = (6, 2, 3, 3, 4, 9);
    let mut rng = coadapt_core::rng(2, 0);
    let policy = Mlp::new(&[obs, 12, 2 * act]).unwrap();
    let critic = Mlp::new(&[obs + act, 12, 1]).unwrap();
    let mut phi = policy.zeros();
    policy.init(&mut phi, 0.5, &mut rng);
    let heads: Vec<Vec<f32>> = (0..5)
        .map(|_| {
            let mut q = critic.zeros();
            critic.init(&mut q, 0.5, &mut rng);
            // Q around 3,000 with spreads of order 1: a sum of squares in f32 would lose them.
            *q.last_mut().unwrap() = 3000.0;
            q
        })
        .collect();
    let thetas: Vec<&[f32]> = heads.iter().map(Vec::as_slice).collect();
    let start: Vec<f32> = (0..n_states * obs).map(|_| rng.random_range(-1.0..1.0)).collect();
    let designs: Vec<f32> = (0..particles * design_dim).map(|_| rng.random_range(0.5..1.5)).collect();
    let f = DesignObjective::new(&policy, &phi, &critic, &thetas, &start, design_at, design_dim).unwrap();
    let twin = DesignObjective::new(&policy, &phi, &critic, &thetas[..2], &start, design_at, design_dim).unwrap();

    // Per design: (mean over states of mean - k sd, mean over states of sd), in f64.
    let naive_over = |hs: &[Vec<f32>], xi: &[f32], k: f64| -> (f64, f64) {
        let (mut lcb, mut sd_total) = (0.0, 0.0);
        for s in start.chunks_exact(obs) {
            let mut o = s.to_vec();
            o[design_at..design_at + design_dim].copy_from_slice(xi);
            let mut a_pi = policy.activations(1);
            let mut a = vec![0.0; act];
            squashed::mean_action(policy.forward(&phi, &o, 1, &mut a_pi), act, &mut a);
            let x: Vec<f32> = o.iter().chain(&a).copied().collect();
            let mut aq = critic.activations(1);
            let v: Vec<f64> = hs.iter().map(|q| f64::from(critic.forward(q, &x, 1, &mut aq)[0])).collect();
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
            lcb += mean - k * sd;
            sd_total += sd;
        }
        (lcb / n_states as f64, sd_total / n_states as f64)
    };
    let naive = |xi: &[f32], k: f64| naive_over(&heads, xi, k);
    let mut spread_seen = 0.0f64;
    for (k, chunk_rows, cores) in [(2.0, 12, 2), (0.0, 64, 1), (1.0, 4, 3)] {
        let mut out = vec![0.0; particles];
        f.evaluate(&designs, QMode::MeanMinusKStd(k), chunk_rows, &mut out, &mut vec![ObjectiveWorkspace::default(); cores]);
        for (p, xi) in designs.chunks_exact(design_dim).enumerate() {
            let (expect, sd) = naive(xi, f64::from(k));
            spread_seen = spread_seen.max(sd);
            // f32 rows near 3,000 carry about 3e-4 of rounding each.
            assert!((f64::from(out[p]) - expect).abs() < 2e-3, "k {k} particle {p}: {} vs {expect} (sd {sd})", out[p]);
        }
    }
    assert!(spread_seen > 0.05, "the heads disagree enough for the test to mean something ({spread_seen})");
    let mut gap = vec![0.0; particles];
    assert!(f.disagreement(&designs, 12, &mut gap, &mut ObjectiveWorkspace::default()));
    for (p, xi) in designs.chunks_exact(design_dim).enumerate() {
        let (_, sd) = naive(xi, 0.0);
        assert!((f64::from(gap[p]) - sd).abs() < 2e-3, "particle {p}: disagreement {} vs sd {sd}", gap[p]);
    }
    // The twin's modes read the first two heads only, whatever else is given.
    for mode in [QMode::First, QMode::MinOfTwin] {
        let (mut a, mut b) = (vec![0.0; particles], vec![0.0; particles]);
        f.evaluate(&designs, mode, 64, &mut a, &mut [ObjectiveWorkspace::default()]);
        twin.evaluate(&designs, mode, 64, &mut b, &mut [ObjectiveWorkspace::default()]);
        assert_eq!(a, b, "{mode:?}");
    }
    // `Heads` is the mean of the critics beyond the twin (the conservative design critics),
    // from one head on; with none beyond the twin the objective refuses the mode.
    for n in [3, 5] {
        let g = DesignObjective::new(&policy, &phi, &critic, &thetas[..n], &start, design_at, design_dim).unwrap();
        g.check_mode(QMode::Heads).unwrap();
        let mut out = vec![0.0; particles];
        g.evaluate(&designs, QMode::Heads, 12, &mut out, &mut vec![ObjectiveWorkspace::default(); 2]);
        for (p, xi) in designs.chunks_exact(design_dim).enumerate() {
            let (expect, _) = naive_over(&heads[2..n], xi, 0.0);
            assert!((f64::from(out[p]) - expect).abs() < 2e-3, "{n} critics, particle {p}: {} vs {expect}", out[p]);
        }
    }
    let e = twin.check_mode(QMode::Heads).unwrap_err().to_string();
    assert!(e.contains("optimizer.q") && e.contains("population-critics"), "{e}");
    for mode in [QMode::First, QMode::MinOfTwin, QMode::MeanMinusKStd(1.0)] {
        twin.check_mode(mode).unwrap();
    }
}

/// With bf16 networks (issue 34) the objective's tails compute in bf16 and the scores stay within
/// bf16's error of the f32 ones: FEAR's shapes (3 x 200, 23 inputs of which 6 design), 700
/// particles over 32 start states, so that the hidden products fill AMX tiles.
#[test]
fn the_objective_in_bf16_scores_as_in_f32_to_bf16_precision() {
    if !bf16_available() {
        eprintln!("SKIPPED: this CPU has no AVX-512 BF16: Precision::Bf16 runs f32 products here");
        return;
    }
    let (obs, act, design_at, design_dim, n_states, particles) = (23, 6, 17, 6, 32, 700);
    let mut rng = coadapt_core::rng(5, 0);
    let policy = Mlp::new(&[obs, 200, 200, 200, 2 * act]).unwrap();
    let critic = Mlp::new(&[obs + act, 200, 200, 200, 1]).unwrap();
    let mut phi = policy.zeros();
    policy.init(&mut phi, 0.5, &mut rng);
    let mut q1 = critic.zeros();
    critic.init(&mut q1, 0.5, &mut rng);
    let start: Vec<f32> = (0..n_states * obs).map(|_| rng.random_range(-1.0..1.0)).collect();
    let designs: Vec<f32> = (0..particles * design_dim).map(|_| rng.random_range(0.8..2.0)).collect();
    let score = |precision: Precision| {
        let (p, c) = (policy.clone().with_precision(precision), critic.clone().with_precision(precision));
        let f = DesignObjective::new(&p, &phi, &c, &[&q1], &start, design_at, design_dim).unwrap();
        let mut out = vec![0.0; particles];
        f.evaluate(&designs, QMode::First, 256, &mut out, &mut [ObjectiveWorkspace::default()]);
        out
    };
    let (f32s, bf16s) = (score(Precision::F32), score(Precision::Bf16));
    let num: f64 = f32s.iter().zip(&bf16s).map(|(a, b)| f64::from(a - b).powi(2)).sum();
    let den: f64 = f32s.iter().map(|a| f64::from(*a).powi(2)).sum();
    let rel = (num / den).sqrt();
    eprintln!("design objective, bf16 against f32: relative error {rel:.2e}");
    assert!(rel < 2f64.powi(-5), "relative error {rel}");
    assert!(rel > 1e-6, "relative error {rel}: nothing ran in bf16?");
    // The order PSO sees: the best particle under bf16 is among f32's best few.
    let best = bf16s.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).unwrap().0;
    let better = f32s.iter().filter(|v| **v > f32s[best]).count();
    assert!(better < 10, "bf16's best particle ranks {} under f32", better + 1);
}
