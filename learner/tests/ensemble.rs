//! The population critic's ensemble heads (`learner.population-critics`, issue 28 section 3):
//! they fit the twin's Bellman target, change nothing the twin, the policy or an action does,
//! travel in checkpoints and snapshots, and a snapshot with another count of heads is refused.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Batch, Transition};
use coadapt_learner::fear::{ActingPolicy, FearLearner, FearLearnerConfig};
use coadapt_learner::{Sac, SacConfig, snapshot};

fn cfg(critics: usize) -> FearLearnerConfig {
    FearLearnerConfig {
        sac: SacConfig { hidden: vec![16], batch_size: 8, ..SacConfig::default() },
        population_batch: 2,
        species_batch: 6,
        individual_updates: 5,
        population_updates: 3,
        population_updates_from_design: 0,
        warmup_episodes: 1,
        population_critics: critics,
        ..FearLearnerConfig::default()
    }
}

fn episode(l: &mut FearLearner, design: f32) {
    l.add_start_state(&[0.1, design]).unwrap();
    for k in 0..10 {
        let (o, n) = ([k as f32 * 0.1, design], [(k + 1) as f32 * 0.1, design]);
        let r = (k as f32 * 0.3 + design).sin();
        l.add_transition(&Transition { obs: &o, action: &[0.5 - 0.1 * k as f32], reward: r, next_obs: &n, terminated: false }).unwrap();
    }
}

fn train(l: &mut FearLearner, designs: usize) {
    for d in 0..designs {
        l.begin_design(d);
        for _ in 0..3 {
            episode(l, d as f32 * 0.3);
            l.end_episode().unwrap();
        }
    }
}

#[test]
fn heads_only_watch_the_twin_policy_and_actions_are_those_of_plain_fear() {
    let (mut plain, mut ens) = (FearLearner::new(2, 1, cfg(2), 7).unwrap(), FearLearner::new(2, 1, cfg(5), 7).unwrap());
    let start: Vec<Vec<f32>> = {
        let p = ens.agent(ActingPolicy::Population);
        (0..p.extra_heads()).map(|i| p.head_params(i).to_vec()).collect()
    };
    train(&mut plain, 3);
    train(&mut ens, 3);
    for which in [ActingPolicy::Population, ActingPolicy::Individual] {
        let (a, b) = (plain.agent(which), ens.agent(which));
        assert_eq!(a.policy_params(), b.policy_params(), "{which:?} policy");
        for i in 0..2 {
            assert_eq!(a.critic_params(i), b.critic_params(i), "{which:?} critic {i} and target");
        }
        assert_eq!(a.alpha(), b.alpha());
    }
    let (mut x, mut y) = ([0.0f32], [0.0f32]);
    plain.agent_mut(ActingPolicy::Population).act(&[0.3, 0.2], false, &mut x);
    ens.agent_mut(ActingPolicy::Population).act(&[0.3, 0.2], false, &mut y);
    assert_eq!(x, y, "the same noise: the heads drew nothing from the agent's generator");
    let p = ens.agent(ActingPolicy::Population);
    assert_eq!(p.extra_heads(), 3);
    assert_eq!(ens.agent(ActingPolicy::Individual).extra_heads(), 0, "the individual pair has only the twin");
    for (i, s) in start.iter().enumerate() {
        assert_ne!(p.head_params(i), s.as_slice(), "head {i} trained");
        for j in 0..i {
            assert_ne!(p.head_params(i), p.head_params(j), "heads {i} and {j} start apart and stay apart");
        }
    }
}

