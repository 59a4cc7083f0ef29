//! The action autoencoder of thesis Eq. 6.1: its gradients against central finite differences,
//! the weights' role, learning a design-dependent action manifold, correlated exploration's
//! form, and its file.
//!
//! Tolerance as in crates/nn/tests/gradcheck.rs: the networks run in f32, so with step h the
//! difference carries ~1e-6/h of rounding noise; the norm and tanh are smooth, the ReLUs
//! piecewise linear (a perturbation that flips a unit straddles a kink and is skipped; the test
//! asserts few are).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::excessive_precision)] // tests: a panic is the failure report

use coadapt_learner::action_space::{ActionAutoencoder, ActionSpaceConfig, weights};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

const H: f32 = 3e-3;

include!("reference/action_space_values.txt");

fn randn(rng: &mut Pcg64Mcg, n: usize, scale: f32) -> Vec<f32> {
    (0..n).map(|_| scale * rng.sample::<f32, _>(StandardNormal)).collect()
}

#[test]
fn gradients_of_eq_6_1_match_central_differences() {
    let (obs_dim, act_dim, rows) = (5, 3, 7);
    let cfg = ActionSpaceConfig { latent_dim: 2, hidden: vec![16, 12], ..ActionSpaceConfig::default() };
    let mut ae = ActionAutoencoder::new(obs_dim, act_dim, cfg, 3).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    // Larger weights than the default init, so the decoder's output is far from 0 and tanh bends.
    let (e0, d0) = (ae.encoder().1.to_vec(), ae.decoder().1.to_vec());
    let theta_e: Vec<f32> = e0.iter().map(|_| 0.4 * rng.sample::<f32, _>(StandardNormal)).collect();
    let theta_d: Vec<f32> = d0.iter().map(|_| 0.4 * rng.sample::<f32, _>(StandardNormal)).collect();
    ae.set_params(&theta_e, &theta_d);
    let obs = randn(&mut rng, rows * obs_dim, 1.0);
    let act: Vec<f32> = randn(&mut rng, rows * act_dim, 0.6).iter().map(|v| v.tanh()).collect();
    // One negative critic value: its weight is 0, so its row contributes nothing.
    let q: Vec<f32> = vec![1.5, 0.2, -3.0, 2.0, 0.7, 1.1, 0.05];
    let w = weights(&q);
    assert_eq!(w[2], 0.0);
    ae.loss_and_gradients(&obs, &act, &w, rows);
    let pattern = ae.relu_pattern(rows);
    let (ge, gd) = (ae.gradients().0.to_vec(), ae.gradients().1.to_vec());
    let mut skipped = 0;
    let mut checked = 0;
    for which in 0..2 {
        let (base, analytic) = if which == 0 { (&theta_e, &ge) } else { (&theta_d, &gd) };
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for i in 0..base.len() {
            let mut loss_at = |delta: f32| {
                let mut p = base.clone();
                p[i] += delta;
                if which == 0 {
                    ae.set_params(&p, &theta_d)
                } else {
                    ae.set_params(&theta_e, &p)
                }
                let l = ae.loss_and_gradients(&obs, &act, &w, rows);
                (l, ae.relu_pattern(rows) == pattern)
            };
            let ((lp, same_p), (lm, same_m)) = (loss_at(H), loss_at(-H));
            if !(same_p && same_m) {
                skipped += 1;
                continue;
            }
            let numeric = (lp - lm) / (2.0 * f64::from(H));
            let a = f64::from(analytic[i]);
            assert!(
                (a - numeric).abs() <= 2e-3 * numeric.abs().max(1.0),
                "{} parameter {i}: analytic {a} vs numeric {numeric}",
                ["encoder", "decoder"][which]
            );
            num += (a - numeric).powi(2);
            den += a * a + numeric * numeric;
            checked += 1;
        }
        let rel = (num / den.max(1e-30)).sqrt();
        assert!(rel < 2e-3, "{}: relative error {rel}", ["encoder", "decoder"][which]);
        assert!(den > 1e-6, "{}: the gradient is not all zero", ["encoder", "decoder"][which]);
    }
    assert!(skipped * 20 < checked, "{skipped} of {} perturbations straddled a kink", checked + skipped);
    ae.set_params(&theta_e, &theta_d);
    // A zero weight everywhere: no loss, no gradient.
    assert_eq!(ae.loss_and_gradients(&obs, &act, &[0.0; 7], rows), 0.0);
    assert!(ae.gradients().0.iter().chain(ae.gradients().1).all(|g| *g == 0.0));
}

