//! The FEAR learner's schedule: warm-up, individual and population updates, copies at a new
//! design, start states.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::Transition;
use coadapt_learner::SacConfig;
use coadapt_learner::fear::{ActingPolicy, FearLearner, FearLearnerConfig};

fn cfg() -> FearLearnerConfig {
    FearLearnerConfig {
        sac: SacConfig { hidden: vec![16], batch_size: 8, ..SacConfig::default() },
        population_batch: 2,
        species_batch: 6,
        individual_updates: 5,
        population_updates: 3,
        ..FearLearnerConfig::default()
    }
}

fn episode(l: &mut FearLearner, design: f32) {
    let obs = [0.1, design];
    l.add_start_state(&obs).unwrap();
    for k in 0..10 {
        let o = [k as f32 * 0.1, design];
        let n = [(k + 1) as f32 * 0.1, design];
        l.add_transition(&Transition { obs: &o, action: &[0.5], reward: 1.0, next_obs: &n, terminated: false }).unwrap();
    }
}

#[test]
fn schedule_follows_algorithm_4() {
    let mut l = FearLearner::new(2, 1, cfg(), 1).unwrap();
    let mut log = vec![];
    for design in 0..4 {
        l.begin_design(design);
        assert_eq!(
            l.agent(ActingPolicy::Individual).policy_params(),
            l.agent(ActingPolicy::Population).policy_params(),
            "individual starts as a copy of the population"
        );
        for ep in 0..5 {
            let acting = l.acting();
            assert_eq!(acting, if ep < 3 { ActingPolicy::Population } else { ActingPolicy::Individual });
            episode(&mut l, design as f32);
            let t = l.end_episode().unwrap();
            log.push((design, ep, t.individual_updates, t.population_updates));
        }
    }
    for (design, ep, ind, pop) in log {
        let warm = ep < 3;
        assert_eq!(ind, if warm { 0 } else { 5 }, "design {design} episode {ep}");
        assert_eq!(pop, if warm || design < 2 { 0 } else { 3 }, "design {design} episode {ep}");
    }
    assert_eq!(l.start_states(), 20);
    assert_eq!(l.population_transitions(), 200);
    let s = l.sample_start_states(4).unwrap();
    assert_eq!(s.len(), 8);
    assert!(s.chunks(2).all(|o| o[0] == 0.1));
}

#[test]
fn population_only_ablation_trains_and_acts_with_the_population() {
    let mut l = FearLearner::new(2, 1, FearLearnerConfig { population_only: true, warmup_episodes: 0, ..cfg() }, 2).unwrap();
    l.begin_design(0);
    assert_eq!(l.acting(), ActingPolicy::Population);
    let before = l.agent(ActingPolicy::Population).policy_params().to_vec();
    episode(&mut l, 1.0);
    let t = l.end_episode().unwrap();
    assert_eq!((t.individual_updates, t.population_updates), (0, 5));
    assert_ne!(l.agent(ActingPolicy::Population).policy_params(), &before[..]);
}
