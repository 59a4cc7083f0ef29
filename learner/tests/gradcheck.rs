//! Finite-difference checks of the SAC and DDPG losses' gradients, taken through the real
//! update code: the losses an update reports are computed at the parameters before it steps,
//! so perturbing one parameter of a clone and reading the reported loss gives the numeric
//! derivative.
//!
//! Tolerance: as in `coadapt-nn`'s checks, f32 rounding of a loss of size ~1 (~1e-6) over a
//! central difference of step 3e-3 gives ~3e-4 of noise, and the smooth parts (tanh, log-prob,
//! squared error) a truncation error of order h^2 ~ 1e-5; so each coordinate must agree within
//! 2e-3 * max(1, |g|). ReLU kinks make the loss non-differentiable on a set of measure zero; a
//! coordinate whose +-h perturbation straddles one can miss, so at most 2 % of the coordinates
//! may disagree. (The exact check of every coordinate is `reference.rs`, against PyTorch.)

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Batch, rng};
use coadapt_learner::{Ddpg, DdpgConfig, Sac, SacConfig};
use rand::Rng;
use rand_distr::StandardNormal;

const H: f32 = 3e-3;

fn batch(rows: usize, obs: usize, act: usize) -> Batch {
    let mut r = rng(5, 0);
    let mut b = Batch::new(rows, obs, act);
    for v in b.obs.iter_mut().chain(b.next_obs.iter_mut()).chain(b.rew.iter_mut()) {
        *v = r.sample(StandardNormal);
    }
    for v in &mut b.act {
        *v = r.random_range(-0.9..0.9);
    }
    b.done[rows / 2] = 1.0;
    b
}

fn check(name: &str, analytic: &[f32], numeric: &[f64]) {
    let bad: Vec<usize> =
        (0..analytic.len()).filter(|&i| (analytic[i] as f64 - numeric[i]).abs() > 2e-3 * numeric[i].abs().max(1.0)).collect();
    assert!(
        bad.len() * 50 <= analytic.len(),
        "{name}: {} of {} coordinates disagree, e.g. [{}] analytic {} numeric {}",
        bad.len(),
        analytic.len(),
        bad[0],
        analytic[bad[0]],
        numeric[bad[0]]
    );
    assert!(analytic.iter().any(|g| g.abs() > 1e-3), "{name}: gradient is trivially small");
}

fn sac() -> (Sac, Batch, Vec<f32>, Vec<f32>) {
    let (obs, act, rows) = (4, 2, 8);
    let cfg = SacConfig {
        hidden: vec![16, 16],
        grad_clamp: 0.0,
        policy_final_init: 0.5,
        critic_final_init: 0.5,
        alpha: 0.2,
        ..SacConfig::default()
    };
    let sac = Sac::new(obs, act, cfg, 3).unwrap();
    let mut r = rng(6, 0);
    let eps: Vec<f32> = (0..rows * act).map(|_| r.sample(StandardNormal)).collect();
    let eps_next: Vec<f32> = (0..rows * act).map(|_| r.sample(StandardNormal)).collect();
    (sac, batch(rows, obs, act), eps, eps_next)
}

#[test]
fn sac_policy_and_critic_gradients_match_finite_differences() {
    let (sac, b, eps, eps_next) = sac();
    let mut base = sac.clone();
    base.update_with_given_noise(&b, &eps, &eps_next);
    let (g_pi, g_q1) = base.last_gradients();
    let (g_pi, g_q1) = (g_pi.to_vec(), g_q1.to_vec());

    let phi = sac.policy_params().to_vec();
    let (q1, q1_bar) = sac.critic_params(0);
    let (q2, q2_bar) = sac.critic_params(1);
    let (q1, q1_bar, q2, q2_bar) = (q1.to_vec(), q1_bar.to_vec(), q2.to_vec(), q2_bar.to_vec());

    let loss_at = |phi: &[f32], q1: &[f32]| {
        let mut s = sac.clone();
        s.set_params(phi, [q1, &q2], [&q1_bar, &q2_bar]);
        s.update_with_given_noise(&b, &eps, &eps_next)
    };
    let numeric_pi: Vec<f64> = (0..phi.len())
        .map(|k| {
            let (mut p, mut m) = (phi.clone(), phi.clone());
            p[k] += H;
            m[k] -= H;
            (loss_at(&p, &q1).policy as f64 - loss_at(&m, &q1).policy as f64) / (2.0 * H as f64)
        })
        .collect();
    check("dJ_pi/dphi", &g_pi, &numeric_pi);

    let numeric_q: Vec<f64> = (0..q1.len())
        .map(|k| {
            let (mut p, mut m) = (q1.clone(), q1.clone());
            p[k] += H;
            m[k] -= H;
            (loss_at(&phi, &p).q1 as f64 - loss_at(&phi, &m).q1 as f64) / (2.0 * H as f64)
        })
        .collect();
    check("dJ_Q1/dtheta1", &g_q1, &numeric_q);
}

