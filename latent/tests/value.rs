//! The value critic through the learned model (Eq. 4.9, 4.10): losses and gradients against
//! PyTorch float64 (tests/reference/value.py) and central differences.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_latent::{LatentDynamics, ValueLosses};
use coadapt_nn::Mlp;
use coadapt_test_support::reference::{self as reference, stats};

/// Within 0.0001 of PyTorch's statistics (f32 against float64).
fn close(name: &str, got: [f64; 3], want: [f64; 3]) {
    reference::close(name, got, want, 0.0001);
}

const LATENT: usize = 2;
const FRAMES: usize = 3;
const ACT: usize = 2;
const N: usize = 3;
const S: usize = FRAMES * LATENT;

struct Nets {
    model: LatentDynamics,
    v: Mlp,
    actor: Mlp,
    mp: Vec<f32>,
    vp: Vec<f32>,
    vt: Vec<f32>,
    ap: Vec<f32>,
    at: Vec<f32>,
    z: Vec<f32>,
}

fn fill(n: usize, f: impl Fn(f64) -> f64) -> Vec<f32> {
    (0..n).map(|i| f(i as f64) as f32).collect()
}

fn nets() -> Nets {
    let model = LatentDynamics::new(LATENT, FRAMES, ACT, &[5, 4]).unwrap();
    let v = Mlp::new(&[S, 6, 5, 1]).unwrap();
    let actor = Mlp::new(&[S, 5, ACT]).unwrap();
    Nets {
        mp: fill(model.net.n_params(), |i| 0.5 * (0.31 * i + 0.2).sin()),
        vp: fill(v.n_params(), |i| 0.4 * (0.17 * i).cos()),
        vt: fill(v.n_params(), |i| 0.4 * (0.19 * i + 0.3).cos()),
        ap: fill(actor.n_params(), |i| 0.6 * (0.23 * i).sin()),
        at: fill(actor.n_params(), |i| 0.6 * (0.29 * i + 0.1).sin()),
        z: fill(N * S, |i| 0.3 * (1.3 * i + 0.5).sin()),
        model,
        v,
        actor,
    }
}

const R: [f32; N] = [0.5, -0.2, 1.0];
const DONE: [bool; N] = [false, true, false];

#[test]
fn losses_and_gradients_match_pytorch() {
    let n = nets();
    let mut l = ValueLosses::new(&n.v, &n.actor, &n.model, 0.9);
    let mut gv = vec![0.0; n.vp.len()];
    let lc = l.critic(&n.vp, &n.vt, &n.at, &n.mp, &n.z, &R, &DONE, N, &mut gv);
    let mut ga = vec![0.0; n.ap.len()];
    let la = l.actor_loss(&n.ap, &n.vp, &n.mp, &n.z, N, &mut ga);
    // .venv-peers/bin/python latent/tests/reference/value.py
    assert!((f64::from(lc) - 2.323443370391e-01).abs() < 1e-6, "critic loss {lc}");
    close("grad_v", stats(&gv), [3.984726881800e+00, 2.782567170353e+02, 1.522457345355e+00]);
    assert!((f64::from(la) - -4.625012496830e-01).abs() < 1e-6, "actor loss {la}");
    close("grad_actor", stats(&ga), [1.670422915714e-02, 6.382294748011e-01, 1.968118610576e-05]);
}

#[test]
fn gradients_match_finite_differences() {
    let n = nets();
    let mut l = ValueLosses::new(&n.v, &n.actor, &n.model, 0.9);
    let mut gv = vec![0.0; n.vp.len()];
    l.critic(&n.vp, &n.vt, &n.at, &n.mp, &n.z, &R, &DONE, N, &mut gv);
    let mut ga = vec![0.0; n.ap.len()];
    l.actor_loss(&n.ap, &n.vp, &n.mp, &n.z, N, &mut ga);
    let h = 1e-3f32;
    let mut scratch_v = vec![0.0; n.vp.len()];
    let mut scratch_a = vec![0.0; n.ap.len()];
    for i in 0..n.vp.len() {
        let (mut up, mut dn) = (n.vp.clone(), n.vp.clone());
        up[i] += h;
        dn[i] -= h;
        // The target's networks stay fixed: only V's own parameters move.
        let lu = l.critic(&up, &n.vt, &n.at, &n.mp, &n.z, &R, &DONE, N, &mut scratch_v);
        let ld = l.critic(&dn, &n.vt, &n.at, &n.mp, &n.z, &R, &DONE, N, &mut scratch_v);
        let fd = f64::from(lu - ld) / (2.0 * f64::from(h));
        assert!((fd - f64::from(gv[i])).abs() < 3e-3 * (1.0 + fd.abs()), "dL_V/dv[{i}]: {} vs finite difference {fd}", gv[i]);
    }
    for i in 0..n.ap.len() {
        let (mut up, mut dn) = (n.ap.clone(), n.ap.clone());
        up[i] += h;
        dn[i] -= h;
        let lu = l.actor_loss(&up, &n.vp, &n.mp, &n.z, N, &mut scratch_a);
        let ld = l.actor_loss(&dn, &n.vp, &n.mp, &n.z, N, &mut scratch_a);
        let fd = f64::from(lu - ld) / (2.0 * f64::from(h));
        assert!((fd - f64::from(ga[i])).abs() < 3e-3 * (1.0 + fd.abs()), "dL_mu/dactor[{i}]: {} vs finite difference {fd}", ga[i]);
    }
}
