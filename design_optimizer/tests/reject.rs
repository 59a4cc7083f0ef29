//! Designs an operator rejected as prototypes: no method proposes one again (nor anything within
//! `reject-radius` of it), the searches over Q settle on their next-best design, and a radius
//! that leaves nothing to propose is an error naming the field.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::reject::Rejected;
use coadapt_design_optimizer::role::{
    ExploitMethod, ExploreMethod, Optimizer, OptimizerConfig, OptimizerSpec, RolloutError, RolloutEvaluator, SimSeed,
};
use coadapt_nn::Mlp;
use coadapt_transport::{DesignKind, DesignReply, DesignRequest, Weights};

const OBS: usize = 4; // 2 state columns + a 2-D design
const ACT: usize = 1;

/// Fitness peaks inside the box, at (1.5, 1.0).
struct Fake;

impl RolloutEvaluator for Fake {
    fn evaluate(&mut self, _policy: &[f32], designs: &[f32], _seeds: &[u64], fitness: &mut [f32]) -> Result<(), RolloutError> {
        for (d, f) in designs.chunks_exact(2).zip(fitness.iter_mut()) {
            *f = -(d[0] - 1.5).powi(2) - (d[1] - 1.0).powi(2);
        }
        Ok(())
    }
}

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

/// Weights of a small fixed pattern, so the objective over Q has some shape.
fn weights(s: &OptimizerSpec) -> Weights {
    let wave = |n: usize, k: f32| (0..n).map(|i| 0.3 * (k * i as f32).sin()).collect::<Vec<f32>>();
    Weights {
        version: 1,
        policy: wave(s.policy.n_params(), 0.7),
        q1: wave(s.critic.n_params(), 1.3),
        q2: wave(s.critic.n_params(), 2.1),
        heads: vec![],
    }
}

fn request(index: u32, kind: DesignKind, rejected: &[f32]) -> DesignRequest {
    DesignRequest {
        index,
        kind,
        weights_version: 1,
        start_states: (0..3 * OBS).map(|i| 0.1 * i as f32).collect(),
        chosen: vec![1.0, 1.0],
        rejected: rejected.to_vec(),
    }
}

fn config(exploit: ExploitMethod, explore: ExploreMethod) -> OptimizerConfig {
    let mut c = OptimizerConfig { exploit, explore, cores: 1, sim_seed: SimSeed::Fixed, ..OptimizerConfig::default() };
    c.pso.particles = 40;
    c.pso.iterations = 20;
    c.novelty.pso.particles = 40;
    c.novelty.pso.iterations = 20;
    c.cmaes.generations = 20;
    c.sim_pso.particles = 20;
    c.sim_pso.iterations = 10;
    c.sim_cmaes.generations = 10;
    c
}

/// One request to a fresh optimiser (seed 7): the same request gives the same design.
fn choose(cfg: &OptimizerConfig, kind: DesignKind, rejected: &[f32]) -> DesignReply {
    let s = spec();
    let w = weights(&s);
    let mut fake = Fake;
    let mut opt = Optimizer::new(cfg.clone(), s, Some(&mut fake), 7).unwrap();
    opt.choose(&request(3, kind, rejected), &w).unwrap()
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    // The box is 1.2 wide in both dimensions.
    a.iter().zip(b).map(|(x, y)| ((x - y) / 1.2).powi(2)).sum::<f32>().sqrt()
}

