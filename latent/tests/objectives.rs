//! The three planning objectives (Eq. 4.11, Eq. 4.12 with a latent reward model, last-Q only)
//! with the Q critic and the value critic: each against a direct rollout of the networks, its
//! action gradient against central differences.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_latent::{CriticKind, LatentDynamics, Lbfgsb, Objective, Planner};
use coadapt_nn::{Activations, Mlp};

const LATENT: usize = 2;
const FRAMES: usize = 3;
const ACT: usize = 2;
const S: usize = FRAMES * LATENT;

struct Nets {
    model: LatentDynamics,
    mp: Vec<f32>,
    q: Mlp,
    qp: Vec<f32>,
    v: Mlp,
    vp: Vec<f32>,
    r: Mlp,
    rp: Vec<f32>,
}

fn wave(n: usize, a: f64, b: f64, c: f64) -> Vec<f32> {
    (0..n).map(|i| (a * (b * i as f64 + c).sin()) as f32).collect()
}

fn nets() -> Nets {
    let model = LatentDynamics::new(LATENT, FRAMES, ACT, &[5, 4]).unwrap();
    let mp = wave(model.net.n_params(), 0.5, 0.31, 0.2);
    let q = Mlp::new(&[S + ACT, 6, 5, 1]).unwrap();
    let qp = wave(q.n_params(), 0.4, 0.17, 1.0);
    let v = Mlp::new(&[S, 6, 1]).unwrap();
    let vp = wave(v.n_params(), 0.6, 0.23, 0.4);
    let r = Mlp::new(&[S, 4, 1]).unwrap();
    let rp = wave(r.n_params(), 0.7, 0.41, 0.9);
    Nets { model, mp, q, qp, v, vp, r, rp }
}

/// The objective by hand: roll the stack forward and add the weighed terms.
fn direct(n: &Nets, obj: Objective, kind: CriticKind, h: usize, z0: &[f32], actions: &[f32]) -> f64 {
    let mut act = Activations::default();
    let w = 1.0 / h as f64;
    let mut z = z0.to_vec();
    let mut f = 0.0;
    for j in 0..=h {
        let a = &actions[j * ACT..(j + 1) * ACT];
        let input: Vec<f32> = z.iter().chain(a).copied().collect();
        let next_code = n.model.net.forward(&n.mp, &input, 1, &mut act).to_vec();
        let next: Vec<f32> = z[LATENT..].iter().chain(&next_code).copied().collect();
        let critic_counts = match obj {
            Objective::SumQ => true,
            Objective::RewardPlusQ | Objective::LastQ => j == h,
        };
        if critic_counts {
            f += w * f64::from(match kind {
                CriticKind::Q => n.q.forward(&n.qp, &input, 1, &mut act)[0],
                CriticKind::V => n.v.forward(&n.vp, &next, 1, &mut act)[0],
            });
        }
        if obj == Objective::RewardPlusQ && j >= 1 && j < h {
            f += w * f64::from(n.r.forward(&n.rp, &z, 1, &mut act)[0]);
        }
        z = next;
    }
    f
}

fn planner<'a>(n: &'a Nets, obj: Objective, kind: CriticKind, h: usize) -> Planner<'a> {
    let (c, cp) = match kind {
        CriticKind::Q => (&n.q, &n.qp),
        CriticKind::V => (&n.v, &n.vp),
    };
    Planner::new(&n.model, &n.mp, c, cp, h).with(obj, kind, Some((&n.r, &n.rp))).unwrap()
}

const ALL: [(Objective, CriticKind); 6] = [
    (Objective::SumQ, CriticKind::Q),
    (Objective::RewardPlusQ, CriticKind::Q),
    (Objective::LastQ, CriticKind::Q),
    (Objective::SumQ, CriticKind::V),
    (Objective::RewardPlusQ, CriticKind::V),
    (Objective::LastQ, CriticKind::V),
];

