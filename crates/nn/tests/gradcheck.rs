//! Finite-difference checks of every hand-written gradient in the crate.
//!
//! Tolerance: the networks run in f32, so a loss of magnitude ~1 carries rounding noise of
//! about 1e-6 (a few ulps accumulated over ~50 multiply-adds per output). Central differences
//! with step h turn that into ~1e-6/h of noise, plus a truncation error of order h^2 f''' for
//! smooth functions (zero for a ReLU network away from kinks, where the loss is piecewise linear
//! in any single parameter). With h = 1e-2 both stay below 1e-4, so an element must match to
//! 1e-3 * max(1, |g|); the whole vector must also agree to a relative error below 1e-3. A
//! parameter whose perturbation flips a ReLU (a kink between p-h and p+h) is skipped, and the
//! test asserts that only a few are.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_nn::{Activations, Mlp, squashed};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

const H: f32 = 1e-2;
/// A ReLU network is piecewise linear in each parameter, so a smaller step costs no truncation
/// error and straddles fewer kinks; its rounding noise (~1e-6/3e-3 = 3e-4) is still in tolerance.
const H_RELU: f32 = 3e-3;

fn randn(rng: &mut Pcg64Mcg, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.sample::<f32, _>(StandardNormal)).collect()
}

fn assert_close(name: &str, analytic: &[f32], numeric: &[f64], skipped: &[bool]) {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (i, ((&a, &n), &s)) in analytic.iter().zip(numeric).zip(skipped).enumerate() {
        if s {
            continue;
        }
        let err = (a as f64 - n).abs();
        assert!(err <= 1e-3 * n.abs().max(1.0), "{name}[{i}]: analytic {a} vs numeric {n}");
        num += err * err;
        den += (a as f64).powi(2) + n * n;
    }
    let rel = (num / den.max(1e-30)).sqrt();
    assert!(rel < 1e-3, "{name}: relative error {rel}");
}

fn relu_pattern(mlp: &Mlp, act: &Activations) -> Vec<bool> {
    (0..mlp.layers().len() - 1).flat_map(|i| act.layer_output(i).iter().map(|v| *v > 0.0).collect::<Vec<_>>()).collect()
}

/// L = sum(c * mlp(x)), so dL/dy = c.
fn linear_loss(mlp: &Mlp, p: &[f32], x: &[f32], rows: usize, c: &[f32], act: &mut Activations) -> (f64, Vec<bool>) {
    let y = mlp.forward(p, x, rows, act);
    let l = y.iter().zip(c).map(|(a, b)| (*a as f64) * (*b as f64)).sum();
    (l, relu_pattern(mlp, act))
}

#[test]
fn mlp_parameter_and_input_gradients_match_finite_differences() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mlp = Mlp::new(&[5, 16, 12, 3]).unwrap();
    let rows = 6;
    let mut p = mlp.zeros();
    mlp.init(&mut p, 0.3, &mut rng);
    let x = randn(&mut rng, rows * 5);
    let c = randn(&mut rng, rows * 3);
    let mut act = mlp.activations(rows);
    mlp.forward(&p, &x, rows, &mut act);
    let mut grad = mlp.zeros();
    let mut dx = vec![0.0; x.len()];
    mlp.backward(&p, &x, &mut act, 0..rows, &c, Some(&mut grad), Some(&mut dx));

    let mut numeric = vec![0.0; p.len()];
    let mut skipped = vec![false; p.len()];
    for k in 0..p.len() {
        let mut q = p.clone();
        q[k] = p[k] + H_RELU;
        let (lp, mp) = linear_loss(&mlp, &q, &x, rows, &c, &mut act);
        q[k] = p[k] - H_RELU;
        let (lm, mm) = linear_loss(&mlp, &q, &x, rows, &c, &mut act);
        skipped[k] = mp != mm;
        numeric[k] = (lp - lm) / (2.0 * H_RELU as f64);
    }
    let n_skipped = skipped.iter().filter(|s| **s).count();
    assert!(n_skipped * 20 < p.len(), "{n_skipped} of {} parameters straddle a ReLU kink", p.len());
    assert_close("dL/dparams", &grad, &numeric, &skipped);

    let mut numeric = vec![0.0; x.len()];
    let mut skipped = vec![false; x.len()];
    for k in 0..x.len() {
        let mut xq = x.clone();
        xq[k] = x[k] + H_RELU;
        let (lp, mp) = linear_loss(&mlp, &p, &xq, rows, &c, &mut act);
        xq[k] = x[k] - H_RELU;
        let (lm, mm) = linear_loss(&mlp, &p, &xq, rows, &c, &mut act);
        skipped[k] = mp != mm;
        numeric[k] = (lp - lm) / (2.0 * H_RELU as f64);
    }
    assert_close("dL/dx", &dx, &numeric, &skipped);
}

