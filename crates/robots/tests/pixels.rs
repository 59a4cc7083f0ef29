//! Every drawable robot through the camera (thesis ch. 4's pixel observations): the Env
//! conformance suite, the frame stack, action repeat, and a picture that moves with the body.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::conformance::check_env;
use coadapt_core::{Env, Pixels, PixelsConfig};

#[test]
fn every_robot_through_the_camera_passes_the_env_conformance_suite() {
    for name in coadapt_robots::ENV_NAMES {
        let mut env = Pixels::new(coadapt_robots::make(name).unwrap(), PixelsConfig::default()).unwrap();
        assert_eq!(env.spec().state_dim, 3 * 3 * 64 * 64, "{name}");
        assert_eq!(env.spec().name, format!("{name}-pixels"));
        check_env(&mut env, 20);
    }
}

#[test]
fn frames_stack_oldest_first_and_actions_repeat() {
    let cfg = PixelsConfig::default();
    let fl = 3 * 64 * 64;
    let mut plain = coadapt_robots::make("half-cheetah").unwrap();
    let mut env = Pixels::new(coadapt_robots::make("half-cheetah").unwrap(), cfg).unwrap();
    let design = env.spec().default_design.clone();
    let d = design.len();
    let first = env.reset(4, &design).unwrap().to_vec();
    plain.reset(4, &design).unwrap();
    assert_eq!(first.len(), 3 * fl + d);
    assert_eq!(first[..fl], first[fl..2 * fl], "every frame of the first stack is the first picture");
    assert_eq!(first[fl..2 * fl], first[2 * fl..3 * fl]);
    assert_eq!(first[3 * fl..], design[..], "the design follows the frames");
    assert!(first[..3 * fl].iter().all(|v| (0.0..=1.0).contains(v)));
    let action: Vec<f32> = (0..env.spec().act_dim()).map(|i| if i % 2 == 0 { 0.9 } else { -0.7 }).collect();
    let mut prev = first;
    let mut moved = false;
    for _ in 0..10 {
        let s = env.step(&action).unwrap();
        let (obs, reward) = (s.observation.to_vec(), s.reward);
        // Action repeat 2: the reward of two robot steps with the same action.
        let want = plain.step(&action).unwrap().reward;
        let s2 = plain.step(&action).unwrap();
        let want = want + s2.reward;
        assert!((reward - want).abs() < 1e-5, "{reward} vs {want}");
        // The robot's own observation behind the frame (what a state-based learner sees).
        assert_eq!(env.state(), s2.observation, "Pixels::state is the robot's observation");
        // The stack shifts by one frame.
        assert_eq!(obs[..2 * fl], prev[fl..3 * fl], "frames shift oldest first");
        moved |= obs[2 * fl..3 * fl] != prev[2 * fl..3 * fl];
        prev = obs;
    }
    assert!(moved, "the newest frame never changed while the robot moved");
    // 1000 robot steps are 500 pixel steps.
    assert_eq!(env.spec().max_episode_steps, 500);
}

/// A robot with no body to draw (a remote one) cannot be seen.
struct Blind(coadapt_core::EnvSpec);

impl Env for Blind {
    fn spec(&self) -> &coadapt_core::EnvSpec {
        &self.0
    }
    fn reset(&mut self, _: u64, _: &[f32]) -> Result<&[f32], coadapt_core::EnvError> {
        Ok(&[])
    }
    fn step(&mut self, _: &[f32]) -> Result<coadapt_core::Step<'_>, coadapt_core::EnvError> {
        Err(coadapt_core::EnvError::NotRunning)
    }
}

#[test]
fn a_robot_that_cannot_be_drawn_is_refused() {
    let spec = coadapt_robots::make("pendulum").unwrap().spec().clone();
    let e = Pixels::new(Blind(spec), PixelsConfig::default()).unwrap_err();
    assert!(e.to_string().contains("cannot be drawn"), "{e}");
}