/// Actions that live on a 2-D manifold that depends on the design (a "leg length" xi scales
/// the map from a 2-D cause u to 4 joints): a 2-D latent reconstructs them once trained.
#[test]
fn a_two_dimensional_latent_learns_a_design_dependent_action_manifold() {
    let (state_dim, act_dim, n) = (3, 4, 4096);
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut obs = Vec::with_capacity(n * (state_dim + 1));
    let mut act = Vec::with_capacity(n * act_dim);
    for _ in 0..n {
        let s = randn(&mut rng, state_dim, 1.0);
        let xi: f32 = rng.random_range(0.5..2.0);
        let u = randn(&mut rng, 2, 0.7);
        let a = [u[0] * xi, u[1], 0.5 * (u[0] + u[1]) / xi, 0.3 * s[0] + 0.3 * u[1]];
        obs.extend_from_slice(&s);
        obs.push(xi);
        act.extend(a.iter().map(|v| v.tanh()));
    }
    let w = vec![1.0; n];
    let cfg = ActionSpaceConfig { latent_dim: 2, hidden: vec![64, 64], learning_rate: 1e-3, batch_size: 256 };
    let mut ae = ActionAutoencoder::new(state_dim + 1, act_dim, cfg, 1).unwrap();
    let b = 256;
    let first = ae.loss_and_gradients(&obs[..b * 4], &act[..b * act_dim], &w[..b], b);
    for step in 0..3000 {
        let i = (step * b) % n;
        ae.update(&obs[i * 4..(i + b) * 4], &act[i * act_dim..(i + b) * act_dim], &w[i..i + b], b);
    }
    let last = ae.loss_and_gradients(&obs[..b * 4], &act[..b * act_dim], &w[..b], b);
    // A 1-D latent cannot hold both causes: the 2-D one must do clearly better than it.
    let cfg1 = ActionSpaceConfig { latent_dim: 1, hidden: vec![64, 64], learning_rate: 1e-3, batch_size: 256 };
    let mut one = ActionAutoencoder::new(state_dim + 1, act_dim, cfg1, 1).unwrap();
    for step in 0..3000 {
        let i = (step * b) % n;
        one.update(&obs[i * 4..(i + b) * 4], &act[i * act_dim..(i + b) * act_dim], &w[i..i + b], b);
    }
    let last1 = one.loss_and_gradients(&obs[..b * 4], &act[..b * act_dim], &w[..b], b);
    assert!(last < 0.15 * first, "the reconstruction error fell only from {first} to {last}");
    assert!(last < 0.6 * last1, "2-D latent {last} against 1-D {last1}");
}

