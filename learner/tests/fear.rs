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
    for design in 0..5 {
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
        assert_eq!(pop, if warm || design < 3 { 0 } else { 3 }, "design {design} episode {ep}");
    }
    assert_eq!(l.start_states(), 25);
    assert_eq!(l.population_transitions(), 250);
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

/// Algorithm 4's "pi_indvd = pi_pop, Q_indvd = Q_pop" at a new design: after the individual pair
/// has trained away from the population pair, `begin_design` makes every network (policy, both
/// critics, both targets) and alpha equal again, restarts all four Adam optimisers and empties
/// the species buffer, keeping the population buffer.
#[test]
fn a_new_design_copies_every_network_and_restarts_the_optimisers() {
    let sac = SacConfig { hidden: vec![16], batch_size: 8, auto_alpha: true, ..SacConfig::default() };
    let mut l = FearLearner::new(2, 1, FearLearnerConfig { sac, population_updates_from_design: 0, ..cfg() }, 3).unwrap();
    l.begin_design(0);
    for _ in 0..5 {
        episode(&mut l, 0.0);
        l.end_episode().unwrap();
    }
    let (ind, pop) = (l.agent(ActingPolicy::Individual), l.agent(ActingPolicy::Population));
    assert_ne!(ind.policy_params(), pop.policy_params(), "the pairs trained apart");
    assert_ne!(ind.critic_params(0), pop.critic_params(0));
    assert_ne!(ind.alpha(), pop.alpha(), "auto-alpha moved both alphas differently");
    assert!(ind.optimiser_steps().iter().all(|&s| s > 0), "{:?}", ind.optimiser_steps());
    assert_eq!(l.species_transitions(), 50);

    l.begin_design(1);
    let (ind, pop) = (l.agent(ActingPolicy::Individual), l.agent(ActingPolicy::Population));
    assert_eq!(ind.policy_params(), pop.policy_params());
    for i in 0..2 {
        let ((theta, bar), (pop_theta, pop_bar)) = (ind.critic_params(i), pop.critic_params(i));
        assert_eq!(theta, pop_theta, "critic {i}");
        assert_eq!(bar, pop_bar, "target critic {i}");
        assert_ne!(theta, bar, "target {i} lags its critic (a copy of both, not of one into the other)");
    }
    assert_eq!(ind.alpha(), pop.alpha());
    assert_eq!(ind.optimiser_steps(), [0; 4], "fresh Adam state");
    assert!(pop.optimiser_steps().iter().all(|&s| s > 0), "the population's optimisers keep their state");
    assert_eq!(l.species_transitions(), 0, "species buffer emptied");
    assert_eq!(l.population_transitions(), 50, "population buffer kept");
}

/// A reward so large that the critic's squared error overflows: the learner stops with an error
/// naming the pair, the update and the loss, and keeps its previous (finite) weights out of
/// the non-finite update's reach as far as publishing goes.
#[test]
fn a_non_finite_loss_stops_training_with_the_update_named() {
    let mut l = FearLearner::new(2, 1, FearLearnerConfig { warmup_episodes: 0, ..cfg() }, 4).unwrap();
    l.begin_design(0);
    l.add_start_state(&[0.1, 0.0]).unwrap();
    for k in 0..10 {
        let (o, n) = ([k as f32 * 0.1, 0.0], [(k + 1) as f32 * 0.1, 0.0]);
        l.add_transition(&Transition { obs: &o, action: &[0.5], reward: 3e38, next_obs: &n, terminated: false }).unwrap();
    }
    let e = l.end_episode().unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(e, coadapt_learner::fear::TrainError::NonFinite { pair: "individual", update: 1, design: 0, episode: 0, .. }),
        "{msg}"
    );
    assert!(msg.contains("critic 1 loss (inf)"), "{msg}");
}

