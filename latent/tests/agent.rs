//! Alg. 3's loop on a robot seen through the camera: planned actions stay in the box and never
//! score below the actor's own rollout they start from; every step lands in the replay; the
//! model learns at the episodes' ends.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_latent::{AgentConfig, Embedding, EmbeddingConfig, Explore, LatentAgent};
use coadapt_learner::config::DdpgConfig;
use rand::SeedableRng;

fn run(explore: Explore) -> (LatentAgent, Vec<f32>, usize) {
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
    let (agent, losses, planned) = run(Explore::Plan);
    assert_eq!(agent.replay.len(), 120);
    assert_eq!(planned, 120, "every training step planned");
    assert!(losses.iter().all(|l| l.is_finite()), "{losses:?}");
    assert!(losses[3] < losses[0], "the model did not learn: {losses:?}");
}

#[test]
fn ou_exploration_is_the_baseline() {
    let (agent, losses, planned) = run(Explore::OrnsteinUhlenbeck);
    assert_eq!((agent.replay.len(), planned), (120, 0));
    assert!(losses.iter().all(|l| l.is_finite()), "{losses:?}");
}
