//! Forward values compared with PyTorch (float64) on fixed weights. The numbers are produced by
//! `tests/reference/make_reference.py` (next to this file) and kept verbatim in
//! `tests/reference/reference_values.txt`, which both this test and the learner's SAC/DDPG
//! reference test include. Our networks run in f32: values of order 0.1-1 must agree to 1e-5
//! relative to the largest magnitude (f32 carries ~7 digits; a few dozen multiply-adds per
//! output lose at most one or two of them).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::excessive_precision, dead_code)] // tests: a panic is the failure report

use coadapt_nn::{Mlp, squashed};

include!("reference/reference_values.txt");

pub fn ref_params(n: usize, offset: f64) -> Vec<f32> {
    (0..n).map(|i| (0.1 * (0.37 * i as f64 + offset).sin()) as f32).collect()
}

pub fn ref_inputs(rows: usize, d: usize, offset: f64) -> Vec<f32> {
    (0..rows * d).map(|k| (0.11 * k as f64 + offset).cos() as f32).collect()
}

fn assert_matches(name: &str, ours: &[f32], reference: &[f64], rel: f64) {
    assert_eq!(ours.len(), reference.len(), "{name}: length");
    let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, (o, r)) in ours.iter().zip(reference).enumerate() {
        assert!((*o as f64 - r).abs() <= rel * scale, "{name}[{i}]: ours {o} vs PyTorch {r} (scale {scale})");
    }
}

#[test]
fn mlp_forward_matches_pytorch() {
    let mlp = Mlp::new(&[5, 7, 7, 3]).unwrap();
    let p = ref_params(mlp.n_params(), 0.1);
    let x = ref_inputs(4, 5, 0.0);
    let mut act = mlp.activations(4);
    let y = mlp.forward(&p, &x, 4, &mut act);
    assert_matches("mlp forward", y, &MLP_FORWARD, 1e-5);
}

#[test]
fn tanh_gaussian_matches_pytorch() {
    let mlp = Mlp::new(&[4, 8, 8, 4]).unwrap();
    let p = ref_params(mlp.n_params(), 0.2);
    let obs = ref_inputs(5, 4, 0.3);
    let eps = ref_inputs(5, 2, 0.7);
    let mut act = mlp.activations(5);
    let head = mlp.forward(&p, &obs, 5, &mut act);
    let (mut a, mut lp) = (vec![0.0; 10], vec![0.0; 5]);
    squashed::sample(head, &eps, 2, &mut a, &mut lp);
    assert_matches("actions", &a, &TANH_GAUSSIAN_ACTIONS, 1e-5);
    assert_matches("log_prob", &lp, &TANH_GAUSSIAN_LOG_PROB, 1e-5);
}
