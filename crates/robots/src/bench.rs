//! Simulation throughput: environment steps per second under random actions, the figure the
//! simulation bar compares with MuJoCo's (`coadapt bench sim` and the `cheetah_speed` example).

use crate::{UnknownEnv, make};
use coadapt_core::{Env, EnvError, rng};
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    UnknownEnv(#[from] UnknownEnv),
    #[error(transparent)]
    Env(#[from] EnvError),
}

/// Actions drawn before the timer starts and cycled through: drawing inside the timed loop would
/// time the random number generator too (gymnasium's `action_space.sample()` costs about 40 us,
/// more than a MuJoCo step), so both sides of the comparison with MuJoCo draw theirs up front.
pub const PREDRAWN_ACTIONS: usize = 4096;

/// Simulated seconds per control step of environment `name` (what one env step advances).
pub fn control_dt(name: &str) -> Option<f64> {
    match name {
        "half-cheetah" | "walker" | "hopper" => Some(f64::from(crate::planar::CONTROL_DT)),
        "daisy" => Some(f64::from(crate::daisy::SimConfig::default().control_dt)),
        "pendulum" => Some(0.05),
        _ => None,
    }
}

/// Env steps per second of environment `name` (from [`make`]) on its default design, with
/// uniform random actions drawn before the timer, for about `seconds` of wall time on the
/// calling thread.
pub fn env_steps_per_second(name: &str, seconds: f64) -> Result<f64, BenchError> {
    let mut env = make(name)?;
    Ok(steps_per_second(&mut env, seconds, 0)?)
}

/// Env steps per second of `env` on its default design with uniform random actions (seeded by
/// `seed`, [`PREDRAWN_ACTIONS`] of them drawn before the timer and cycled), for about `seconds`
/// of wall time. Episodes restart when they end, and the resets count in the time, as they do
/// when an actor collects experience.
pub fn steps_per_second(env: &mut dyn Env, seconds: f64, seed: u64) -> Result<f64, EnvError> {
    let design = env.spec().default_design.clone();
    let max_steps = env.spec().max_episode_steps;
    let act_dim = env.spec().act_dim();
    let mut actions = vec![0.0; PREDRAWN_ACTIONS * act_dim];
    let mut r = rng(seed, 1);
    for a in actions.chunks_exact_mut(act_dim.max(1)) {
        env.spec().action.sample(&mut r, a);
    }
    let mut episode = seed;
    let start = Instant::now();
    env.reset(episode, &design)?;
    let (mut steps, mut t) = (0u64, 0usize);
    loop {
        let k = (steps as usize % PREDRAWN_ACTIONS) * act_dim;
        let s = env.step(&actions[k..k + act_dim])?;
        let done = s.terminated || s.truncated;
        steps += 1;
        t += 1;
        if done || t >= max_steps {
            episode += 1;
            t = 0;
            env.reset(episode, &design)?;
        }
        // Reading the clock every step would cost more than a Pendulum step.
        if steps % 64 == 0 && start.elapsed().as_secs_f64() >= seconds {
            return Ok(steps as f64 / start.elapsed().as_secs_f64());
        }
    }
}
