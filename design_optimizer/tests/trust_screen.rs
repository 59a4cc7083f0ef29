//! The design choices beyond the thesis (issue 28 section 3): the trust region around the
//! designs trained so far, and critic-screened rollouts. The critic here grows with both
//! design coordinates, so PSO over it runs to the box's far corner, as FEAR's critic does
//! where it extrapolates; the fake robot's return is best at the near corner instead.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::role::{ExploitMethod, Optimizer, OptimizerConfig, OptimizerSpec, RolloutError, RolloutEvaluator};
use coadapt_design_optimizer::screen::diverse_best;
use coadapt_design_optimizer::trust::TrustRegion;
use coadapt_nn::Mlp;
use coadapt_transport::{DesignKind, DesignRequest, Weights};

const OBS: usize = 4; // 2 state columns + a 2-D design at 2..4
const ACT: usize = 1;

fn spec() -> OptimizerSpec {
    OptimizerSpec {
        policy: Mlp::new(&[OBS, 8, 2 * ACT]).unwrap(),
        critic: Mlp::new(&[OBS + ACT, 8, 1]).unwrap(),
        bounds: BoxSpace::new(vec![0.8, 0.8], vec![2.0, 2.0]).unwrap(),
        design_at: 2,
        obs_dim: OBS,
        act_dim: ACT,
    }
}

/// Q(s, a, xi) = relu(xi_0 + 2 xi_1): highest at the corner (2, 2).
fn weights(s: &OptimizerSpec) -> Weights {
    let mut q = s.critic.zeros();
    let l = s.critic.layers();
    q[l[0].w + 2] = 1.0; // hidden unit 0 <- xi_0
    q[l[0].w + 3] = 2.0; // hidden unit 0 <- xi_1
    q[l[1].w] = 1.0; // output <- hidden unit 0
    Weights { version: 1, policy: s.policy.zeros(), q1: q.clone(), q2: q, heads: vec![] }
}

fn request(chosen: Vec<f32>) -> DesignRequest {
    DesignRequest { index: 5, kind: DesignKind::Exploit, weights_version: 1, start_states: vec![0.1; 3 * OBS], chosen, rejected: vec![] }
}

/// The return of a rollout: best at (1, 1), minus the seed's noise (the same for every design
/// from that seed); it records every rollout.
#[derive(Default)]
struct Robot {
    rollouts: Vec<(Vec<f32>, u64, usize)>,
}

impl RolloutEvaluator for Robot {
    fn evaluate(&mut self, _: &[f32], _: &[f32], _: &[u64], _: &mut [f32]) -> Result<(), RolloutError> {
        panic!("screened rollouts use returns(), not the baselines' evaluate()")
    }

    fn returns(&mut self, _policy: &[f32], designs: &[f32], seeds: &[u64], steps: usize, returns: &mut [f32]) -> Result<(), RolloutError> {
        for ((d, &seed), r) in designs.chunks_exact(2).zip(seeds).zip(returns.iter_mut()) {
            *r = 100.0 - 50.0 * ((d[0] - 1.0).powi(2) + (d[1] - 1.0).powi(2)) - (seed % 7) as f32;
            self.rollouts.push((d.to_vec(), seed, steps));
        }
        Ok(())
    }
}

/// Box-normalised distance in the 0.8..2.0 box.
fn dist(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| ((x - y) / 1.2).powi(2)).sum::<f32>().sqrt()
}

const TRAINED: [f32; 10] = [1.0, 1.0, 1.1, 0.9, 0.9, 1.2, 1.3, 1.0, 1.0, 1.4];

fn small(exploit: ExploitMethod) -> OptimizerConfig {
    let mut c = OptimizerConfig { exploit, cores: 1, ..OptimizerConfig::default() };
    c.pso.particles = 60;
    c.pso.iterations = 40;
    c
}

#[test]
fn the_trust_region_keeps_the_search_over_q_near_the_trained_designs_and_widens_with_them() {
    let s = spec();
    let w = weights(&s);
    let plain = Optimizer::new(small(ExploitMethod::PsoQ), spec(), None, 3).unwrap().choose(&request(TRAINED.to_vec()), &w).unwrap();
    let nearest = |d: &[f32]| TRAINED.chunks_exact(2).map(|t| dist(d, t)).fold(f32::INFINITY, f32::min);
    assert!(nearest(&plain.design) > 0.5, "without a region the critic's corner: {:?}", plain.design);

    for exploit in [ExploitMethod::PsoQ, ExploitMethod::CmaesQ] {
        let cfg = OptimizerConfig { trust_radius: 0.1, ..small(exploit) };
        let reply = Optimizer::new(cfg, spec(), None, 3).unwrap().choose(&request(TRAINED.to_vec()), &w).unwrap();
        let r = nearest(&reply.design);
        assert!(r <= 0.1 + 1e-4, "{exploit:?}: {:?} is {r} from the trained designs", reply.design);
        assert!(r > 0.09, "{exploit:?}: the best the region allows is on its edge, towards the corner: {r}");
        let better = reply.predicted_objective.unwrap();
        assert!(better > 1.0 + 2.0 * 1.4, "{exploit:?}: beyond the best trained design's score: {better}");
    }

    let bounds = spec().bounds;
    let r5 = TrustRegion::new(&TRAINED, &bounds, 0.1, 0.5).unwrap().radius();
    let r20 = TrustRegion::new(&TRAINED.repeat(4), &bounds, 0.1, 0.5).unwrap().radius();
    assert!((r5 - 0.1).abs() < 1e-6 && (r20 - 0.2).abs() < 1e-6, "r(5) {r5}, r(20) {r20}");
    assert!(TrustRegion::new(&[], &bounds, 0.1, 0.5).is_none(), "no trained design, no region");
    assert!(TrustRegion::new(&TRAINED, &bounds, 0.0, 0.5).is_none(), "radius 0 is the thesis: no region");

    let region = TrustRegion::new(&TRAINED[..2], &bounds, 0.1, 0.0).unwrap();
    let mut inside = [1.05, 1.05];
    region.project(&mut inside);
    assert_eq!(inside, [1.05, 1.05], "a design inside is left alone");
    let mut outside = [2.0, 1.0];
    region.project(&mut outside);
    assert!((dist(&outside, &[1.0, 1.0]) - 0.1).abs() < 1e-5 && (outside[1] - 1.0).abs() < 1e-6, "{outside:?}");
}

