//! SAC and DDPG learn Pendulum: the bar of DESIGN.md section 5 (mean return of the last 10
//! episodes above -200 within 20,000 steps), checked for one seed each. The five-seed study is
//! `scripts/pendulum_seeds.sh`, recorded in docs/EXPERIMENTS.md.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::atomic::AtomicBool;

use coadapt_learner::train::{self, TrainConfig};
use coadapt_learner::{Algo, DdpgConfig, Exploration};

/// DDPG explores with Gaussian noise of 0.1 here: the thesis's OU process (sigma 0.5, theta
/// 0.15) has a stationary standard deviation of about 0.95 on actions in [-1, 1], which makes
/// Pendulum's training episodes nearly random whatever the policy (measured: -720 after 15k
/// steps, while the same agent with Gaussian 0.1 passes -200 at about 6k).
fn learns(algo: Algo, seed: u64) {
    let dir = std::env::temp_dir().join(format!("coadapt-learning-{algo}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = TrainConfig {
        algo,
        seed,
        steps: BUDGET,
        target_return: Some(-200.0),
        stop_at_target: false,
        ddpg: DdpgConfig { exploration: Exploration::Gaussian, sigma: 0.1, ..DdpgConfig::default() },
        ..TrainConfig::default()
    };
    let mut env = coadapt_robots::make("pendulum").unwrap();
    let s = train::run(&cfg, env.as_mut(), &dir, &AtomicBool::new(false), &mut |_| {}).unwrap();
    eprintln!("{algo} seed {seed}: {s:?}");
    let step = s.first_step_reaching_target.unwrap_or_else(|| panic!("{algo} did not reach -200 in {BUDGET} steps: {s:?}"));
    assert!(step < BUDGET, "{algo}: first reached -200 at step {step}");
    // Still learned at the end, not a lucky stretch of episodes: the last 10 episodes (run
    // past the first success rather than stopping at it) are above -200 too.
    assert!(s.mean_return_last_10 > -200.0, "{algo}: mean of the last 10 episodes at {BUDGET}: {}", s.mean_return_last_10);
}

/// Steps of each test run: the bar is 20,000; the five-seed studies (docs/EXPERIMENTS.md
/// section 1) first pass -200 at 4,800-7,200 steps, so 12,000 leaves room for a slower seed
/// and still fails a learner that needs the whole bar.
const BUDGET: u64 = 12_000;

#[test]
fn sac_learns_pendulum() {
    learns(Algo::Sac, 1);
}

#[test]
fn ddpg_learns_pendulum() {
    learns(Algo::Ddpg, 1);
}
