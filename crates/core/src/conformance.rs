//! The conformance suite every [`Env`] implementation runs (built-in robots, remote robots over
//! dm_env_rpc): one set of promises, checked the same way for each.
//!
//! Call [`check_env`] from a test with a fresh environment; it panics with a message naming the
//! broken promise (it is test support, not a runtime check).

use rand::Rng;

use crate::{Env, EnvError, rng};

/// What one episode produced (for comparing two implementations of the same robot).
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    pub observations: Vec<Vec<f32>>,
    pub rewards: Vec<f32>,
    pub terminated: bool,
    pub truncated: bool,
}

/// Runs up to `max_steps` steps of an episode from `seed` with body `design` and actions drawn
/// from `action_seed` (uniform in the action box); records every observation and reward.
pub fn trace(env: &mut dyn Env, seed: u64, design: &[f32], action_seed: u64, max_steps: usize) -> Result<Trace, EnvError> {
    let spec = env.spec().clone();
    let mut r = rng(action_seed, 0x434f_4e46);
    let mut t = Trace { observations: vec![env.reset(seed, design)?.to_vec()], rewards: vec![], terminated: false, truncated: false };
    let mut a = vec![0.0; spec.act_dim()];
    for _ in 0..max_steps {
        for (x, (lo, hi)) in a.iter_mut().zip(spec.action.low.iter().zip(&spec.action.high)) {
            *x = r.random_range(*lo..=*hi);
        }
        let s = env.step(&a)?;
        t.observations.push(s.observation.to_vec());
        t.rewards.push(s.reward);
        if s.terminated || s.truncated {
            t.terminated = s.terminated;
            t.truncated = s.truncated;
            break;
        }
    }
    Ok(t)
}

/// The promises of the [`Env`] trait, checked on `env` over `steps` steps per episode:
/// observations of `obs_dim` values ending with the design, finite rewards; the same seed,
/// design and actions give the same episode; a design outside the box and a non-finite action
/// are refused with errors naming them; stepping after the end is refused.
pub fn check_env(env: &mut dyn Env, steps: usize) {
    let spec = env.spec().clone();
    assert_eq!(spec.obs_dim(), spec.state_dim + spec.design_dim(), "obs_dim is state then design");
    spec.design.check("default design", &spec.default_design).expect("the default design is inside the design box");
    assert!(spec.action.low.iter().zip(&spec.action.high).all(|(l, h)| l < h), "a non-empty action box");
    let mut design = spec.default_design.clone();
    if let Some(d) = design.first_mut() {
        // Another body than the default, inside the box.
        *d = 0.5 * (spec.design.low[0] + spec.design.high[0]);
    }
    let a = trace(env, 7, &design, 11, steps).expect("an episode runs");
    for (i, o) in a.observations.iter().enumerate() {
        assert_eq!(o.len(), spec.obs_dim(), "observation {i} has obs_dim values");
        assert_eq!(&o[spec.state_dim..], &design[..], "observation {i} ends with the design");
        assert!(o.iter().all(|v| v.is_finite()), "observation {i} is finite");
    }
    assert!(a.rewards.iter().all(|r| r.is_finite()), "rewards are finite");
    let b = trace(env, 7, &design, 11, steps).expect("a second episode runs");
    assert_eq!(a, b, "the same seed, design and actions give the same episode");
    if spec.design_dim() > 0 {
        let mut outside = design.clone();
        outside[0] = spec.design.high[0] + 1.0;
        assert!(matches!(env.reset(1, &outside), Err(EnvError::Design(_))), "a design outside the box is refused");
        let mut nan = design.clone();
        nan[0] = f32::NAN;
        assert!(matches!(env.reset(1, &nan), Err(EnvError::Design(_))), "a non-finite design is refused");
    }
    env.reset(1, &design).expect("reset after refused designs");
    let mut action = vec![0.0; spec.act_dim()];
    action[0] = f32::NAN;
    assert!(matches!(env.step(&action), Err(EnvError::Action(_))), "a non-finite action is refused");
    // Run an episode to its end (bounded by the declared length, or 5,000 steps).
    env.reset(2, &design).expect("reset");
    let zero = vec![0.0; spec.act_dim()];
    let limit = spec.max_episode_steps.min(5_000);
    let mut ended = false;
    for _ in 0..limit {
        let s = env.step(&zero).expect("a zero action steps");
        if s.terminated || s.truncated {
            ended = true;
            break;
        }
    }
    if ended {
        assert!(matches!(env.step(&zero), Err(EnvError::NotRunning)), "a step after the end is refused");
    }
}