#[test]
fn input_only_backward_equals_full_backward() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mlp = Mlp::new(&[4, 8, 8, 2]).unwrap();
    let mut p = mlp.zeros();
    mlp.init(&mut p, 0.5, &mut rng);
    let x = randn(&mut rng, 3 * 4);
    let dy = randn(&mut rng, 3 * 2);
    let mut act = mlp.activations(3);
    mlp.forward(&p, &x, 3, &mut act);
    let (mut dx_full, mut dx_only) = (vec![0.0; 12], vec![0.0; 12]);
    let mut g = mlp.zeros();
    mlp.backward(&p, &x, &mut act, 0..3, &dy, Some(&mut g), Some(&mut dx_full));
    mlp.backward(&p, &x, &mut act, 0..3, &dy, None, Some(&mut dx_only));
    assert_eq!(dx_full, dx_only);
    assert!(dx_full.iter().any(|v| *v != 0.0));
    // A sub-range of a stacked forward gives the same gradients as a forward of those rows alone.
    let (mut dx_sub, mut g_sub) = (vec![0.0; 8], mlp.zeros());
    mlp.backward(&p, &x, &mut act, 1..3, &dy[2..], Some(&mut g_sub), Some(&mut dx_sub));
    let mut act2 = mlp.activations(2);
    mlp.forward(&p, &x[4..], 2, &mut act2);
    let (mut dx2, mut g2) = (vec![0.0; 8], mlp.zeros());
    mlp.backward(&p, &x[4..], &mut act2, 0..2, &dy[2..], Some(&mut g2), Some(&mut dx2));
    assert_eq!(dx_sub, dx2);
    assert_eq!(g_sub, g2);
}

/// L = sum(ca * action) + sum(cl * log_prob) for the squashed Gaussian, as a function of the head.
fn squashed_loss(head: &[f32], eps: &[f32], act: usize, ca: &[f32], cl: &[f32]) -> f64 {
    let rows = cl.len();
    let mut a = vec![0.0; rows * act];
    let mut lp = vec![0.0; rows];
    squashed::sample(head, eps, act, &mut a, &mut lp);
    a.iter().zip(ca).map(|(x, c)| (*x as f64) * (*c as f64)).sum::<f64>()
        + lp.iter().zip(cl).map(|(x, c)| (*x as f64) * (*c as f64)).sum::<f64>()
}

#[test]
fn tanh_gaussian_gradients_match_finite_differences() {
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let (rows, act) = (7, 3);
    let mut head = randn(&mut rng, rows * 2 * act);
    for r in 0..rows {
        for j in 0..act {
            head[r * 2 * act + act + j] *= 0.5; // log_std well inside the clamp
        }
    }
    let eps = randn(&mut rng, rows * act);
    let ca = randn(&mut rng, rows * act);
    let cl = randn(&mut rng, rows);
    let mut a = vec![0.0; rows * act];
    let mut lp = vec![0.0; rows];
    squashed::sample(&head, &eps, act, &mut a, &mut lp);
    let mut d_head = vec![0.0; head.len()];
    squashed::backward(&head, &eps, &a, &ca, &cl, act, &mut d_head);
    let numeric: Vec<f64> = (0..head.len())
        .map(|k| {
            let mut h = head.clone();
            h[k] = head[k] + H;
            let lp = squashed_loss(&h, &eps, act, &ca, &cl);
            h[k] = head[k] - H;
            let lm = squashed_loss(&h, &eps, act, &ca, &cl);
            (lp - lm) / (2.0 * H as f64)
        })
        .collect();
    assert_close("dL/dhead", &d_head, &numeric, &vec![false; head.len()]);
}

#[test]
fn clamped_log_std_passes_no_gradient() {
    let head = [0.3, 5.0]; // act 1: mean 0.3, log_std 5 > LOG_STD_MAX
    let eps = [0.7];
    let (mut a, mut lp) = ([0.0], [0.0]);
    squashed::sample(&head, &eps, 1, &mut a, &mut lp);
    let mut d = [0.0; 2];
    squashed::backward(&head, &eps, &a, &[1.0], &[1.0], 1, &mut d);
    assert_eq!(d[1], 0.0);
    assert!(d[0] != 0.0);
    // The log-probability used the clamped std: u = 0.3 + e^2 * 0.7.
    let u = 0.3f32 + 2f32.exp() * 0.7;
    assert!((a[0] - u.tanh()).abs() < 1e-6);
}

#[test]
fn log1m_tanh_sq_is_exact_where_the_naive_form_fails() {
    for u in [-30.0f32, -5.0, -0.5, 0.0, 0.5, 5.0, 30.0] {
        let reference = (1.0 - (u as f64).tanh().powi(2)).ln();
        let ours = squashed::log1m_tanh_sq(u) as f64;
        if reference.is_finite() {
            assert!((ours - reference).abs() < 1e-4 * reference.abs().max(1.0), "u={u}: {ours} vs {reference}");
        } else {
            // f64 tanh saturates at |u| = 30; the exact value is log(4) - 2|u|.
            assert!((ours - (4f64.ln() - 2.0 * (u as f64).abs())).abs() < 1e-3);
        }
    }
}
