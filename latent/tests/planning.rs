//! The planning objective f_Q (Eq. 4.11) through the latent dynamics: its value against a
//! direct rollout of the networks, its gradient against central differences and PyTorch
//! (tests/reference/planning.py); the dynamics loss's gradient against central differences.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_latent::{LatentDynamics, Planner};
use coadapt_nn::{Activations, Mlp};

const LATENT: usize = 2;
const FRAMES: usize = 3;
const ACT: usize = 2;
const H: usize = 3;

fn setup() -> (LatentDynamics, Vec<f32>, Mlp, Vec<f32>, Vec<f32>, Vec<f32>) {
    let model = LatentDynamics::new(LATENT, FRAMES, ACT, &[5, 4]).unwrap();
    let mp: Vec<f32> = (0..model.net.n_params()).map(|i| (0.5 * (0.31 * i as f64 + 0.2).sin()) as f32).collect();
    let critic = Mlp::new(&[FRAMES * LATENT + ACT, 6, 5, 1]).unwrap();
    let cp: Vec<f32> = (0..critic.n_params()).map(|i| (0.4 * (0.17 * i as f64).cos()) as f32).collect();
    let z0: Vec<f32> = (0..FRAMES * LATENT).map(|i| (0.3 * (1.3 * i as f64 + 0.5).sin()) as f32).collect();
    let actions: Vec<f32> = (0..(H + 1) * ACT).map(|i| (0.8 * (0.7 * i as f64).cos()) as f32).collect();
    (model, mp, critic, cp, z0, actions)
}

/// f_Q computed by hand: roll the stack forward, weigh Q by 1/H.
fn direct(model: &LatentDynamics, mp: &[f32], critic: &Mlp, cp: &[f32], z0: &[f32], actions: &[f32]) -> f64 {
    let (mut ma, mut ca) = (Activations::default(), Activations::default());
    let mut z = z0.to_vec();
    let mut f = 0.0;
    for j in 0..=H {
        let a = &actions[j * ACT..(j + 1) * ACT];
        let input: Vec<f32> = z.iter().chain(a).copied().collect();
        f += f64::from(critic.forward(cp, &input, 1, &mut ca)[0]) / H as f64;
        let next = model.net.forward(mp, &input, 1, &mut ma).to_vec();
        z = z[LATENT..].iter().chain(&next).copied().collect();
    }
    f
}

#[test]
fn the_objective_is_the_critic_weighed_along_the_model_rollout() {
    let (model, mp, critic, cp, z0, actions) = setup();
    let mut p = Planner::new(&model, &mp, &critic, &cp, H);
    let mut g = vec![0.0; actions.len()];
    let f = p.value_and_grad(&z0, &actions, &mut g);
    let want = direct(&model, &mp, &critic, &cp, &z0, &actions);
    assert!((f64::from(f) - want).abs() < 1e-6, "{f} vs {want}");
    // PyTorch float64: .venv-peers/bin/python latent/tests/reference/planning.py
    let (pt_f, pt_g) = reference();
    assert!((f64::from(f) - pt_f).abs() < 1e-5, "{f} vs PyTorch {pt_f}");
    for (i, (a, b)) in g.iter().zip(&pt_g).enumerate() {
        assert!((f64::from(*a) - b).abs() < 1e-5 * (1.0 + b.abs()), "df/da[{i}] = {a} vs PyTorch {b}");
    }
}

#[test]
fn the_action_gradient_matches_finite_differences() {
    let (model, mp, critic, cp, z0, actions) = setup();
    let mut p = Planner::new(&model, &mp, &critic, &cp, H);
    let mut g = vec![0.0; actions.len()];
    p.value_and_grad(&z0, &actions, &mut g);
    let h = 1e-3f32;
    for i in 0..actions.len() {
        let (mut up, mut dn) = (actions.clone(), actions.clone());
        up[i] += h;
        dn[i] -= h;
        let fd = (direct(&model, &mp, &critic, &cp, &z0, &up) - direct(&model, &mp, &critic, &cp, &z0, &dn)) / (2.0 * f64::from(h));
        assert!((fd - f64::from(g[i])).abs() < 2e-3 * (1.0 + fd.abs()), "df/da[{i}]: {} vs finite difference {fd}", g[i]);
    }
}