/// A head and critic 1 fit the same loss on the same rows and target, so a head that starts as
/// critic 1 (fresh Adam both) takes exactly critic 1's step; critic 1's gradient is the one
/// checked against PyTorch (`reference.rs`) and finite differences (`gradcheck.rs`). A head
/// fitted to anything else (another target, rows [s, a~], no clamp) would step elsewhere.
#[test]
fn a_head_that_starts_as_critic_1_steps_exactly_as_critic_1() {
    let sac_cfg = SacConfig { hidden: vec![16, 16], batch_size: 8, grad_clamp: 0.5, ..SacConfig::default() };
    let mut sac = Sac::with_heads(3, 2, sac_cfg, 3, 2).unwrap();
    let q1 = sac.critic_params(0).0.to_vec();
    sac.set_head_params(1, &q1);
    let mut b = Batch::new(8, 3, 2);
    for (i, v) in b.obs.iter_mut().enumerate() {
        *v = (i as f32 * 0.37).sin();
    }
    for (i, v) in b.next_obs.iter_mut().enumerate() {
        *v = (i as f32 * 0.21).cos();
    }
    for (i, v) in b.act.iter_mut().enumerate() {
        *v = (i as f32 * 0.53).sin() * 0.9;
    }
    for (i, v) in b.rew.iter_mut().enumerate() {
        *v = i as f32 - 3.0;
    }
    for _ in 0..3 {
        let l = sac.update(&b);
        assert!(l.heads > 0.0 && l.heads.is_finite(), "{l:?}");
        assert_eq!(sac.head_params(1), sac.critic_params(0).0, "the head took critic 1's steps");
        assert_ne!(sac.head_params(0), sac.critic_params(0).0);
    }
}

#[test]
fn heads_travel_in_snapshots_and_checkpoints_and_another_count_is_refused() {
    let dir = coadapt_test_support::scratch("learner", "ensemble-snapshot");
    std::fs::create_dir_all(&dir).unwrap();
    let mut l = FearLearner::new(2, 1, cfg(4), 5).unwrap();
    train(&mut l, 2);
    let snap = snapshot::write(&dir.join("snapshots"), 1, "src", "test", 2, |out| l.save_state(out)).unwrap();
    let mut back = FearLearner::new(2, 1, cfg(4), 99).unwrap();
    let (_, mut inp) = snapshot::load(&snap).unwrap();
    back.load_state(&mut inp).unwrap();
    // Resumed and uninterrupted learners go on identically, heads and their Adam included.
    train(&mut l, 1);
    train(&mut back, 1);
    let (a, b) = (l.agent(ActingPolicy::Population), back.agent(ActingPolicy::Population));
    for i in 0..2 {
        assert_eq!(a.head_params(i), b.head_params(i), "head {i} after the resume");
    }
    assert_eq!(a.critic_params(0), b.critic_params(0));

    for critics in [2, 6] {
        let mut other = FearLearner::new(2, 1, cfg(critics), 5).unwrap();
        let (_, mut inp) = snapshot::load(&snap).unwrap();
        let e = other.load_state(&mut inp).unwrap_err().to_string();
        assert!(e.contains("learner.population-critics") && e.contains("2 ensemble heads"), "{e}");
    }

    // A checkpoint carries the heads; a plain run's checkpoint leaves a run's own heads alone.
    let path = dir.join("population.safetensors");
    a.save(&path).unwrap();
    let mut c = FearLearner::new(2, 1, cfg(4), 1).unwrap();
    c.init_population(&path).unwrap();
    assert_eq!(c.agent(ActingPolicy::Population).head_params(1), a.head_params(1));
    let plain_path = dir.join("plain.safetensors");
    FearLearner::new(2, 1, cfg(2), 3).unwrap().agent(ActingPolicy::Population).save(&plain_path).unwrap();
    let mut d = FearLearner::new(2, 1, cfg(4), 1).unwrap();
    let own = d.agent(ActingPolicy::Population).head_params(0).to_vec();
    d.init_population(&plain_path).unwrap();
    assert_eq!(d.agent(ActingPolicy::Population).head_params(0), own.as_slice());
}

#[test]
fn fewer_than_two_critics_is_a_setting_that_cannot_work() {
    for n in [0, 1] {
        let e = cfg(n).check().unwrap_err().to_string();
        assert!(e.starts_with("learner.population-critics: "), "{e}");
    }
    cfg(2).check().unwrap();
    cfg(7).check().unwrap();
}
