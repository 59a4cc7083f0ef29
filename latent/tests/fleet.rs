//! Planning in the actor: a [`LatentActor`] given the agent's packed weights acts and plans
//! exactly as the agent; bad weights are refused and change nothing; Alg. 3 through a fleet
//! of actor threads gives the in-process run bit for bit; an actor that goes silent has its
//! episode taken over after the lease.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_latent::{
    ActingWeightsError, AgentConfig, CriticKind, Embedding, EmbeddingConfig, EpisodeRunner, Explore, LatentActor, LatentAgent, Objective,
    run_actor,
};
use coadapt_learner::config::DdpgConfig;
use rand::SeedableRng;

const SIDE: usize = 32;
const STEPS: usize = 25;

fn env() -> Pixels<Box<dyn Env>> {
    let px = PixelsConfig { width: SIDE, height: SIDE, frames: 1, action_repeat: 2 };
    Pixels::new(coadapt_robots::make("pendulum").unwrap(), px).unwrap()
}

fn embedding() -> (Embedding, Vec<f32>) {
    let emb = Embedding::new(EmbeddingConfig { image: SIDE, in_channels: 3, channels: [8, 8, 8], latent: 4, margin: 1.0 }).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    let (mut enc, mut dec) = (vec![0.0; emb.encoder_params()], vec![0.0; emb.decoder_params()]);
    emb.init(&mut enc, &mut dec, &mut rng);
    (emb, enc)
}

fn config(explore: Explore, critic: CriticKind, objective: Objective) -> AgentConfig {
    AgentConfig {
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
    }
}

fn agent(cfg: &AgentConfig) -> LatentAgent {
    let (emb, enc) = embedding();
    let mut rng = coadapt_core::rng(1, 11);
    LatentAgent::new(cfg.clone(), emb, enc, 3, 1, 1, &mut rng).unwrap()
}

fn actor(cfg: &AgentConfig) -> LatentActor {
    let emb = Embedding::new(EmbeddingConfig { image: SIDE, in_channels: 3, channels: [8, 8, 8], latent: 4, margin: 1.0 }).unwrap();
    LatentActor::new(cfg.clone(), emb, 3, 1, 7).unwrap()
}

/// One episode of the agent in process (as `coadapt latent` runs it); its return.
fn local_episode(agent: &mut LatentAgent, env: &mut Pixels<Box<dyn Env>>, seed: u64, train: bool) -> f32 {
    let n = agent.image_len();
    let design = env.spec().default_design.clone();
    let first = env.reset(seed, &design).unwrap()[..n].to_vec();
    let mut z = agent.reset(&first).to_vec();
    let mut a = vec![0.0; 1];
    let mut ret = 0.0;
    for _ in 0..STEPS {
        agent.act(train, &mut a);
        let s = env.step(&a).unwrap();
        let (r, term, trunc, frame) = (s.reward, s.terminated, s.truncated, s.observation[..n].to_vec());
        let next = agent.observe(&frame).to_vec();
        if train {
            agent.store(&z, &a, r, &next, term).unwrap();
        }
        ret += r;
        z = next;
        if term || trunc {
            break;
        }
    }
    ret
}

