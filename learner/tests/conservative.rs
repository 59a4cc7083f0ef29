//! COMs' conservative term on FEAR's population critics (`[learner.conservative]`, issue 28
//! section 3): its gradient against central finite differences (the adversarial designs held
//! fixed, as COMs holds them), the adversary's ascent (uphill on Q, inside the box, state and
//! action untouched), the learner's wiring (off is FEAR bit for bit; on, only the population
//! critics train differently), what it does to a critic trained on bodies in the middle of the
//! box, and the config's refusals.
//!
//! Tolerance as in crates/nn/tests/gradcheck.rs: f32 networks, so with step h the difference
//! carries ~1e-6/h of rounding noise; a perturbation that flips a ReLU straddles a kink and is
//! skipped (the test asserts few are).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::Transition;
use coadapt_learner::SacConfig;
use coadapt_learner::conservative::{Conservative, ConservativeConfig, ConservativeWork};
use coadapt_learner::fear::{ActingPolicy, FearLearner, FearLearnerConfig};
use coadapt_learner::networks::critic;
use coadapt_nn::{Activations, Mlp};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

const H: f32 = 3e-3;

/// State 2, design 2 (box [0.5, 1.5] x [0, 2]), action 2: critic rows `[s0, s1, xi0, xi1, a0, a1]`.
fn setup(rows: usize, seed: u64) -> (Mlp, Vec<f32>, Vec<f32>, Conservative) {
    let net = critic(4, 2, &[16, 12]).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let theta: Vec<f32> = (0..net.n_params()).map(|_| 0.4 * rng.sample::<f32, _>(StandardNormal)).collect();
    let mut x = Vec::new();
    for _ in 0..rows {
        x.extend([rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)]);
        x.extend([rng.random_range(0.7..1.3), rng.random_range(0.4..1.6)]);
        x.extend([rng.random_range(-0.9..0.9), rng.random_range(-0.9..0.9)]);
    }
    let c = Conservative { weight: 0.7, steps: 3, step: 0.1, design: 2..4, low: vec![0.5, 0.0], high: vec![1.5, 2.0] };
    (net, theta, x, c)
}

fn mean_q(net: &Mlp, theta: &[f32], x: &[f32], rows: usize, act: &mut Activations) -> f64 {
    net.forward(theta, x, rows, act).iter().map(|q| f64::from(*q)).sum::<f64>() / rows as f64
}

fn relu_pattern(net: &Mlp, act: &Activations, rows: usize) -> Vec<bool> {
    let layers = net.layers();
    (0..layers.len() - 1).flat_map(|i| act.layer_output(i)[..rows * layers[i].n_out].iter().map(|v| *v > 0.0).collect::<Vec<_>>()).collect()
}