#[test]
fn no_method_proposes_a_rejected_design_again() {
    let radius = OptimizerConfig::default().reject_radius;
    assert_eq!(radius, 0.05);
    let cases = [
        (ExploitMethod::PsoQ, ExploreMethod::Random, DesignKind::Exploit),
        (ExploitMethod::CmaesQ, ExploreMethod::Random, DesignKind::Exploit),
        (ExploitMethod::Random, ExploreMethod::Random, DesignKind::Exploit),
        (ExploitMethod::SimPso, ExploreMethod::Random, DesignKind::Exploit),
        (ExploitMethod::SimCmaes, ExploreMethod::Random, DesignKind::Exploit),
        (ExploitMethod::PsoQ, ExploreMethod::Random, DesignKind::Explore),
        (ExploitMethod::PsoQ, ExploreMethod::Novelty, DesignKind::Explore),
    ];
    for (exploit, explore, kind) in cases {
        let cfg = config(exploit, explore);
        let name = format!("{exploit:?} / {explore:?} ({kind:?})");
        let first = choose(&cfg, kind, &[]);
        assert_eq!(choose(&cfg, kind, &[]).design, first.design, "{name}: the same request, the same design");
        let second = choose(&cfg, kind, &first.design);
        assert!(distance(&second.design, &first.design) > radius, "{name}: {:?} after rejecting {:?}", second.design, first.design);
        // Rejections accumulate.
        let both = [first.design.clone(), second.design.clone()].concat();
        let third = choose(&cfg, kind, &both);
        for d in [&first.design, &second.design] {
            assert!(distance(&third.design, d) > radius, "{name}: {:?} after rejecting {both:?}", third.design);
        }
        if matches!(exploit, ExploitMethod::PsoQ | ExploitMethod::CmaesQ) && kind == DesignKind::Exploit {
            // The search over Q settles on its next-best design: no better than the first.
            let (p1, p2) = (first.predicted_objective.unwrap(), second.predicted_objective.unwrap());
            assert!(p2 <= p1 + 1e-4, "{name}: the second choice scores {p2}, the rejected one {p1}");
        }
    }
}

/// The ES baselines train on the best design seen: once that one is rejected they must not
/// propose it again in a later generation.
#[test]
fn es_baselines_drop_a_rejected_best_design() {
    for m in [ExploitMethod::OpenaiEs, ExploitMethod::CmaesEs] {
        let mut cfg = config(m, ExploreMethod::Random);
        cfg.openai_es.population = 8;
        cfg.cmaes_es.population = Some(8);
        let s = spec();
        let w = weights(&s);
        let mut fake = Fake;
        let mut opt = Optimizer::new(cfg, s, Some(&mut fake), 3).unwrap();
        let first = opt.choose(&request(3, DesignKind::Exploit, &[]), &w).unwrap();
        let again = opt.choose(&request(3, DesignKind::Exploit, &first.design), &w).unwrap();
        assert!(distance(&again.design, &first.design) > 0.05, "{m:?}: {:?} proposed again", first.design);
    }
}

#[test]
fn a_radius_that_leaves_nothing_is_an_error_naming_the_field() {
    for exploit in [ExploitMethod::Random, ExploitMethod::PsoQ] {
        let cfg = OptimizerConfig { reject_radius: 10.0, ..config(exploit, ExploreMethod::Random) };
        let s = spec();
        let w = weights(&s);
        let mut opt = Optimizer::new(cfg, s, None, 1).unwrap();
        let e = opt.choose(&request(3, DesignKind::Exploit, &[1.0, 1.0]), &w).unwrap_err().to_string();
        assert!(e.contains("optimizer.reject-radius"), "{exploit:?}: {e}");
    }
    for r in [f32::NAN, -0.1, f32::INFINITY] {
        let e = Optimizer::new(OptimizerConfig { reject_radius: r, ..OptimizerConfig::default() }, spec(), None, 1).unwrap_err();
        assert!(e.to_string().contains("optimizer.reject-radius"), "{e}");
    }
}

#[test]
fn nearness_is_measured_in_box_normalised_units() {
    let bounds = BoxSpace::new(vec![0.0, 0.0, 5.0], vec![1.0, 100.0, 5.0]).unwrap();
    let r = Rejected::new(&[0.5, 50.0, 5.0], &bounds, 0.05);
    assert!(r.near(&[0.53, 50.0, 5.0]) && r.near(&[0.5, 54.0, 5.0]), "3 % of a width is near");
    assert!(!r.near(&[0.56, 50.0, 5.0]) && !r.near(&[0.5, 56.0, 5.0]), "6 % is not");
    assert!((r.distance(&[0.53, 54.0, 5.0]) - 0.05).abs() < 1e-5, "Euclidean over the scaled dimensions; a pinned one is ignored");
    assert!(!Rejected::new(&[], &bounds, 0.05).near(&[0.5, 50.0, 5.0]), "nothing rejected, nothing near");
}
