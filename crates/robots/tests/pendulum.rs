#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, EnvError};
use coadapt_robots::make;

#[test]
fn pendulum_matches_gymnasium_dynamics_and_truncates_at_200() {
    let mut env = make("pendulum").unwrap();
    let obs = env.reset(0, &[1.0, 1.0]).unwrap().to_vec();
    assert_eq!(obs.len(), 5);
    let th = obs[1].atan2(obs[0]);
    let thdot = obs[2];
    let s = env.step(&[0.5]).unwrap();
    // Pendulum-v1 by hand: u = 1.0 N m.
    let expect_thdot = thdot + (15.0 * th.sin() + 3.0 * 1.0) * 0.05;
    let expect_th = th + expect_thdot * 0.05;
    assert!((s.observation[2] - expect_thdot).abs() < 1e-5);
    assert!((s.observation[0] - expect_th.cos()).abs() < 1e-5);
    let norm = (th + std::f32::consts::PI).rem_euclid(2.0 * std::f32::consts::PI) - std::f32::consts::PI;
    assert!((s.reward + (norm * norm + 0.1 * thdot * thdot + 0.001)).abs() < 1e-5);
    let mut n = 1;
    loop {
        let s = env.step(&[0.0]).unwrap();
        n += 1;
        assert!(!s.terminated);
        if s.truncated {
            break;
        }
    }
    assert_eq!(n, 200);
    assert_eq!(env.step(&[0.0]).unwrap_err(), EnvError::NotRunning);
}

#[test]
fn same_seed_same_episode_and_bad_input_is_rejected() {
    let mut a = make("pendulum").unwrap();
    let mut b = make("pendulum").unwrap();
    assert_eq!(a.reset(9, &[1.5, 0.7]).unwrap(), b.reset(9, &[1.5, 0.7]).unwrap());
    for k in 0..50 {
        let act = [((k as f32) * 0.3).sin()];
        let (sa, sb) = (a.step(&act).unwrap().observation.to_vec(), b.step(&act).unwrap().observation.to_vec());
        assert_eq!(sa, sb);
    }
    assert!(matches!(a.reset(1, &[3.0, 1.0]), Err(EnvError::Design(_))));
    assert!(matches!(a.reset(1, &[1.0]), Err(EnvError::Design(_))));
    a.reset(1, &[1.0, 1.0]).unwrap();
    assert!(matches!(a.step(&[f32::NAN]), Err(EnvError::Action(_))));
    assert!(matches!(a.step(&[0.0, 1.0]), Err(EnvError::Action(_))));
    assert!(make("nope").is_err());
}