#[test]
fn every_objective_matches_a_direct_rollout_and_finite_differences() {
    let n = nets();
    let z0 = wave(S, 0.3, 1.3, 0.5);
    for h in [1, 3, 4] {
        let actions = wave((h + 1) * ACT, 0.8, 0.7, 1.6);
        for (obj, kind) in ALL {
            let mut p = planner(&n, obj, kind, h);
            let mut g = vec![0.0; actions.len()];
            let f = p.value_and_grad(&z0, &actions, &mut g);
            let want = direct(&n, obj, kind, h, &z0, &actions);
            assert!((f64::from(f) - want).abs() < 1e-5, "{obj:?} {kind:?} H={h}: {f} vs {want}");
            let e = 1e-3f32;
            let mut nonzero = 0;
            for i in 0..actions.len() {
                let (mut up, mut dn) = (actions.clone(), actions.clone());
                up[i] += e;
                dn[i] -= e;
                let fd = (direct(&n, obj, kind, h, &z0, &up) - direct(&n, obj, kind, h, &z0, &dn)) / (2.0 * f64::from(e));
                assert!((fd - f64::from(g[i])).abs() < 2e-3 * (1.0 + fd.abs()), "{obj:?} {kind:?} H={h}: df/da[{i}] {} vs {fd}", g[i]);
                if fd.abs() > 1e-6 {
                    nonzero += 1;
                }
            }
            assert!(nonzero > 0, "{obj:?} {kind:?} H={h}: a gradient of zeros tests nothing");
        }
    }
}

#[test]
fn the_objectives_differ_where_they_should() {
    let n = nets();
    let z0 = wave(S, 0.3, 1.3, 0.5);
    let h = 3;
    let actions = wave((h + 1) * ACT, 0.8, 0.7, 1.6);
    let value = |obj, kind| {
        let mut g = vec![0.0; actions.len()];
        planner(&n, obj, kind, h).value_and_grad(&z0, &actions, &mut g)
    };
    let (sum, rq, last) =
        (value(Objective::SumQ, CriticKind::Q), value(Objective::RewardPlusQ, CriticKind::Q), value(Objective::LastQ, CriticKind::Q));
    assert!(sum != last && rq != last && sum != rq, "{sum} {rq} {last}");
    // Last-Q only: the first action moves the objective only through the model, and f_{r+Q} is
    // last-Q plus the reward terms.
    let mut act = Activations::default();
    let mut z = z0.clone();
    let mut rewards = 0.0;
    for j in 0..h {
        let input: Vec<f32> = z.iter().chain(&actions[j * ACT..(j + 1) * ACT]).copied().collect();
        let code = n.model.net.forward(&n.mp, &input, 1, &mut act).to_vec();
        z = z[LATENT..].iter().chain(&code).copied().collect();
        if j + 1 < h {
            rewards += n.r.forward(&n.rp, &z, 1, &mut act)[0] / h as f32;
        }
    }
    assert!((rq - last - rewards).abs() < 1e-5, "{rq} - {last} != {rewards}");
    // A reward-plus-q planner without a reward model is refused.
    let err = Planner::new(&n.model, &n.mp, &n.q, &n.qp, h).with(Objective::RewardPlusQ, CriticKind::Q, None).unwrap_err();
    assert!(err.to_string().contains("reward model"), "{err}");
}

#[test]
fn planning_with_the_value_critic_raises_its_objective_within_the_box() {
    let n = nets();
    let z0 = wave(S, 0.3, 1.3, 0.5);
    let h = 4;
    for obj in [Objective::SumQ, Objective::RewardPlusQ, Objective::LastQ] {
        let mut actions = wave((h + 1) * ACT, 0.8, 0.7, 1.6);
        let before = direct(&n, obj, CriticKind::V, h, &z0, &actions);
        let mut opt = Lbfgsb::default();
        let after = planner(&n, obj, CriticKind::V, h).plan(&z0, &mut actions, -1.0, 1.0, 20, &mut opt);
        assert!(f64::from(after) > before, "{obj:?}: {before} -> {after}");
        assert!(actions.iter().all(|a| (-1.0..=1.0).contains(a)));
        assert!((f64::from(after) - direct(&n, obj, CriticKind::V, h, &z0, &actions)).abs() < 1e-5);
    }
}