#[test]
fn exploration_is_the_policys_action_at_z_0_and_a_file_round_trips() {
    let cfg = ActionSpaceConfig { latent_dim: 2, hidden: vec![8], ..ActionSpaceConfig::default() };
    let mut ae = ActionAutoencoder::new(3, 2, cfg.clone(), 9).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let (e, d) = (randn(&mut rng, ae.encoder().1.len(), 0.5), randn(&mut rng, ae.decoder().1.len(), 0.5));
    ae.set_params(&e, &d);
    let (obs, pi) = ([0.2, -0.4, 1.0], [0.3, -0.95]);
    assert_eq!(ae.explore(&obs, &pi, &[0.0, 0.0], 0.8), pi.to_vec(), "z = 0: no perturbation");
    assert_eq!(ae.explore(&obs, &pi, &[1.0, -2.0], 0.0), pi.to_vec(), "beta = 0: no perturbation");
    let a = ae.explore(&obs, &pi, &[1.5, -2.0], 0.8);
    let dz = ae.decode(&[obs, obs].concat(), &[1.5, -2.0, 0.0, 0.0], 2);
    for k in 0..2 {
        let want = (pi[k] + 0.8 * (dz[k] - dz[2 + k])).clamp(-1.0, 1.0);
        assert!((a[k] - want).abs() < 1e-6, "{a:?}");
        assert!((-1.0..=1.0).contains(&a[k]));
    }
    assert_ne!(a, pi.to_vec());
    let dir = coadapt_test_support::scratch("learner", "action-space");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("ae.safetensors");
    ae.save(&path).unwrap();
    let mut back = ActionAutoencoder::new(3, 2, cfg, 1).unwrap();
    back.load(&path).unwrap();
    assert_eq!(back.encoder().1, ae.encoder().1);
    assert_eq!(back.decoder().1, ae.decoder().1);
    let mut wrong = ActionAutoencoder::new(4, 2, ActionSpaceConfig { hidden: vec![8], ..ActionSpaceConfig::default() }, 1).unwrap();
    assert!(wrong.load(&path).unwrap_err().to_string().contains("encoder"));
}

/// Eq. 6.1's loss, latent codes, decoded actions and both gradients against PyTorch (float64) on
/// fixed weights: `reference/action_space.py`, output pasted verbatim in
/// `reference/action_space_values.txt`. Our side is f32: each vector to 1e-5 of its largest
/// magnitude (a few dozen multiply-adds per value, and a norm and a tanh).
#[test]
fn eq_6_1_matches_pytorch() {
    let (obs_dim, act_dim, rows) = (4, 3, 6);
    let cfg = ActionSpaceConfig { latent_dim: 2, hidden: vec![8, 6], ..ActionSpaceConfig::default() };
    let mut ae = ActionAutoencoder::new(obs_dim, act_dim, cfg, 1).unwrap();
    let p = |n: usize, scale: f64, offset: f64| -> Vec<f32> { (0..n).map(|i| (scale * (0.37 * i as f64 + offset).sin()) as f32).collect() };
    let x = |r: usize, d: usize, scale: f64, offset: f64| -> Vec<f32> {
        (0..r * d).map(|k| (scale * (0.11 * k as f64 + offset).cos()) as f32).collect()
    };
    let (ne, nd) = (ae.encoder().1.len(), ae.decoder().1.len());
    ae.set_params(&p(ne, 0.5, 0.4), &p(nd, 0.5, 0.9));
    let (obs, act) = (x(rows, obs_dim, 1.0, 0.3), x(rows, act_dim, 0.8, 1.1));
    let q: Vec<f32> = (0..rows).map(|i| (2.0 * (0.7 * i as f64 + 0.2).cos()) as f32).collect();
    let loss = ae.loss_and_gradients(&obs, &act, &weights(&q), rows);
    let close = |name: &str, ours: &[f32], reference: &[f64]| {
        assert_eq!(ours.len(), reference.len(), "{name}: length");
        let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (i, (o, r)) in ours.iter().zip(reference).enumerate() {
            assert!((f64::from(*o) - r).abs() <= 1e-5 * scale, "{name}[{i}]: ours {o} vs PyTorch {r} (scale {scale})");
        }
    };
    assert!((loss - AE_LOSS).abs() <= 1e-5 * AE_LOSS.abs(), "loss: ours {loss} vs PyTorch {AE_LOSS}");
    let (ge, gd) = (ae.gradients().0.to_vec(), ae.gradients().1.to_vec());
    close("encoder gradient", &ge, &AE_GRAD_ENCODER);
    close("decoder gradient", &gd, &AE_GRAD_DECODER);
    let z = ae.encode(&obs, &act, rows);
    close("z", &z, &AE_Z);
    close("decoded", &ae.decode(&obs, &z, rows), &AE_DECODED);
}