#[test]
fn the_conservative_gradient_matches_central_differences() {
    let rows = 9;
    let (net, theta, x_data, c) = setup(rows, 5);
    let mut work = ConservativeWork::default();
    c.adversary(&net, &theta, &x_data, rows, &mut work);
    let gap = c.gradient(&net, &theta, rows, &mut work);
    let x_adv = c.adversarial_rows(&work, rows, net.n_in()).to_vec();
    let analytic = work.grad.clone();

    // The term with the adversarial rows fixed, and the ReLU pattern of both row sets.
    let mut act = Activations::default();
    let mut term = |p: &[f32]| {
        let adv = mean_q(&net, p, &x_adv, rows, &mut act);
        let pa = relu_pattern(&net, &act, rows);
        let data = mean_q(&net, p, &x_data, rows, &mut act);
        let pd = relu_pattern(&net, &act, rows);
        (f64::from(c.weight) * (adv - data), adv - data, [pa, pd].concat())
    };
    let (_, gap0, pattern) = term(&theta);
    assert!((gap0 - f64::from(gap)).abs() < 1e-4, "gap {gap} vs {gap0}");
    let (mut num, mut den, mut skipped, mut checked) = (0.0f64, 0.0f64, 0, 0);
    for i in 0..theta.len() {
        let mut at = |d: f32| {
            let mut p = theta.clone();
            p[i] += d;
            term(&p)
        };
        let ((lp, _, pp), (lm, _, pm)) = (at(H), at(-H));
        if pp != pattern || pm != pattern {
            skipped += 1;
            continue;
        }
        let numeric = (lp - lm) / (2.0 * f64::from(H));
        let a = f64::from(analytic[i]);
        assert!((a - numeric).abs() <= 2e-3 * numeric.abs().max(1.0), "parameter {i}: analytic {a} vs numeric {numeric}");
        num += (a - numeric).powi(2);
        den += a * a + numeric * numeric;
        checked += 1;
    }
    let rel = (num / den.max(1e-30)).sqrt();
    assert!(rel < 2e-3, "relative error {rel}");
    assert!(den > 1e-6, "the gradient is not all zero");
    assert!(skipped * 20 < checked, "{skipped} of {} perturbations straddled a kink", checked + skipped);

    // The weight scales the gradient; the gap does not depend on it.
    let c2 = Conservative { weight: 2.0 * c.weight, ..c.clone() };
    let mut w2 = ConservativeWork::default();
    c2.adversary(&net, &theta, &x_data, rows, &mut w2);
    assert_eq!(c2.gradient(&net, &theta, rows, &mut w2), gap);
    for (a, b) in w2.grad.iter().zip(&analytic) {
        assert!((a - 2.0 * b).abs() <= 1e-5 * b.abs().max(1.0), "{a} vs 2 x {b}");
    }
}

#[test]
fn the_adversary_climbs_q_inside_the_box_and_leaves_state_and_action_alone() {
    let rows = 32;
    let (net, theta, x_data, c) = setup(rows, 9);
    let mut work = ConservativeWork::default();
    c.adversary(&net, &theta, &x_data, rows, &mut work);
    let x_adv = c.adversarial_rows(&work, rows, net.n_in()).to_vec();
    let mut act = Activations::default();
    let q0 = net.forward(&theta, &x_data, rows, &mut act).to_vec();
    let q1 = net.forward(&theta, &x_adv, rows, &mut act).to_vec();
    let mut moved = 0;
    for r in 0..rows {
        let (d, a) = (&x_data[r * 6..r * 6 + 6], &x_adv[r * 6..r * 6 + 6]);
        assert_eq!([d[0], d[1], d[4], d[5]], [a[0], a[1], a[4], a[5]], "row {r}: only the design moves");
        for (k, (lo, hi)) in c.low.iter().zip(&c.high).enumerate() {
            assert!((*lo..=*hi).contains(&a[2 + k]), "row {r}: design {k} = {} outside [{lo}, {hi}]", a[2 + k]);
        }
        // Each of 3 steps moves at most 0.1 box widths in box units (Euclidean).
        let u = ((a[2] - d[2]) / 1.0).powi(2) + ((a[3] - d[3]) / 2.0).powi(2);
        assert!(u.sqrt() <= 0.3 + 1e-5, "row {r} moved {} box widths", u.sqrt());
        moved += usize::from(u > 0.0);
    }
    assert!(moved == rows, "{moved} of {rows} rows moved");
    // Steps of 0.1 box widths may overshoot a bend of Q in a row; on the mean they climb.
    let (m0, m1) = (q0.iter().sum::<f32>() / rows as f32, q1.iter().sum::<f32>() / rows as f32);
    assert!(m1 > m0 + 1e-3, "the ascent did not raise mean Q: {m0} -> {m1}");
    let rose = q0.iter().zip(&q1).filter(|(a, b)| b > a).count();
    assert!(rose * 4 >= rows * 3, "Q rose in only {rose} of {rows} rows");
    // One short step is first order: Q rises in every row (but one that straddles a kink).
    let small = Conservative { steps: 1, step: 1e-3, ..c.clone() };
    small.adversary(&net, &theta, &x_data, rows, &mut work);
    let q2 = net.forward(&theta, small.adversarial_rows(&work, rows, net.n_in()), rows, &mut act).to_vec();
    let fell: Vec<usize> = (0..rows).filter(|r| q2[*r] <= q0[*r]).collect();
    assert!(fell.len() <= 1, "Q did not rise on one short step in rows {fell:?}");
}