#[test]
fn ddpg_actor_and_critic_gradients_match_finite_differences() {
    let (obs, act, rows) = (4, 2, 8);
    let cfg = DdpgConfig { hidden: vec![16, 16], grad_clamp: 0.0, final_init: 0.5, ..DdpgConfig::default() };
    let ddpg = Ddpg::new(obs, act, cfg, 4).unwrap();
    let b = batch(rows, obs, act);
    let mut base = ddpg.clone();
    base.update(&b);
    let (g_mu, g_q) = base.last_gradients();
    let (g_mu, g_q) = (g_mu.to_vec(), g_q.to_vec());

    // Targets differ from the online networks so the check covers the target path.
    let mut r = rng(8, 0);
    let phi = ddpg.actor_params().to_vec();
    let mut probe = ddpg.clone();
    let theta: Vec<f32> = {
        let mut t = vec![0.0; ddpg.critic().n_params()];
        ddpg.critic().init(&mut t, 0.5, &mut r);
        t
    };
    let phi_bar: Vec<f32> = phi.iter().map(|p| p + 0.05 * r.sample::<f32, _>(StandardNormal)).collect();
    let theta_bar: Vec<f32> = theta.iter().map(|p| p + 0.05 * r.sample::<f32, _>(StandardNormal)).collect();
    probe.set_params(&phi, &theta, &phi_bar, &theta_bar);
    let mut base = probe.clone();
    base.update(&b);
    let (g_mu2, g_q2) = base.last_gradients();
    let losses_at = |phi: &[f32], theta: &[f32]| {
        let mut d = probe.clone();
        d.set_params(phi, theta, &phi_bar, &theta_bar);
        d.update(&b)
    };
    let numeric_mu: Vec<f64> = (0..phi.len())
        .map(|k| {
            let (mut p, mut m) = (phi.clone(), phi.clone());
            p[k] += H;
            m[k] -= H;
            (losses_at(&p, &theta).actor as f64 - losses_at(&m, &theta).actor as f64) / (2.0 * H as f64)
        })
        .collect();
    check("dJ_mu/dphi", g_mu2, &numeric_mu);
    let numeric_q: Vec<f64> = (0..theta.len())
        .map(|k| {
            let (mut p, mut m) = (theta.clone(), theta.clone());
            p[k] += H;
            m[k] -= H;
            (losses_at(&phi, &p).critic as f64 - losses_at(&phi, &m).critic as f64) / (2.0 * H as f64)
        })
        .collect();
    check("dJ_Q/dtheta", g_q2, &numeric_q);
    assert_eq!(g_mu.len(), g_mu2.len());
    assert_eq!(g_q.len(), g_q2.len());
}

#[test]
fn automatic_entropy_tuning_moves_alpha_towards_the_target_entropy() {
    let (obs, act, rows) = (4, 2, 8);
    let b = batch(rows, obs, act);
    // A target entropy far above the policy's (entropy -log pi ~ 1.3 here) must raise alpha to
    // push entropy up; far below must lower it. Adam's first step moves log(alpha) by lr
    // against the sign of the gradient -(log pi + target).
    for (target, raises) in [(50.0, true), (-50.0, false)] {
        let cfg = SacConfig {
            hidden: vec![16],
            auto_alpha: true,
            target_entropy: Some(target),
            alpha: 0.1,
            alpha_lr: 0.01,
            ..SacConfig::default()
        };
        let mut sac = Sac::new(obs, act, cfg, 2).unwrap();
        let before = sac.alpha();
        let l = sac.update(&b);
        let after = sac.alpha();
        assert!((after.ln() - before.ln()).abs() > 0.009, "log alpha moved by about lr: {before} -> {after}");
        assert_eq!(after > before, raises, "target {target}, mean log pi {}: alpha {before} -> {after}", l.log_pi);
    }
    // Fixed alpha never moves.
    let mut sac = Sac::new(obs, act, SacConfig { hidden: vec![16], ..SacConfig::default() }, 2).unwrap();
    sac.update(&b);
    assert_eq!(sac.alpha(), SacConfig::default().alpha);
}
