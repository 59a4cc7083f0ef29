//! SAC and DDPG losses, gradients and one full update compared with PyTorch (float64) on fixed
//! weights. The PyTorch script is `crates/nn/tests/reference/make_reference.py`; its output,
//! verbatim, is `crates/nn/tests/reference/reference_values.txt`, included here.
//!
//! Tolerances (our side is f32): losses and gradients to 1e-4 of the largest magnitude of the
//! compared vector (f32 keeps ~7 digits; the SAC graph chains ~100 operations per output, and
//! the policy gradient here is tiny, ~1e-5, so its relative accuracy is what counts); updated
//! parameters to 2e-7 absolute, under 0.1 % of an Adam step of lr 3e-4.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::excessive_precision, dead_code)] // tests: a panic is the failure report

use coadapt_core::Batch;
use coadapt_learner::{Ddpg, DdpgConfig, Sac, SacConfig};

include!("../../crates/nn/tests/reference/reference_values.txt");

fn ref_params(n: usize, offset: f64) -> Vec<f32> {
    (0..n).map(|i| (0.1 * (0.37 * i as f64 + offset).sin()) as f32).collect()
}

fn ref_inputs(rows: usize, d: usize, offset: f64) -> Vec<f32> {
    (0..rows * d).map(|k| (0.11 * k as f64 + offset).cos() as f32).collect()
}

fn ref_batch() -> Batch {
    let mut b = Batch::new(5, 4, 2);
    b.obs = ref_inputs(5, 4, 0.3);
    b.act = ref_inputs(5, 2, 1.1).iter().map(|v| 0.5 * v).collect();
    b.rew = (0..5).map(|i| (0.11 * i as f64 + 1.3).cos() as f32).collect();
    b.next_obs = ref_inputs(5, 4, 1.7);
    b.done = vec![0.0, 0.0, 0.0, 1.0, 0.0];
    b
}

fn close(name: &str, ours: f32, reference: f64, tol: f64) {
    assert!((ours as f64 - reference).abs() <= tol, "{name}: ours {ours} vs PyTorch {reference}");
}

fn vec_close(name: &str, ours: &[f32], reference: &[f64], rel: f64) {
    assert_eq!(ours.len(), reference.len(), "{name}: length");
    let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, (o, r)) in ours.iter().zip(reference).enumerate() {
        assert!((*o as f64 - r).abs() <= rel * scale, "{name}[{i}]: ours {o} vs PyTorch {r} (scale {scale})");
    }
}

fn vec_abs(name: &str, ours: &[f32], reference: &[f64], tol: f64) {
    assert_eq!(ours.len(), reference.len(), "{name}: length");
    for (i, (o, r)) in ours.iter().zip(reference).enumerate() {
        assert!((*o as f64 - r).abs() <= tol, "{name}[{i}]: ours {o} vs PyTorch {r}");
    }
}

fn reference_sac(grad_clamp: f32) -> Sac {
    let cfg = SacConfig { hidden: vec![8, 8], alpha: 0.01, grad_clamp, ..SacConfig::default() };
    let mut sac = Sac::new(4, 2, cfg, 0).unwrap();
    let (np, nq) = (sac.policy().n_params(), sac.critic().n_params());
    let (phi, q1, q2, q1b, q2b) = (ref_params(np, 0.2), ref_params(nq, 0.4), ref_params(nq, 0.5), ref_params(nq, 0.6), ref_params(nq, 0.7));
    sac.set_params(&phi, [&q1, &q2], [&q1b, &q2b]);
    sac
}

#[test]
fn sac_losses_gradients_and_update_match_pytorch() {
    let b = ref_batch();
    let (eps, eps_next) = (ref_inputs(5, 2, 0.7), ref_inputs(5, 2, 1.9));

    // Unclamped gradients first (the reference prints them before clamping).
    let mut sac = reference_sac(0.0);
    let l = sac.update_with_given_noise(&b, &eps, &eps_next);
    close("policy loss", l.policy, SAC_POLICY_LOSS, 1e-6);
    close("q1 loss", l.q1, SAC_Q1_LOSS, 1e-6);
    close("q2 loss", l.q2, SAC_Q2_LOSS, 1e-6);
    close("alpha loss", l.alpha, SAC_ALPHA_LOSS, 1e-4);
    let (g_pi, g_q1) = sac.last_gradients();
    vec_close("policy gradient", g_pi, &SAC_POLICY_GRAD, 1e-4);
    vec_close("q1 gradient", g_q1, &SAC_Q1_GRAD, 1e-4);

    // The full update with the reference's clamp to [-1, 1], Adam and Polyak.
    let mut sac = reference_sac(1.0);
    sac.update_with_given_noise(&b, &eps, &eps_next);
    vec_abs("policy after step", sac.policy_params(), &SAC_POLICY_AFTER_STEP, 2e-7);
    let (q1, q1_bar) = sac.critic_params(0);
    vec_abs("q1 after step", q1, &SAC_Q1_AFTER_STEP, 2e-7);
    vec_abs("target q1 after step", q1_bar, &SAC_TARGET_Q1_AFTER_STEP, 2e-7);
}

#[test]
fn ddpg_losses_and_gradients_match_pytorch() {
    let cfg = DdpgConfig { hidden: vec![8, 8], grad_clamp: 0.0, ..DdpgConfig::default() };
    let mut ddpg = Ddpg::new(4, 2, cfg, 0).unwrap();
    let (na, nq) = (ddpg.actor().n_params(), ddpg.critic().n_params());
    ddpg.set_params(&ref_params(na, 0.2), &ref_params(nq, 0.4), &ref_params(na, 0.8), &ref_params(nq, 0.6));
    let l = ddpg.update(&ref_batch());
    close("critic loss", l.critic, DDPG_CRITIC_LOSS, 1e-6);
    close("actor loss", l.actor, DDPG_ACTOR_LOSS, 1e-6);
    let (g_mu, g_q) = ddpg.last_gradients();
    vec_close("actor gradient", g_mu, &DDPG_ACTOR_GRAD, 1e-4);
    vec_close("critic gradient", g_q, &DDPG_CRITIC_GRAD, 1e-4);
}