fn fear_cfg(weight: f32) -> FearLearnerConfig {
    FearLearnerConfig {
        sac: SacConfig { hidden: vec![32, 32], batch_size: 32, gamma: 0.9, critic_lr: 1e-3, policy_lr: 1e-3, ..SacConfig::default() },
        population_batch: 8,
        species_batch: 24,
        individual_updates: 4,
        population_updates: 4,
        population_updates_from_design: 0,
        warmup_episodes: 0,
        conservative: ConservativeConfig { weight, steps: 5, step: 0.1 },
        ..FearLearnerConfig::default()
    }
}

/// A learner on a robot with state 1 and design 2 in the box [0, 1]^2, action 1; its bodies
/// all lie in the middle of the box ([0.3, 0.7]^2, every corner within the adversary's reach of
/// 5 steps of 0.1 box widths) and the reward does not depend on the body,
/// so any body the critic scores above the trained ones is its extrapolation, not the data's.
fn learner(weight: f32, seed: u64) -> FearLearner {
    let mut l = FearLearner::new(3, 1, fear_cfg(weight), seed).unwrap();
    l.set_design_box(&[0.0, 0.0], &[1.0, 1.0]);
    l
}

fn episode(l: &mut FearLearner, design: [f32; 2], rng: &mut Pcg64Mcg) {
    l.add_start_state(&[0.0, design[0], design[1]]).unwrap();
    for k in 0..20 {
        let s = k as f32 * 0.05;
        let a: f32 = rng.random_range(-1.0..1.0);
        let r = 1.0 - 0.2 * a * a;
        let (o, n) = ([s, design[0], design[1]], [s + 0.05, design[0], design[1]]);
        l.add_transition(&Transition { obs: &o, action: &[a], reward: r, next_obs: &n, terminated: false }).unwrap();
    }
}

#[test]
fn off_is_fear_bit_for_bit_and_on_changes_only_the_population_critics() {
    let run = |weight: f32, set_box: bool| {
        let mut l = FearLearner::new(3, 1, fear_cfg(weight), 3).unwrap();
        if set_box {
            l.set_design_box(&[0.0, 0.0], &[1.0, 1.0]);
        }
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        l.begin_design(0);
        let mut last = None;
        for _ in 0..3 {
            episode(&mut l, [0.5, 0.45], &mut rng);
            last = l.end_episode().unwrap().last_population;
        }
        (l, last.unwrap())
    };
    let (plain, lp) = run(0.0, false);
    let (off, lo) = run(0.0, true);
    let (on, ln) = run(1.0, true);
    let pop = |l: &FearLearner, i| l.agent(ActingPolicy::Population).critic_params(i).0.to_vec();
    let ind = |l: &FearLearner, i| l.agent(ActingPolicy::Individual).critic_params(i).0.to_vec();
    for i in 0..2 {
        assert_eq!(pop(&plain, i), pop(&off, i), "weight 0 changed population critic {i}");
        // Within a design the individual pair trains before the population pair and from its own
        // copy: the term never reaches it.
        assert_eq!(ind(&plain, i), ind(&on, i), "the term reached individual critic {i}");
        assert_ne!(pop(&plain, i), pop(&on, i), "weight 1 left population critic {i} as FEAR's");
    }
    assert_eq!(lp.conservative_gap, 0.0);
    assert_eq!(lo, lp);
    assert!(ln.conservative_gap.is_finite() && ln.conservative_gap != 0.0, "{ln:?}");
}

