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

/// Env steps per second of environment `name` (from [`make`]) on its default design, with
/// uniform random actions, for about `seconds` of wall time on the calling thread.
pub fn env_steps_per_second(name: &str, seconds: f64) -> Result<f64, BenchError> {
    let mut env = make(name)?;
    Ok(steps_per_second(&mut env, seconds, 0)?)
}

/// Env steps per second of `env` on its default design with uniform random actions (seeded by
/// `seed`), for about `seconds` of wall time. Episodes restart when they end, and the resets count
/// in the time, as they do when an actor collects experience.
pub fn steps_per_second(env: &mut dyn Env, seconds: f64, seed: u64) -> Result<f64, EnvError> {
    let design = env.spec().default_design.clone();
    let max_steps = env.spec().max_episode_steps;
    let mut action = vec![0.0; env.spec().act_dim()];
    let mut r = rng(seed, 1);
    let mut episode = seed;
    let start = Instant::now();
    env.reset(episode, &design)?;
    let (mut steps, mut t) = (0u64, 0usize);
    loop {
        env.spec().action.sample(&mut r, &mut action);
        let s = env.step(&action)?;
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