#[test]
fn screened_rollouts_let_the_robot_choose_among_the_critics_diverse_best() {
    let s = spec();
    let w = weights(&s);
    let mut cfg = small(ExploitMethod::Screened);
    cfg.screen.candidates = 4;
    cfg.screen.rollouts = 3;
    cfg.screen.steps = 100;
    cfg.screen.separation = 0.3;
    let mut robot = Robot::default();
    let reply = Optimizer::new(cfg, spec(), Some(&mut robot), 3).unwrap().choose(&request(TRAINED.to_vec()), &w).unwrap();
    assert_eq!((reply.method.as_str(), reply.design_rollouts), ("screened", 12));
    assert_eq!(robot.rollouts.len(), 12);
    assert!(robot.rollouts.iter().all(|r| r.2 == 100), "short rollouts of screen.steps");

    let candidates: Vec<&Vec<f32>> = robot.rollouts.iter().step_by(3).map(|r| &r.0).collect();
    for (i, c) in robot.rollouts.chunks_exact(3).enumerate() {
        assert!(c.iter().all(|r| &r.0 == candidates[i]), "three rollouts of each candidate in turn");
        let seeds: Vec<u64> = c.iter().map(|r| r.1).collect();
        let first: Vec<u64> = robot.rollouts[..3].iter().map(|r| r.1).collect();
        assert_eq!(seeds, first, "every candidate from the same reset seeds");
    }
    for (i, a) in candidates.iter().enumerate() {
        for b in &candidates[i + 1..] {
            assert!(dist(a, b) >= 0.3, "candidates {a:?} and {b:?} closer than screen.separation");
        }
    }
    let fear = Optimizer::new(small(ExploitMethod::PsoQ), spec(), None, 3).unwrap().choose(&request(TRAINED.to_vec()), &w).unwrap();
    assert_eq!(candidates[0], &fear.design, "the first candidate is FEAR's own answer");
    let robot_best = candidates.iter().min_by(|a, b| dist(a, &[1.0, 1.0]).total_cmp(&dist(b, &[1.0, 1.0]))).unwrap();
    assert_eq!(&reply.design, *robot_best, "the candidate the robot does best with wins");
    assert_ne!(reply.design, fear.design, "here the robot overrules the critic");

    // One candidate is FEAR: same design, no rollouts.
    let mut one = small(ExploitMethod::Screened);
    one.screen.candidates = 1;
    let mut robot = Robot::default();
    let reply = Optimizer::new(one, spec(), Some(&mut robot), 3).unwrap().choose(&request(TRAINED.to_vec()), &w).unwrap();
    assert_eq!((reply.design, reply.design_rollouts, robot.rollouts.len()), (fear.design, 0, 0));
}

#[test]
fn bad_screen_and_trust_settings_are_refused_naming_the_field() {
    let mut robot = Robot::default();
    let bad = [
        (OptimizerConfig { trust_radius: -0.1, ..small(ExploitMethod::PsoQ) }, "optimizer.trust-radius"),
        (OptimizerConfig { trust_growth: f32::NAN, ..small(ExploitMethod::PsoQ) }, "optimizer.trust-growth"),
    ];
    for (cfg, field) in bad {
        let e = Optimizer::new(cfg, spec(), None, 1).unwrap_err().to_string();
        assert!(e.contains(field), "{e}");
    }
    let mut cfg = small(ExploitMethod::Screened);
    cfg.screen.rollouts = 0;
    let e = Optimizer::new(cfg, spec(), Some(&mut robot), 1).unwrap_err().to_string();
    assert!(e.contains("optimizer.screen.rollouts"), "{e}");
    let e = Optimizer::new(small(ExploitMethod::Screened), spec(), None, 1).unwrap_err().to_string();
    assert!(e.contains("needs simulation rollouts"), "{e}");
}

#[test]
fn diverse_best_takes_the_best_first_and_skips_near_ones() {
    let designs = [0.0, 0.0, 0.05, 0.0, 1.0, 1.0, 0.5, 0.5, 2.0, 2.0];
    let scores = [5.0, 4.0, 3.0, f32::NAN, f32::NEG_INFINITY];
    let picked = diverse_best(&designs, &scores, 2, &[1.0, 1.0], 3, 0.1);
    assert_eq!(picked, vec![vec![0.0, 0.0], vec![1.0, 1.0]], "0.05 away is too near; NaN and -inf never count");
}
