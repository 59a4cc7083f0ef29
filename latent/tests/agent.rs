//! Alg. 3's loop on a robot seen through the camera: planned actions stay in the box and never
//! score below the actor's own rollout they start from; every step lands in the replay; the
//! model learns at the episodes' ends.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_latent::{AgentConfig, Critic, CriticKind, Embedding, EmbeddingConfig, Explore, LatentAgent, Objective};
use coadapt_learner::config::DdpgConfig;
use rand::SeedableRng;

fn run(explore: Explore, critic: CriticKind, objective: Objective) -> (LatentAgent, Vec<f32>, usize) {
    let side = 32;
    let px = PixelsConfig { width: side, height: side, frames: 1, action_repeat: 2 };
    let mut env = Pixels::new(coadapt_robots::make("pendulum").unwrap(), px).unwrap();
    let n = 3 * side * side;
    let emb = Embedding::new(EmbeddingConfig { image: side, in_channels: 3, channels: [8, 8, 8], latent: 4, margin: 1.0 }).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    let (mut enc, mut dec) = (vec![0.0; emb.encoder_params()], vec![0.0; emb.decoder_params()]);
    emb.init(&mut enc, &mut dec, &mut rng);
    let cfg = AgentConfig {
        explore,
        critic,
        objective,
        horizon: 3,
        plan_iterations: 5,
        model_hidden: vec![32, 32],
        updates_per_episode: 20,
        replay_capacity: 1000,
        ddpg: DdpgConfig { hidden: vec![32, 32], batch_size: 16, sigma: 0.5, theta: 0.15, ..DdpgConfig::default() },
        ..AgentConfig::default()
    };
    let act = env.spec().act_dim();
    let mut agent = LatentAgent::new(cfg, emb, enc, 3, act, 1, &mut rng).unwrap();
    let design = env.spec().default_design.clone();
    let mut model_losses = Vec::new();
    let mut planned = 0;
    for episode in 0..4 {
        let first = env.reset(episode, &design).unwrap()[..n].to_vec();
        let mut z = agent.reset(&first).to_vec();
        let mut a = vec![0.0; act];
        for _ in 0..30 {
            if let Some((after, before)) = agent.act(true, &mut a) {
                assert!(after >= before - 1e-6, "the plan scored {after} below the actor's rollout {before}");
                planned += 1;
            }
            assert!(a.iter().all(|v| (-1.0..=1.0).contains(v)), "{a:?}");
            let s = env.step(&a).unwrap();
            let (r, done, frame) = (s.reward, s.terminated, s.observation[..n].to_vec());
            let next = agent.observe(&frame).to_vec();
            agent.store(&z, &a, r, &next, done).unwrap();
            z = next;
        }
        model_losses.push(agent.train(&mut rng));
    }
    (agent, model_losses, planned)
}

#[test]
fn planned_exploration_runs_alg_3() {
    let (agent, losses, planned) = run(Explore::Plan, CriticKind::Q, Objective::SumQ);
    assert_eq!(agent.replay.len(), 120);
    assert_eq!(planned, 120, "every training step planned");
    assert!(losses.iter().all(|l| l.is_finite()), "{losses:?}");
    assert!(losses[3] < losses[0], "the model did not learn: {losses:?}");
}

#[test]
fn ou_exploration_is_the_baseline() {
    let (agent, losses, planned) = run(Explore::OrnsteinUhlenbeck, CriticKind::Q, Objective::SumQ);
    assert_eq!((agent.replay.len(), planned), (120, 0));
    assert!(losses.iter().all(|l| l.is_finite()), "{losses:?}");
}

#[test]
fn the_value_critic_plans_and_learns_through_the_model() {
    for explore in [Explore::Plan, Explore::OrnsteinUhlenbeck] {
        let (agent, losses, planned) = run(explore, CriticKind::V, Objective::SumQ);
        assert_eq!(agent.replay.len(), 120);
        assert_eq!(planned, if explore == Explore::Plan { 120 } else { 0 });
        assert!(losses[3] < losses[0], "the model did not learn: {losses:?}");
        let Critic::V(d) = &agent.critic else { panic!("a Q critic for CriticKind::V") };
        // Trained: the targets trail the parameters, everything finite.
        assert!(d.p.v.iter().chain(&d.p.phi).all(|v| v.is_finite()));
        assert!(d.p.v.iter().zip(&d.p.v_bar).any(|(a, b)| a != b), "V never stepped");
        assert!(d.p.phi.iter().zip(&d.p.phi_bar).any(|(a, b)| a != b), "the actor never stepped");
    }
}

#[test]
fn the_reward_plus_q_objective_learns_its_reward_model() {
    // The same batch scores both (a fresh generator with the same seed for each).
    let batch = || rand::rngs::StdRng::seed_from_u64(9);
    let (mut agent, _, planned) = run(Explore::Plan, CriticKind::Q, Objective::RewardPlusQ);
    assert_eq!(planned, 120);
    let trained = agent.reward_loss(&mut batch());
    // The same replay scored by an untrained reward model.
    let r = agent.reward.as_mut().expect("f_{r+Q} builds a reward model");
    let kept = r.params.clone();
    r.params.iter_mut().for_each(|p| *p *= 0.0);
    let untrained = agent.reward_loss(&mut batch());
    agent.reward.as_mut().unwrap().params = kept;
    assert!(trained.is_finite() && trained < untrained, "reward model: {trained} trained vs {untrained} at zero");
    // Other objectives need none.
    let (agent, ..) = run(Explore::Plan, CriticKind::Q, Objective::LastQ);
    assert!(agent.reward.is_none());
}