/// What the term is for: trained on bodies in the middle of the box only, with a reward that
/// does not depend on the body, FEAR's critic still finds bodies it scores above the trained
/// ones (the best of an 11 x 11 grid over the box, what PSO over Q goes to: its "optimism");
/// the conservative critic's best is close to its score of the trained bodies. Same data, same
/// seeds, 8 seeds. Not every seed: gradient ascent climbs from the data to the maxima it can
/// reach, and a maximum it does not climb to stays (on this machine seed 2 of 8, where the
/// conservative critic's optimism was 1.81 against FEAR's 1.32; the other seven 0.000-0.011
/// against 0.22-0.84).
#[test]
fn trained_on_middle_bodies_the_conservative_critic_does_not_invent_a_better_body() {
    let mut optimism = [Vec::new(), Vec::new()];
    for seed in 1..=8 {
        for (k, weight) in [0.0, 2.0].into_iter().enumerate() {
            let mut l = learner(weight, seed);
            let mut rng = Pcg64Mcg::seed_from_u64(seed);
            for d in 0..4 {
                l.begin_design(d);
                let design = [rng.random_range(0.3..0.7), rng.random_range(0.3..0.7)];
                for _ in 0..2 {
                    episode(&mut l, design, &mut rng);
                    l.end_episode().unwrap();
                }
            }
            l.train_population(1500).unwrap();
            // Q(s, a = 0, design) over a few states, at a body and at the middle of the box.
            let sac = l.agent(ActingPolicy::Population);
            let (theta, _) = sac.critic_params(0);
            let mut act = Activations::default();
            let q = |xi: [f32; 2], act: &mut Activations| {
                let x: Vec<f32> = (0..5).flat_map(|i| [i as f32 * 0.2, xi[0], xi[1], 0.0]).collect();
                mean_q(sac.critic(), theta, &x, 5, act) as f32
            };
            let best = (0..121).map(|i| q([(i % 11) as f32 * 0.1, (i / 11) as f32 * 0.1], &mut act)).fold(f32::MIN, f32::max);
            optimism[k].push(best - q([0.5, 0.5], &mut act));
        }
    }
    let median = |v: &[f32]| {
        let mut v = v.to_vec();
        v.sort_by(f32::total_cmp);
        (v[3] + v[4]) / 2.0
    };
    let (fear, cons) = (&optimism[0], &optimism[1]);
    assert!(median(fear) > 0.2, "FEAR's critic invented no better body ({fear:?}): the test shows nothing");
    let held = fear.iter().zip(cons).filter(|(f, c)| **c < **f / 2.0).count();
    assert!(held >= 6, "the conservative critic's optimism was under half FEAR's on {held} of 8 seeds: {cons:?} vs {fear:?}");
    assert!(median(cons) < median(fear) / 4.0, "median optimism {} vs FEAR's {}", median(cons), median(fear));
}

#[test]
fn bad_settings_are_refused_naming_the_key() {
    let bad = [
        (ConservativeConfig { weight: -1.0, ..ConservativeConfig::default() }, "learner.conservative.weight"),
        (ConservativeConfig { weight: f32::NAN, ..ConservativeConfig::default() }, "learner.conservative.weight"),
        (ConservativeConfig { weight: 1.0, steps: 0, ..ConservativeConfig::default() }, "learner.conservative.steps"),
        (ConservativeConfig { weight: 1.0, step: 0.0, ..ConservativeConfig::default() }, "learner.conservative.step"),
        (ConservativeConfig { weight: 1.0, step: 1.5, ..ConservativeConfig::default() }, "learner.conservative.step"),
    ];
    for (c, key) in bad {
        let e = FearLearnerConfig { conservative: c.clone(), ..FearLearnerConfig::default() }.check().unwrap_err().to_string();
        assert!(e.starts_with(key), "{c:?}: {e}");
    }
    assert!(FearLearnerConfig::default().check().is_ok());
    assert!(
        FearLearnerConfig {
            conservative: ConservativeConfig { weight: 0.5, ..ConservativeConfig::default() },
            ..FearLearnerConfig::default()
        }
        .check()
        .is_ok()
    );
}