/// After two trained episodes (weights far from their initialisation), the actor with the
/// agent's packed weights takes the agent's actions bit for bit: deterministic and planned,
/// for each critic and objective.
#[test]
fn the_actor_acts_and_plans_as_the_agent() {
    for (critic, objective) in [(CriticKind::Q, Objective::SumQ), (CriticKind::V, Objective::SumQ), (CriticKind::Q, Objective::RewardPlusQ)]
    {
        let cfg = config(Explore::Plan, critic, objective);
        let mut ag = agent(&cfg);
        let mut e = env();
        let mut rng = coadapt_core::rng(3, 0);
        for ep in 0..2 {
            local_episode(&mut ag, &mut e, ep, true);
            ag.train(&mut rng);
        }
        let mut ac = actor(&cfg);
        assert!(!ac.loaded());
        let mut w = Vec::new();
        ag.acting_weights(&mut w);
        assert_eq!(w.len(), ac.weights_len(), "{critic:?} {objective:?}");
        ac.set_weights(&w).unwrap();
        let n = ag.image_len();
        let design = e.spec().default_design.clone();
        let first = e.reset(9, &design).unwrap()[..n].to_vec();
        assert_eq!(ag.reset(&first), ac.reset(&first));
        let (mut a1, mut a2) = (vec![0.0; 1], vec![0.0; 1]);
        let mut planned = 0;
        for t in 0..10 {
            let explore = t % 2 == 0;
            let p1 = ag.act(explore, &mut a1);
            let p2 = ac.act(explore, &mut a2);
            assert_eq!(p1, p2, "{critic:?} {objective:?} step {t}");
            assert_eq!(a1, a2, "{critic:?} {objective:?} step {t}");
            planned += usize::from(p1.is_some());
            let frame = e.step(&a1).unwrap().observation[..n].to_vec();
            assert_eq!(ag.observe(&frame), ac.observe(&frame));
        }
        assert_eq!(planned, 5);
    }
}

/// Weights of the wrong length or with a NaN are refused naming what is wrong; the actor acts
/// on with the parameters it had.
#[test]
fn bad_acting_weights_are_refused_and_change_nothing() {
    let cfg = config(Explore::Plan, CriticKind::Q, Objective::SumQ);
    let ag = agent(&cfg);
    let mut ac = actor(&cfg);
    let mut w = Vec::new();
    ag.acting_weights(&mut w);
    ac.set_weights(&w).unwrap();
    let mut e = env();
    let n = ac.image_len();
    let design = e.spec().default_design.clone();
    let first = e.reset(1, &design).unwrap()[..n].to_vec();
    ac.reset(&first);
    let mut before = vec![0.0; 1];
    ac.act(false, &mut before);
    let err = ac.set_weights(&w[1..]).unwrap_err();
    assert_eq!(err, ActingWeightsError::Len { expected: w.len(), got: w.len() - 1 });
    let mut bad = w.iter().map(|v| v + 0.5).collect::<Vec<_>>();
    bad[123] = f32::NAN;
    assert_eq!(ac.set_weights(&bad).unwrap_err(), ActingWeightsError::NonFinite { index: 123 });
    let mut after = vec![0.0; 1];
    ac.act(false, &mut after);
    assert_eq!(before, after, "a refused message changed the actor");
    // Another critic's weights do not fit.
    let v = agent(&config(Explore::Plan, CriticKind::V, Objective::SumQ));
    v.acting_weights(&mut w);
    assert!(matches!(ac.set_weights(&w), Err(ActingWeightsError::Len { .. })));
}

/// Actor threads over the in-process transport, each planning with its own [`LatentActor`].
fn actor_threads(
    cfg: &AgentConfig,
    actors: Vec<coadapt_transport::ActorLinks>,
    stop: &Arc<AtomicBool>,
) -> Vec<std::thread::JoinHandle<(u64, usize)>> {
    actors
        .into_iter()
        .enumerate()
        .map(|(i, mut links)| {
            let (cfg, stop) = (cfg.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut ac = actor(&cfg);
                let mut e = env();
                let mut planned = 0;
                let n = run_actor(&mut ac, &mut e, STEPS, i as u64, &mut links, &stop, &mut |ep| planned += ep.plan_ms.len()).unwrap();
                (n, planned)
            })
        })
        .collect()
}

