//! `coadapt train`'s update schedules: `per-episode` takes exactly the gradient steps that
//! `per-step` takes, but all at the episode's end, so the policy does not change within an
//! episode (FEAR's schedule on one body, EXPERIMENTS 5.5).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use coadapt_learner::SacConfig;
use coadapt_learner::train::{self, TrainConfig, TrainSummary, UpdateSchedule};

fn run(name: &str, schedule: UpdateSchedule, updates_per_step: u32) -> (TrainSummary, Vec<f32>) {
    let dir: PathBuf = std::env::temp_dir().join(format!("coadapt-update-schedule-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = TrainConfig {
        seed: 3,
        // Two whole Pendulum episodes (200 steps each) and a third cut at 50 steps.
        steps: 450,
        learning_starts: 100,
        updates_per_step,
        update_schedule: schedule,
        checkpoint_every: 0,
        sac: SacConfig { hidden: vec![32, 32], batch_size: 32, ..SacConfig::default() },
        ..TrainConfig::default()
    };
    let mut env = coadapt_robots::make("pendulum").unwrap();
    let mut returns = Vec::new();
    let s = train::run(&cfg, env.as_mut(), &dir, &AtomicBool::new(false), &mut |r| returns.push(r.episode_return)).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    (s, returns)
}

#[test]
fn per_episode_takes_the_same_updates_after_the_episode() {
    let (step1, step_returns) = run("step1", UpdateSchedule::PerStep, 1);
    let (step3, step3_returns) = run("step3", UpdateSchedule::PerStep, 3);
    let (ep1, ep_returns) = run("episode1", UpdateSchedule::PerEpisode, 1);
    let (ep3, ep3_returns) = run("episode3", UpdateSchedule::PerEpisode, 3);
    assert_eq!(step_returns.len(), 3);
    assert_eq!(ep_returns.len(), 3);
    // Steps 100..450 each owe one update (three with updates-per-step = 3), the cut third
    // episode's included: the schedules differ in when, not how many.
    assert_eq!(step1.updates, 351);
    assert_eq!(ep1.updates, step1.updates);
    assert_eq!(ep3.updates, 3 * 351);
    assert_eq!(step3.updates, ep3.updates);
    // Per step, the policy changes from step 100 of the first episode on, so more updates per
    // step change that episode's return. Per episode, the first episode is played by the
    // untrained policy whatever is owed at its end; the second one differs.
    assert_ne!(step_returns[0], step3_returns[0], "per-step updates change the first episode");
    assert_eq!(ep_returns[0], ep3_returns[0], "per-episode updates waited for the end of the first episode");
    assert_ne!(ep_returns[1], ep3_returns[1], "the first episode's burst trained the policy of the second");
    assert_ne!(ep_returns[1], step_returns[1], "the two schedules are different runs");
}

/// A run stopped by the shutdown flag before its steps says so (`interrupted`), so that a
/// campaign does not take it for a finished one; a run that reaches its steps does not.
#[test]
fn a_run_stopped_before_its_steps_says_it_was_interrupted() {
    let (done, _) = run("whole", UpdateSchedule::PerStep, 1);
    assert!(!done.interrupted, "a whole run: {done:?}");
    let dir: PathBuf = std::env::temp_dir().join(format!("coadapt-update-schedule-stopped-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = TrainConfig { seed: 3, steps: 450, checkpoint_every: 0, ..TrainConfig::default() };
    let mut env = coadapt_robots::make("pendulum").unwrap();
    let stop = AtomicBool::new(false);
    let mut episodes = 0;
    let s = train::run(&cfg, env.as_mut(), &dir, &stop, &mut |_| {
        episodes += 1;
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!((episodes, s.steps), (1, 200), "stopped after its first episode");
    assert!(s.interrupted, "{s:?}");
}
