//! The sparse-reward reaching stand-in: the scripted demonstrator succeeds from every start,
//! doing nothing earns nothing, flailing out of the workspace is punished, and the camera sees
//! the target.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_robots::reach::{SUCCESS_RADIUS, TARGET_Q, demonstration_action, target};

fn episode(env: &mut dyn Env, seed: u64, policy: &mut dyn FnMut(&[f32], &mut [f32])) -> (Vec<f32>, bool, bool) {
    let design = env.spec().default_design.clone();
    let mut obs = env.reset(seed, &design).unwrap().to_vec();
    let mut a = vec![0.0; 3];
    let mut rewards = Vec::new();
    loop {
        policy(&obs, &mut a);
        let s = env.step(&a).unwrap();
        rewards.push(s.reward);
        obs = s.observation.to_vec();
        if s.terminated || s.truncated {
            return (rewards, s.terminated, s.truncated);
        }
    }
}

#[test]
fn the_demonstrator_succeeds_from_every_start_and_the_reward_is_sparse() {
    let mut env = coadapt_robots::make("reach").unwrap();
    for seed in 0..50 {
        let (r, terminated, _) = episode(&mut *env, seed, &mut demonstration_action);
        assert!(terminated && *r.last().unwrap() == 1.0, "seed {seed}: {r:?}");
        assert!(r[..r.len() - 1].iter().all(|&v| v == 0.0), "seed {seed}: reward before success: {r:?}");
        assert!(r.len() <= 20 && r.len() >= 5, "seed {seed}: {} steps", r.len());
    }
    // Standing still: 20 steps of nothing, cut by the time limit.
    let (r, terminated, truncated) = episode(&mut *env, 3, &mut |_, a| a.fill(0.0));
    assert_eq!((r.len(), terminated, truncated), (20, false, true));
    assert!(r.iter().all(|&v| v == 0.0));
    // Swinging the first joint down as fast as allowed leaves the workspace: -1, the end.
    let (r, terminated, _) = episode(&mut *env, 3, &mut |_, a| a.copy_from_slice(&[-1.0, -1.0, -1.0]));
    assert!(terminated && *r.last().unwrap() == -1.0, "{r:?}");
    // The target is where TARGET_Q puts the default arm's hand; the observation says how far.
    let t = target();
    let o = env.reset(0, &[1.0, 1.0, 1.0]).unwrap().to_vec();
    assert!(o[3].hypot(o[4]) > 4.0 * SUCCESS_RADIUS, "the start is not already a success: {o:?}");
    assert!((o[0] - TARGET_Q[0]).abs() > 0.2 && t[1] > 0.0);
}

#[test]
fn the_camera_sees_the_arm_move_towards_the_target() {
    let px = PixelsConfig { width: 32, height: 32, frames: 1, action_repeat: 1 };
    let mut env = Pixels::new(coadapt_robots::make("reach").unwrap(), px).unwrap();
    let first = env.reset(1, &[1.0, 1.0, 1.0]).unwrap()[..3 * 32 * 32].to_vec();
    let lit = first.iter().filter(|v| **v < 0.99).count();
    assert!(lit > 20, "the arm and the target cover some pixels: {lit}");
    let mut a = vec![0.0; 3];
    demonstration_action(env.state(), &mut a);
    let mut last = first.clone();
    for _ in 0..5 {
        let s = env.step(&a).unwrap();
        last = s.observation[..3 * 32 * 32].to_vec();
        demonstration_action(env.state(), &mut a);
    }
    assert_ne!(first, last, "the picture changes as the arm moves");
}
