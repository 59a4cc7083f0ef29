//! `[world]` on every robot: the default world is the robot as it was, bit for bit; each value
//! a legged robot takes changes what the robot does, in the direction physics says; robots
//! without ground, motors or torso refuse any but the defaults, naming the key.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::Env;
use coadapt_robots::{ENV_NAMES, MakeError, World, make, make_in};

const LEGGED: [&str; 4] = ["half-cheetah", "walker", "hopper", "daisy"];

/// The observations of `steps` steps of a fixed open-loop gait from seed 7's start.
fn roll(env: &mut dyn Env, steps: usize) -> Vec<Vec<f32>> {
    let design = env.spec().default_design.clone();
    let n = env.spec().act_dim();
    let mut out = vec![env.reset(7, &design).unwrap().to_vec()];
    for t in 0..steps {
        let a: Vec<f32> = (0..n).map(|j| ((t as f32) * 0.3 + j as f32).sin()).collect();
        out.push(env.step(&a).unwrap().observation.to_vec());
    }
    out
}

/// How far the torso moved forward over the roll: the sum of the per-step rewards is not
/// comparable across robots, so use the observations' distance from the default world's.
fn distance(a: &[Vec<f32>], b: &[Vec<f32>]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x.iter().zip(y).map(|(p, q)| (p - q).abs()).sum::<f32>()).sum()
}

#[test]
fn the_default_world_is_every_robot_as_it_was() {
    for &name in ENV_NAMES {
        let mut old = make(name).unwrap();
        let mut new = make_in(name, &World::default()).unwrap();
        let steps = if name == "reach" { 5 } else { 60 };
        assert_eq!(roll(old.as_mut(), steps), roll(new.as_mut(), steps), "{name}");
    }
}

#[test]
fn friction_actuators_and_payload_change_a_legged_robot() {
    for name in LEGGED {
        let base = roll(make(name).unwrap().as_mut(), 80);
        for (what, world) in [
            ("friction 0.05", World { friction: Some(0.05), ..World::default() }),
            ("friction 2", World { friction: Some(2.0), ..World::default() }),
            ("actuators x0.5", World { actuator_scale: 0.5, ..World::default() }),
            ("torso x2", World { torso_mass_scale: 2.0, ..World::default() }),
        ] {
            let other = roll(make_in(name, &world).unwrap().as_mut(), 80);
            let d = distance(&base, &other);
            assert!(d > 1.0, "{name} in {what}: the observations moved only {d} from the robot's own world");
            assert!(other.iter().flatten().all(|v| v.is_finite()), "{name} in {what}: not finite");
        }
        // The robot's own friction set explicitly is the default world.
        let own = [0.4, 0.9, 1.0, 0.8][LEGGED.iter().position(|&n| n == name).unwrap()];
        let same = roll(make_in(name, &World { friction: Some(own), ..World::default() }).unwrap().as_mut(), 80);
        assert_eq!(base, same, "{name}: friction {own} is its own");
    }
}

#[test]
fn weaker_actuators_move_the_cheetah_less() {
    // Zero torque and full-strength torque bracket any scale: the joints swing less with half
    // the torque (same actions, same start).
    let swing = |scale: f32| {
        let mut env = make_in("half-cheetah", &World { actuator_scale: scale, ..World::default() }).unwrap();
        let obs = roll(env.as_mut(), 60);
        // The first 6 entries are the joint angles (scaled to their ranges).
        obs.windows(2).map(|w| (0..6).map(|j| (w[1][j] - w[0][j]).abs()).sum::<f32>()).sum::<f32>()
    };
    let (weak, full) = (swing(0.25), swing(1.0));
    assert!(weak < 0.8 * full, "a quarter of the torque swung the joints {weak}, full torque {full}");
}

#[test]
fn robots_without_ground_refuse_a_world_and_bad_values_are_named() {
    for name in ["pendulum", "reach"] {
        let e = make_in(name, &World { friction: Some(1.0), ..World::default() }).err().unwrap();
        assert!(matches!(e, MakeError::World(_)), "{name}: {e}");
        assert!(e.to_string().starts_with("world.friction: "), "{e}");
        let e = make_in(name, &World { actuator_scale: 2.0, ..World::default() }).err().unwrap();
        assert!(e.to_string().starts_with("world.actuator-scale: "), "{e}");
    }
    for name in LEGGED {
        let e = make_in(name, &World { friction: Some(f32::NAN), ..World::default() }).err().unwrap();
        assert!(e.to_string().starts_with("world.friction: NaN is not"), "{name}: {e}");
        let e = make_in(name, &World { torso_mass_scale: -1.0, ..World::default() }).err().unwrap();
        assert!(e.to_string().starts_with("world.torso-mass-scale: -1 is not"), "{name}: {e}");
    }
    assert!(matches!(make_in("cartpole", &World::default()), Err(MakeError::Unknown(_))));
}