/// Alg. 3 with planning through two actor threads gives the in-process run bit for bit:
/// the same returns, replay and trained networks.
#[test]
fn a_fleet_run_equals_the_in_process_run() {
    let cfg = config(Explore::Plan, CriticKind::Q, Objective::SumQ);
    let episodes = 3;
    let (mut local, mut e) = (agent(&cfg), env());
    let mut rng = coadapt_core::rng(3, 0);
    let mut want = Vec::new();
    for ep in 0..episodes {
        let tr = local_episode(&mut local, &mut e, 100 + 2 * ep, true);
        local.train(&mut rng);
        let ev = local_episode(&mut local, &mut e, 101 + 2 * ep, false);
        want.push((tr, ev));
    }

    let (learner, actors, _opt) = coadapt_transport::in_process::fleet(2);
    let stop = Arc::new(AtomicBool::new(false));
    let threads = actor_threads(&cfg, actors, &stop);
    let mut remote = agent(&cfg);
    let mut runner = EpisodeRunner::new(learner, 12, 1, STEPS);
    let mut rng = coadapt_core::rng(3, 0);
    let mut got = Vec::new();
    for ep in 0..episodes {
        let tr = runner.episode(&mut remote, true, 100 + 2 * ep, ep as u32).unwrap();
        remote.train(&mut rng);
        let ev = runner.episode(&mut remote, false, 101 + 2 * ep, ep as u32).unwrap();
        assert_eq!((tr.steps, ev.steps, tr.reissued), (STEPS, STEPS, 0));
        got.push((tr.episode_return, ev.episode_return));
    }
    drop(runner);
    let done: Vec<(u64, usize)> = threads.into_iter().map(|t| t.join().unwrap()).collect();
    assert_eq!(done.iter().map(|d| d.0).sum::<u64>(), 2 * episodes, "{done:?}");
    assert_eq!(done.iter().map(|d| d.1).sum::<usize>(), episodes as usize * STEPS, "every training step planned");
    assert_eq!(got, want);
    assert_eq!(remote.replay.len(), local.replay.len());
    let (mut wl, mut wr) = (Vec::new(), Vec::new());
    local.acting_weights(&mut wl);
    remote.acting_weights(&mut wr);
    assert!(wl == wr, "the trained networks differ");
}

/// An actor that takes an episode and goes silent: after the lease the episode goes to the
/// other actor, and only the finished copy reaches the replay.
#[test]
fn a_silent_actors_episode_is_taken_over() {
    let cfg = config(Explore::OrnsteinUhlenbeck, CriticKind::Q, Objective::SumQ);
    let (learner, mut actors, _opt) = coadapt_transport::in_process::fleet(2);
    let stop = Arc::new(AtomicBool::new(false));
    // The hung actor: takes the first assignment, sends one chunk's worth of nothing, hangs.
    let mut hung = actors.remove(0);
    let hung_stop = stop.clone();
    let took = Arc::new(AtomicBool::new(false));
    let took2 = took.clone();
    let hung_thread = std::thread::spawn(move || {
        while !hung_stop.load(Ordering::Relaxed) {
            if !took2.load(Ordering::Relaxed)
                && let Ok(Some(_)) = hung.assignments.recv_timeout(Duration::from_millis(20))
            {
                took2.store(true, Ordering::Relaxed);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    });
    let mut runner = EpisodeRunner::new(learner, 12, 1, STEPS);
    runner.set_lease(Duration::from_millis(300));
    let mut ag = agent(&cfg);
    // The healthy actor starts only after the hung one holds the assignment.
    let runner_thread = std::thread::spawn(move || {
        let ep = runner.episode(&mut ag, true, 5, 0);
        (ep, ag.replay.len(), runner)
    });
    while !took.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let threads = actor_threads(&cfg, actors, &stop);
    let (ep, stored, runner) = runner_thread.join().unwrap();
    let ep = ep.unwrap();
    assert_eq!((ep.reissued, ep.actor, ep.steps, stored), (1, 0, STEPS, STEPS));
    drop(runner);
    stop.store(true, Ordering::Relaxed);
    hung_thread.join().unwrap();
    for t in threads {
        assert_eq!(t.join().unwrap().0, 1);
    }
}