#[test]
fn the_dynamics_loss_gradient_matches_finite_differences() {
    let (model, mp, ..) = setup();
    let n = 4;
    let input: Vec<f32> = (0..n * (FRAMES * LATENT + ACT)).map(|i| ((0.9 * i as f64).sin()) as f32).collect();
    let target: Vec<f32> = (0..n * LATENT).map(|i| ((0.4 * i as f64).cos()) as f32).collect();
    let (mut act, mut dy) = (Activations::default(), Vec::new());
    let mut g = vec![0.0; mp.len()];
    model.loss_and_grad(&mp, &input, &target, n, &mut g, &mut act, &mut dy);
    let h = 1e-3f32;
    for i in 0..mp.len() {
        let (mut up, mut dn) = (mp.clone(), mp.clone());
        up[i] += h;
        dn[i] -= h;
        let mut scratch = vec![0.0; mp.len()];
        let lu = model.loss_and_grad(&up, &input, &target, n, &mut scratch, &mut act, &mut dy);
        let ld = model.loss_and_grad(&dn, &input, &target, n, &mut scratch, &mut act, &mut dy);
        let fd = f64::from(lu - ld) / (2.0 * f64::from(h));
        assert!((fd - f64::from(g[i])).abs() < 3e-3 * (1.0 + fd.abs()), "dL/dparam[{i}]: {} vs finite difference {fd}", g[i]);
    }
}

#[test]
fn planning_raises_the_objective_and_finds_a_known_optimum_on_the_bounds() {
    // A critic that ignores the state and rewards a = (+1, -1) linearly: the optimum of f_Q is
    // every action on those bounds, whatever the model does.
    let (model, mp, ..) = setup();
    let critic = Mlp::new(&[FRAMES * LATENT + ACT, 1]).unwrap();
    let mut cp = vec![0.0; critic.n_params()];
    cp[FRAMES * LATENT] = 0.7;
    cp[FRAMES * LATENT + 1] = -0.4;
    let z0 = vec![0.1; FRAMES * LATENT];
    let mut p = Planner::new(&model, &mp, &critic, &cp, H);
    let mut actions = vec![0.0; (H + 1) * ACT];
    let mut g = vec![0.0; actions.len()];
    let before = p.value_and_grad(&z0, &actions, &mut g);
    let mut opt = coadapt_latent::Lbfgsb::default();
    let after = p.plan(&z0, &mut actions, -1.0, 1.0, 20, &mut opt);
    assert!(after > before, "{before} -> {after}");
    for a in actions.chunks_exact(ACT) {
        assert_eq!(a, [1.0, -1.0], "{actions:?}");
    }
    // The real critic and model: 20 iterations raise f_Q and keep the actions in the box.
    let (model, mp, critic, cp, z0, mut actions) = setup();
    let mut p = Planner::new(&model, &mp, &critic, &cp, H);
    let before = direct(&model, &mp, &critic, &cp, &z0, &actions.iter().map(|a| a.clamp(-1.0, 1.0)).collect::<Vec<_>>());
    let after = p.plan(&z0, &mut actions, -1.0, 1.0, 20, &mut opt);
    assert!(f64::from(after) > before, "{before} -> {after}");
    assert!(actions.iter().all(|a| (-1.0..=1.0).contains(a)));
    assert!((f64::from(after) - direct(&model, &mp, &critic, &cp, &z0, &actions)).abs() < 1e-5);
}

/// Printed by latent/tests/reference/planning.py.
fn reference() -> (f64, Vec<f64>) {
    (REFERENCE.0, REFERENCE.1.to_vec())
}

const REFERENCE: (f64, [f64; 8]) = (
    -8.493955512075e-01,
    [
        -5.904800445553e-03,
        -6.709269528477e-03,
        4.804171856437e-02,
        4.436720630344e-02,
        7.911144188531e-02,
        7.571527468592e-02,
        6.668056890819e-02,
        6.659352892967e-02,
    ],
);
