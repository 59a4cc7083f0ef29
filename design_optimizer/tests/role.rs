//! The optimiser role's simulation baselines over a fake rollout evaluator: which reset seeds
//! the rollouts start from, and which ES candidate is trained on.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::role::{
    EsTrainOn, ExploitMethod, Optimizer, OptimizerConfig, OptimizerSpec, RolloutError, RolloutEvaluator, SimSeed,
};
use coadapt_nn::Mlp;
use coadapt_transport::{DesignKind, DesignRequest, Weights};

const OBS: usize = 4; // 2 state columns + a 2-D design
const ACT: usize = 1;

/// Records every rollout (design, seed); its fitness is a function of the design plus noise
/// drawn from the seed, so a fixed seed gives a noise-free comparison and fresh seeds do not.
#[derive(Default)]
struct Fake {
    rollouts: Vec<(Vec<f32>, u64, f32)>,
}

impl RolloutEvaluator for Fake {
    fn evaluate(&mut self, _policy: &[f32], designs: &[f32], seeds: &[u64], fitness: &mut [f32]) -> Result<(), RolloutError> {
        assert_eq!(seeds.len(), fitness.len(), "one seed per rollout");
        for ((d, &seed), f) in designs.chunks_exact(2).zip(seeds).zip(fitness.iter_mut()) {
            let noise = (seed % 1000) as f32 / 1000.0;
            *f = -(d[0] - 1.5).powi(2) - (d[1] - 1.0).powi(2) + noise;
            self.rollouts.push((d.to_vec(), seed, *f));
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

fn weights(s: &OptimizerSpec) -> Weights {
    Weights {
        version: 1,
        policy: vec![0.01; s.policy.n_params()],
        q1: vec![0.01; s.critic.n_params()],
        q2: vec![0.01; s.critic.n_params()],
        heads: vec![],
    }
}

fn request(index: u32) -> DesignRequest {
    DesignRequest {
        index,
        kind: DesignKind::Exploit,
        weights_version: 1,
        start_states: vec![0.1; 3 * OBS],
        chosen: vec![],
        rejected: vec![],
    }
}

fn sim_pso(sim_seed: SimSeed) -> Vec<(Vec<f32>, u64, f32)> {
    let mut cfg = OptimizerConfig { exploit: ExploitMethod::SimPso, sim_seed, ..OptimizerConfig::default() };
    cfg.sim_pso.particles = 5;
    cfg.sim_pso.iterations = 3;
    let mut fake = Fake::default();
    let s = spec();
    let w = weights(&s);
    let mut opt = Optimizer::new(cfg, s, Some(&mut fake), 7).unwrap();
    let reply = opt.choose(&request(3), &w).unwrap();
    assert_eq!(reply.design_rollouts, 15);
    drop(opt);
    fake.rollouts
}

#[test]
fn simulation_rollouts_start_from_a_fresh_seed_each_by_default_and_from_one_when_fixed() {
    assert_eq!(OptimizerConfig::default().sim_seed, SimSeed::Fresh, "the reference resets to a new start state per rollout");
    let fresh = sim_pso(SimSeed::Fresh);
    assert_eq!(fresh.len(), 15);
    let distinct: std::collections::BTreeSet<u64> = fresh.iter().map(|r| r.1).collect();
    assert_eq!(distinct.len(), 15, "every rollout its own seed");
    assert_eq!(sim_pso(SimSeed::Fresh), fresh, "the seeds come from the run's seed: reproducible");

    let fixed = sim_pso(SimSeed::Fixed);
    assert!(fixed.iter().all(|r| r.1 == 7), "every rollout from the run's seed");
}

#[test]
fn es_baselines_train_on_the_best_design_seen_over_all_generations() {
    assert_eq!(OptimizerConfig::default().es_train_on, EsTrainOn::BestSeen);
    for m in [ExploitMethod::OpenaiEs, ExploitMethod::CmaesEs] {
        for train_on in [EsTrainOn::BestSeen, EsTrainOn::GenerationBest] {
            let mut cfg = OptimizerConfig { exploit: m, es_train_on: train_on, ..OptimizerConfig::default() };
            cfg.openai_es.population = 6;
            cfg.cmaes_es.population = Some(6);
            let mut fake = Fake::default();
            let s = spec();
            let w = weights(&s);
            let mut opt = Optimizer::new(cfg, s, Some(&mut fake), 11).unwrap();
            let mut replies = vec![];
            for g in 0..8 {
                replies.push(opt.choose(&request(3 + g), &w).unwrap());
            }
            drop(opt);
            let mut generation_best_differs = false;
            for (g, reply) in replies.iter().enumerate() {
                assert_eq!(reply.design_rollouts, 6, "{m:?}: one generation of 6 per design");
                let seen = &fake.rollouts[..6 * (g + 1)];
                let this = &fake.rollouts[6 * g..6 * (g + 1)];
                let best = |rs: &[(Vec<f32>, u64, f32)]| rs.iter().max_by(|a, b| a.2.total_cmp(&b.2)).unwrap().0.clone();
                let (best_seen, generation_best) = (best(seen), best(this));
                generation_best_differs |= best_seen != generation_best;
                let want = if train_on == EsTrainOn::BestSeen { best_seen } else { generation_best };
                assert_eq!(reply.design, want, "{m:?} {train_on:?}, generation {g}");
            }
            assert!(generation_best_differs, "{m:?}: some generation's best was worse than an earlier one (the test tells the two apart)");
        }
    }
}

#[test]
fn a_bad_pessimism_is_refused_naming_the_field() {
    for k in [f32::NAN, -1.0, f32::INFINITY] {
        let cfg = OptimizerConfig { pessimism: k, ..OptimizerConfig::default() };
        let e = Optimizer::new(cfg, spec(), None, 1).unwrap_err().to_string();
        assert!(e.contains("optimizer.pessimism"), "{e}");
    }
}

/// Weights that make the objective depend on the design (not all equal).
fn varied_weights(s: &OptimizerSpec) -> Weights {
    let v = |n: usize, k: f32| (0..n).map(|i| (i as f32 * k).sin() * 0.5).collect::<Vec<f32>>();
    Weights {
        version: 1,
        policy: v(s.policy.n_params(), 0.7),
        q1: v(s.critic.n_params(), 1.3),
        q2: v(s.critic.n_params(), 2.1),
        heads: vec![],
    }
}

#[test]
fn calibration_scores_the_chosen_the_next_random_and_the_trained_designs_without_drawing() {
    use coadapt_design_optimizer::calibration::{CalibrationFile, Candidate};
    let cfg = OptimizerConfig { exploit: ExploitMethod::Random, ..OptimizerConfig::default() };
    let s = spec();
    let w = varied_weights(&s);
    let trained = vec![1.0, 1.0, 1.9, 0.9, 0.85, 1.7];
    let exploit = DesignRequest { chosen: trained.clone(), ..request(3) };
    let explore = DesignRequest { index: 4, kind: DesignKind::Explore, chosen: trained.clone(), ..request(4) };

    let mut opt = Optimizer::new(cfg.clone(), spec(), None, 5).unwrap();
    let reply = opt.choose(&exploit, &w).unwrap();
    let rows = opt.calibration(&exploit, &w, &reply).unwrap();
    let next = opt.choose(&explore, &w).unwrap();
    assert!(opt.calibration(&explore, &w, &next).unwrap().is_empty(), "exploration requests are not scored");

    assert_eq!(rows.len(), 5, "chosen, next random, three trained: {rows:?}");
    assert!(rows.iter().all(|r| r.request == 3));
    assert_eq!((rows[0].candidate, &rows[0].design), (Candidate::Chosen, &reply.design));
    assert_eq!(Some(rows[0].predicted), reply.predicted_objective, "the chosen design's score is the reply's");
    assert_eq!(rows[1].candidate, Candidate::NextRandom);
    assert_eq!(rows[1].design, next.design, "the design peeked at is the one the next request gets");
    for (i, r) in rows[2..].iter().enumerate() {
        assert_eq!((r.candidate, &r.design[..]), (Candidate::Trained(i as u32), &trained[2 * i..2 * i + 2]));
    }
    let scores: Vec<f32> = rows.iter().map(|r| r.predicted).collect();
    assert!(scores.iter().all(|x| x.is_finite()), "{scores:?}");
    assert!(scores.windows(2).any(|p| p[0] != p[1]), "the designs score differently: {scores:?}");

    // Scoring draws nothing: the same seed without calibration gives the same designs.
    let mut plain = Optimizer::new(cfg, spec(), None, 5).unwrap();
    assert_eq!(plain.choose(&exploit, &w).unwrap().design, reply.design);
    assert_eq!(plain.choose(&explore, &w).unwrap().design, next.design);

    // The file: a header once, one line per row, the design as designs.csv writes it.
    let dir = std::env::temp_dir().join(format!("coadapt-calibration-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = CalibrationFile::beside(&dir.join("optimizer-state.jsonl"));
    file.append(&rows).unwrap();
    file.append(&rows[..1]).unwrap();
    let text = std::fs::read_to_string(file.path()).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 1 + 5 + 1, "{text}");
    assert_eq!(lines[0], "request,candidate,trained_index,predicted_objective,design");
    assert!(
        lines[1].starts_with("3,chosen,,") && lines[2].starts_with("3,next-random,,") && lines[3].starts_with("3,trained,0,"),
        "{text}"
    );
    assert!(lines[5].ends_with("0.85;1.7"), "{text}");
}

/// A fake that sets the stop flag during its `stop_after`-th batch of rollouts (as Ctrl-C
/// landing mid-search would) and counts its batches.
struct Stopping<'a> {
    stop: &'a std::sync::atomic::AtomicBool,
    stop_after: usize,
    batches: usize,
}

impl RolloutEvaluator for Stopping<'_> {
    fn evaluate(&mut self, _policy: &[f32], _designs: &[f32], _seeds: &[u64], fitness: &mut [f32]) -> Result<(), RolloutError> {
        self.batches += 1;
        if self.batches == self.stop_after {
            self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        fitness.fill(1.0);
        Ok(())
    }
}

/// A stop during a search by simulation gives it up after the batch of rollouts under way
/// (a Daisy sim-PSO choice is minutes of them: a stop used to wait for all 30 generations);
/// the cut search is no answer (`Stopped`, not a design). Without the stop the same search
/// runs all its generations and answers.
#[test]
fn a_stop_gives_up_a_search_by_simulation_between_batches_of_rollouts() {
    use coadapt_design_optimizer::role::OptimizerError;
    use std::sync::atomic::AtomicBool;
    let mut cfg = OptimizerConfig { exploit: ExploitMethod::SimPso, ..OptimizerConfig::default() };
    cfg.sim_pso.particles = 5;
    cfg.sim_pso.iterations = 10;
    let s = spec();
    let w = weights(&s);
    for (stop_after, want_batches) in [(3, 3), (usize::MAX, 10)] {
        let stop = AtomicBool::new(false);
        let mut fake = Stopping { stop: &stop, stop_after, batches: 0 };
        let mut opt = Optimizer::new(cfg.clone(), spec(), Some(&mut fake), 7).unwrap();
        let got = opt.choose_until(&request(3), &w, &stop);
        drop(opt);
        assert_eq!(fake.batches, want_batches, "batches of rollouts run (stop during batch {stop_after})");
        match got {
            Err(OptimizerError::Stopped { index: 3 }) => assert!(stop_after < usize::MAX, "stopped with no stop"),
            Ok(reply) => {
                assert_eq!(stop_after, usize::MAX, "a cut search answered: {reply:?}");
                assert_eq!(reply.design_rollouts, 50);
            }
            Err(e) => panic!("{e}"),
        }
    }
}