#[test]
fn with_roll_back_a_non_finite_update_restores_the_networks_and_training_goes_on() {
    use coadapt_learner::fear::{ActingPolicy, OnNonFinite};
    let c = FearLearnerConfig { warmup_episodes: 0, on_non_finite: OnNonFinite::RollBack, max_rollbacks_in_a_row: 2, ..cfg() };
    let mut l = FearLearner::new(2, 1, c, 4).unwrap();
    l.begin_design(0);
    l.add_start_state(&[0.1, 0.0]).unwrap();
    let before = |l: &FearLearner| {
        let a = l.agent(ActingPolicy::Individual);
        (a.policy_params().to_vec(), a.critic_params(0).0.to_vec(), a.optimiser_steps(), a.updates())
    };
    let push = |l: &mut FearLearner, reward: f32| {
        for k in 0..10 {
            let (o, n) = ([k as f32 * 0.1, 0.0], [(k + 1) as f32 * 0.1, 0.0]);
            l.add_transition(&Transition { obs: &o, action: &[0.5], reward, next_obs: &n, terminated: false }).unwrap();
        }
    };
    push(&mut l, 3e38);
    let saved = before(&l);
    let t = l.end_episode().unwrap();
    let why = t.rolled_back.expect("rolled back");
    assert!(why.contains("critic 1 loss (inf)"), "{why}");
    assert_eq!(before(&l), saved, "networks, Adam steps and update count are as before the episode");
    // Twice more in a row is one more than allowed: the run stops with the update named.
    assert!(l.end_episode().unwrap().rolled_back.is_some());
    assert!(matches!(l.end_episode(), Err(coadapt_learner::fear::TrainError::NonFinite { .. })));
}

/// Transfer (thesis 6.1): `init_population` copies exactly the source's population networks
/// (policy, both critics, both targets) and nothing else: this learner's individual pair, Adam
/// moments, update count, alpha and buffers are as a fresh learner's; the first design then
/// copies them into the individual pair. With `load_population_replay`, the source's
/// population buffer comes too.
#[test]
fn init_population_copies_the_population_networks_and_nothing_else() {
    use coadapt_learner::snapshot;
    // A source that has trained, so its networks, targets and Adam moments are its own.
    let mut src = FearLearner::new(2, 1, FearLearnerConfig { population_updates_from_design: 0, warmup_episodes: 0, ..cfg() }, 11).unwrap();
    src.begin_design(0);
    for _ in 0..3 {
        episode(&mut src, 0.5);
        src.end_episode().unwrap();
    }
    let dir = coadapt_test_support::scratch("learner", "init-population");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("population.safetensors");
    let sp = src.agent(ActingPolicy::Population);
    assert!(sp.updates() > 0, "the source trained its population pair");
    sp.save(&path).unwrap();

    let fresh = FearLearner::new(2, 1, cfg(), 1).unwrap();
    let mut l = FearLearner::new(2, 1, cfg(), 1).unwrap();
    l.init_population(&path).unwrap();
    let (p, s, f) = (l.agent(ActingPolicy::Population), src.agent(ActingPolicy::Population), fresh.agent(ActingPolicy::Population));
    assert_eq!(p.policy_params(), s.policy_params());
    for i in 0..2 {
        assert_eq!(p.critic_params(i), s.critic_params(i), "critic {i} and its target");
    }
    assert_ne!(p.policy_params(), f.policy_params(), "the copy is not the fresh start");
    assert_eq!(p.updates(), 0, "the update count is this learner's");
    assert_eq!(p.optimiser_steps(), [0; 4], "Adam starts fresh");
    assert_eq!(p.alpha(), f.alpha(), "alpha is this learner's");
    let ind = l.agent(ActingPolicy::Individual);
    assert_eq!(ind.policy_params(), fresh.agent(ActingPolicy::Individual).policy_params(), "the individual pair waits for a design");
    assert_eq!((l.population_transitions(), l.start_states()), (0, 0), "no experience came with the networks");
    l.begin_design(0);
    assert_eq!(l.agent(ActingPolicy::Individual).policy_params(), s.policy_params(), "the first design starts from the copy");

    // The replay, when asked: from a snapshot of the source.
    let snap = snapshot::write(&dir.join("snapshots"), 1, "src", "test", 2, |out| src.save_state(out)).unwrap();
    let (_, mut inp) = snapshot::load(&snap).unwrap();
    let n = l.load_population_replay(&mut inp).unwrap();
    assert_eq!(n, src.population_transitions());
    assert_eq!(l.population_transitions(), 30);
    // A source of another shape is refused, naming the network.
    let other = FearLearner::new(3, 1, cfg(), 1).unwrap();
    let path3 = dir.join("other.safetensors");
    other.agent(ActingPolicy::Population).save(&path3).unwrap();
    let e = l.init_population(&path3).unwrap_err().to_string();
    assert!(e.contains("policy") && e.contains("shape"), "{e}");
}
