//! Walker and Hopper in rapier: landing on their feet and collapsing limp, start height, joint
//! limits under abuse, stability at the design bounds, determinism, the observation layout and
//! reward, and input validation. The ignored tests print the measurements in the modules' docs.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, EnvError, rng};
use coadapt_robots::bench::{env_steps_per_second, steps_per_second};
use coadapt_robots::hopper::{Hopper, HopperModel};
use coadapt_robots::make;
use coadapt_robots::planar::{PlanarEnv, Robot, STANDING_HEIGHT, SimConfig};
use coadapt_robots::walker::{Walker, WalkerModel};
use rand::Rng;

/// Worst joint-limit violation (radians) allowed under sustained full torque. The multibody limit
/// constraints only engage once a joint is past its limit, so a fast joint overshoots by about its
/// speed times a solver substep; the default settings measured 0.070 rad (Walker) and 0.067 rad
/// (Hopper) at worst over the designs below (module docs). HalfCheetah's tests allow the same.
const LIMIT_TOLERANCE: f32 = 0.1;

/// Designs at the bounds: every value low, the original, every value high, and a mixed corner.
fn corners<R: Robot>() -> [Vec<f32>; 4] {
    let mixed = (0..R::DESIGN_LOW.len()).map(|i| if i % 2 == 0 { R::DESIGN_HIGH[i] } else { R::DESIGN_LOW[i] }).collect();
    [R::DESIGN_LOW.to_vec(), R::DEFAULT_DESIGN.to_vec(), R::DESIGN_HIGH.to_vec(), mixed]
}

fn no_settling<R: Robot>() -> PlanarEnv<R> {
    PlanarEnv::with_config(SimConfig { settle_steps: 0, ..R::default_config() })
}

fn falls_and_rests<R: Robot>() {
    let n = R::JOINT_LIMITS.len();
    let mut env = no_settling::<R>();
    env.reset(3, R::DEFAULT_DESIGN).unwrap();
    let start = env.torso_height().unwrap();
    let low = env.lowest_point().unwrap();
    assert!((low - 0.01).abs() < 1e-4, "{}: starts with its lowest point at {low} m, not 1 cm", R::NAME);
    // Limp, the body folds up on the ground.
    let mut last = Vec::new();
    for _ in 0..300 {
        last = env.step(&vec![0.0; n]).unwrap().observation.to_vec();
    }
    let rest = env.torso_height().unwrap();
    assert!(rest < start - 0.3, "{}: did not collapse: {start} -> {rest}", R::NAME);
    assert!(rest > 0.03, "{}: torso sank into the ground: {rest}", R::NAME);
    assert!(env.lowest_point().unwrap() > -0.01, "{}: a part rests in the ground", R::NAME);
    // Joint velocities (scaled by 0.1) and torso velocities (forward, vertical, pitch rate).
    for (i, v) in last[n..2 * n + 3].iter().enumerate() {
        assert!(v.abs() < 0.02, "{}: not at rest: observation[{}] = {v}", R::NAME, n + i);
    }
    // The default reset lands the body on its feet with the joints held, then frees them: the
    // first observation shows it upright, standing, with the joints where the seed put them.
    let mut env = PlanarEnv::<R>::new();
    let mut held = no_settling::<R>();
    for design in corners::<R>() {
        for seed in 0..5 {
            held.reset(seed, &design).unwrap();
            let drawn = held.joint_angles().unwrap();
            let obs = env.reset(seed, &design).unwrap().to_vec();
            for (i, (q, q0)) in env.joint_angles().unwrap().iter().zip(&drawn).enumerate() {
                assert!((q - q0).abs() < 0.02, "{} {design:?} seed {seed}: joint {i} moved {q0} -> {q} while held", R::NAME);
            }
            // Joint velocities x 0.1 (under 1 rad/s), torso velocities: the body has landed, and a
            // pose that does not balance has only begun to tip.
            for (i, v) in obs[n..2 * n].iter().enumerate() {
                assert!(v.abs() < 0.1, "{} {design:?} seed {seed}: joint velocity observation[{}] = {v}", R::NAME, n + i);
            }
            for (i, v) in obs[2 * n..2 * n + 3].iter().enumerate() {
                assert!(v.abs() < 1.0, "{} {design:?} seed {seed}: torso velocity observation[{}] = {v}", R::NAME, 2 * n + i);
            }
            assert!(obs[2 * n + 3].abs() < 0.05, "{} {design:?} seed {seed}: pitch {} at the start", R::NAME, obs[2 * n + 3]);
            let low = env.lowest_point().unwrap();
            assert!(low.abs() < 0.01, "{} {design:?} seed {seed}: lowest point {low} m after landing", R::NAME);
        }
    }
}

#[test]
fn the_bodies_land_on_their_feet_and_collapse_limp() {
    falls_and_rests::<WalkerModel>();
    falls_and_rests::<HopperModel>();
}

/// Torso heights at reset (before settling) for every seed in 0..20, for each design.
fn longer_legs_start_higher<R: Robot>(designs: &[Vec<f32>]) {
    let mut env = no_settling::<R>();
    for seed in 0..20 {
        let mut heights = Vec::new();
        for d in designs {
            env.reset(seed, d).unwrap();
            let low = env.lowest_point().unwrap();
            assert!((low - 0.01).abs() < 1e-4, "{} {d:?} seed {seed}: lowest point {low} m at the start", R::NAME);
            heights.push(env.torso_height().unwrap());
        }
        assert!(heights.windows(2).all(|w| w[1] > w[0] + 0.1), "{} seed {seed}: {heights:?}", R::NAME);
    }
}

#[test]
fn longer_legs_start_the_torso_higher() {
    longer_legs_start_higher::<WalkerModel>(&[vec![0.5; 6], vec![1.0; 6], vec![1.5; 6]]);
    // The nose stays at 1: only the leg segments.
    longer_legs_start_higher::<HopperModel>(&[vec![1.0, 0.5, 0.5, 0.5, 0.5], vec![1.0; 5], vec![1.0, 2.0, 2.0, 2.0, 2.0]]);
    // The original walker and hopper stand above the 0.8 m of the reward's standing term.
    let mut walker = Walker::new();
    walker.reset(0, &[1.0; 6]).unwrap();
    let mut hopper = Hopper::new();
    hopper.reset(0, &[1.0; 5]).unwrap();
    for h in [walker.torso_height().unwrap(), hopper.torso_height().unwrap()] {
        assert!(h > STANDING_HEIGHT, "{h}");
    }
}

/// Runs `steps` steps of random full-torque actions (each held for 1-20 steps, which pushes joints
/// into their limits far harder than a per-step coin flip), new episodes every 1000 steps;
/// returns the worst limit violation and the deepest any part went into the ground. Panics on an
/// error or a non-finite observation.
fn abuse<R: Robot>(cfg: SimConfig, design: &[f32], steps: usize, seed: u64) -> (f32, f32) {
    let n = R::JOINT_LIMITS.len();
    let mut env = PlanarEnv::<R>::with_config(cfg);
    let mut r = rng(seed, 9);
    let (mut action, mut hold, mut worst, mut deepest) = (vec![0.0f32; n], 0, 0.0f32, 0.0f32);
    for t in 0..steps {
        if t % 1000 == 0 {
            env.reset(seed + t as u64, design).unwrap();
        }
        if hold == 0 {
            action.iter_mut().for_each(|a| *a = if r.random::<bool>() { 1.0 } else { -1.0 });
            hold = r.random_range(1..=20);
        }
        hold -= 1;
        let s = env.step(&action).unwrap();
        assert!(s.observation.iter().all(|x| x.is_finite()), "{} step {t}: {:?}", R::NAME, s.observation);
        worst = worst.max(env.limit_violation());
        deepest = deepest.max(-env.lowest_point().unwrap());
    }
    (worst, deepest)
}

#[test]
fn joint_limits_hold_under_random_full_torque() {
    let (walker, _) = abuse::<WalkerModel>(WalkerModel::default_config(), &[1.0; 6], 10_000, 1);
    assert!(walker < LIMIT_TOLERANCE, "walker: worst violation {walker} rad");
    let (hopper, _) = abuse::<HopperModel>(HopperModel::default_config(), &[1.0; 5], 10_000, 1);
    assert!(hopper < LIMIT_TOLERANCE, "hopper: worst violation {hopper} rad");
}

fn stable_at_the_corners<R: Robot>() {
    let [low, _, high, mixed] = corners::<R>();
    // 10,000 steps over the two extreme corners.
    for d in [low, high] {
        let (worst, _) = abuse::<R>(R::default_config(), &d, 5_000, 2);
        assert!(worst < LIMIT_TOLERANCE, "{} {d:?}: worst violation {worst} rad", R::NAME);
    }
    // Uniform random actions on a mixed corner.
    let mut env = PlanarEnv::<R>::new();
    let mut r = rng(4, 0);
    let mut a = vec![0.0f32; R::JOINT_LIMITS.len()];
    env.reset(4, &mixed).unwrap();
    for _ in 0..1000 {
        env.spec().action.sample(&mut r, &mut a);
        assert!(env.step(&a).unwrap().observation.iter().all(|x| x.is_finite()));
    }
}

#[test]
fn walker_is_stable_and_holds_its_limits_at_the_design_bounds() {
    stable_at_the_corners::<WalkerModel>();
}

#[test]
fn hopper_is_stable_and_holds_its_limits_at_the_design_bounds() {
    stable_at_the_corners::<HopperModel>();
}

fn rollout<R: Robot>(seed: u64, design: &[f32], steps: usize) -> Vec<f32> {
    let mut env = PlanarEnv::<R>::new();
    let mut out = env.reset(seed, design).unwrap().to_vec();
    let mut r = rng(seed, 5);
    let mut a = vec![0.0f32; R::JOINT_LIMITS.len()];
    for _ in 0..steps {
        env.spec().action.sample(&mut r, &mut a);
        let s = env.step(&a).unwrap();
        out.extend_from_slice(s.observation);
        out.push(s.reward);
    }
    out
}

fn deterministic<R: Robot>(design: &[f32]) {
    let a = rollout::<R>(11, design, 300);
    let b = rollout::<R>(11, design, 300);
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()), "{}", R::NAME);
    let obs_dim = PlanarEnv::<R>::new().spec().obs_dim();
    assert_ne!(rollout::<R>(12, design, 0), a[..obs_dim].to_vec(), "{}: the seed must change the start", R::NAME);
    // Reusing one environment across resets gives the same episode too.
    let mut env = PlanarEnv::<R>::new();
    env.reset(99, R::DESIGN_LOW).unwrap();
    env.step(&vec![1.0; R::JOINT_LIMITS.len()]).unwrap();
    let first = env.reset(11, design).unwrap().to_vec();
    assert_eq!(first, a[..obs_dim].to_vec(), "{}", R::NAME);
}

#[test]
fn same_seed_and_design_give_the_same_episode() {
    deterministic::<WalkerModel>(&[1.41, 0.96, 0.57, 1.23, 1.5, 0.71]);
    deterministic::<HopperModel>(&[3.1, 0.77, 1.64, 1.2, 0.52]);
}

/// Dimensions through `make`, the design appended, truncation at 1000 steps, and the reward from
/// the torso's height, forward velocity and pitch.
fn layout_and_reward<R: Robot>(name: &str, dims: (usize, usize, usize, usize), design: &[f32]) {
    let mut env = make(name).unwrap();
    let spec = env.spec().clone();
    assert_eq!((spec.state_dim, spec.obs_dim(), spec.act_dim(), spec.design_dim()), dims, "{name}");
    assert_eq!((spec.max_episode_steps, spec.default_design.as_slice()), (1000, R::DEFAULT_DESIGN), "{name}");
    assert_eq!((spec.design.low.as_slice(), spec.design.high.as_slice()), (R::DESIGN_LOW, R::DESIGN_HIGH), "{name}");
    let state = dims.0;
    let n = dims.2;
    let obs = env.reset(2, design).unwrap().to_vec();
    assert_eq!(&obs[state..], design, "{name}");
    // Pictures show every capsule: the torso's, then one per limb.
    let mut shapes = Vec::new();
    env.draw(&mut shapes);
    assert_eq!(shapes.len(), R::plan(design).torso.len() + n, "{name}");
    assert_eq!(obs[state - 1], 0.0, "{name}: height change is measured from the settled start");
    let mut r = rng(2, 1);
    let mut a = vec![0.0f32; n];
    let mut steps = 0;
    loop {
        spec.action.sample(&mut r, &mut a);
        let s = env.step(&a).unwrap();
        steps += 1;
        assert!(s.observation[..n].iter().all(|q| q.abs() < 1.0 + 2.0 * LIMIT_TOLERANCE), "{name}: angles {:?}", &s.observation[..n]);
        assert!(!s.terminated);
        if s.truncated {
            break;
        }
    }
    assert_eq!(steps, 1000, "{name}");
    assert!(matches!(env.step(&a), Err(EnvError::NotRunning)), "{name}");

    // The reward: ((h > 0.8) (max(vx, 0) + 1) - 0.1 |pitch|) / 10, with vx and pitch in the
    // observation (indices 2n and 2n + 3) and h the torso height.
    let mut env = PlanarEnv::<R>::new();
    env.reset(5, design).unwrap();
    let (mut standing, mut fallen) = (0, 0);
    for _ in 0..300 {
        spec.action.sample(&mut r, &mut a);
        let s = env.step(&a).unwrap();
        let (o, reward) = (s.observation.to_vec(), s.reward);
        let h = env.torso_height().unwrap();
        let up = if h > STANDING_HEIGHT { 1.0 } else { 0.0 };
        let expected = (up * (o[2 * n].max(0.0) + 1.0) - 0.1 * o[2 * n + 3].abs()) / 10.0;
        assert!((reward - expected).abs() < 1e-6, "{name}: reward {reward}, expected {expected}");
        // Torso vertical velocity, pitch rate and height change in the observation.
        assert!(o[2 * n + 1].is_finite() && o[2 * n + 2].is_finite());
        if up == 1.0 { standing += 1 } else { fallen += 1 }
    }
    // Random actions topple the body sooner or later: both branches of the reward are exercised.
    assert!(standing > 0 && fallen > 0, "{name}: standing {standing}, fallen {fallen}");
}

#[test]
fn observation_layout_and_reward() {
    layout_and_reward::<WalkerModel>("walker", (17, 23, 6, 6), &[1.08, 1.18, 1.39, 0.76, 1.45, 0.92]);
    layout_and_reward::<HopperModel>("hopper", (13, 18, 4, 5), &[2.5, 1.2, 1.1, 0.9, 1.3]);
}

fn normalised_angles<R: Robot>() {
    let n = R::JOINT_LIMITS.len();
    let mut env = no_settling::<R>();
    let obs = env.reset(8, R::DEFAULT_DESIGN).unwrap().to_vec();
    let q = env.joint_angles().unwrap();
    for (i, &[lo, hi]) in R::JOINT_LIMITS.iter().enumerate() {
        assert!((obs[i] - (2.0 * (q[i] - lo) / (hi - lo) - 1.0)).abs() < 1e-6, "{} joint {i}", R::NAME);
        assert_eq!(obs[n + i], 0.0, "{}: at rest before settling", R::NAME);
        // Reset draws angles in +-0.5 rad, clamped to the limits.
        assert!(q[i] >= lo.max(-0.5) - 1e-4 && q[i] <= hi.min(0.5) + 1e-4, "{} joint {i}: {}", R::NAME, q[i]);
    }
}

#[test]
fn normalised_angles_match_the_joint_angles() {
    normalised_angles::<WalkerModel>();
    normalised_angles::<HopperModel>();
}

fn rejects_bad_input<R: Robot>(bad_designs: &[Vec<f32>]) {
    let n = R::JOINT_LIMITS.len();
    let mut env = PlanarEnv::<R>::new();
    assert!(matches!(env.step(&vec![0.0; n]), Err(EnvError::NotRunning)));
    for bad in bad_designs {
        assert!(matches!(env.reset(0, bad), Err(EnvError::Design(_))), "{} {bad:?}", R::NAME);
    }
    env.reset(0, R::DEFAULT_DESIGN).unwrap();
    let mut inf = vec![0.0; n];
    inf[1] = f32::INFINITY;
    for bad in [vec![0.0; n - 1], vec![0.0; n + 1], inf] {
        assert!(matches!(env.step(&bad), Err(EnvError::Action(_))), "{} {bad:?}", R::NAME);
    }
    // Out-of-range actions are clipped: 5 acts as 1.
    let mut clipped = PlanarEnv::<R>::new();
    let mut unit = PlanarEnv::<R>::new();
    clipped.reset(6, R::DEFAULT_DESIGN).unwrap();
    unit.reset(6, R::DEFAULT_DESIGN).unwrap();
    let big: Vec<f32> = (0..n).map(|i| [5.0, -5.0, 0.5, 3.0][i % 4]).collect();
    let unit_action: Vec<f32> = big.iter().map(|a| a.clamp(-1.0, 1.0)).collect();
    let a = clipped.step(&big).unwrap().observation.to_vec();
    let b = unit.step(&unit_action).unwrap().observation.to_vec();
    assert_eq!(a, b, "{}", R::NAME);
}

#[test]
fn bad_designs_and_actions_are_rejected() {
    rejects_bad_input::<WalkerModel>(&[vec![1.0; 5], vec![1.0; 7], vec![0.4; 6], vec![1.6; 6], vec![1.0, 1.0, f32::NAN, 1.0, 1.0, 1.0]]);
    // The nose may reach 4, the legs only 2.
    rejects_bad_input::<HopperModel>(&[
        vec![1.0; 4],
        vec![1.0; 6],
        vec![0.4, 1.0, 1.0, 1.0, 1.0],
        vec![4.1, 1.0, 1.0, 1.0, 1.0],
        vec![1.0, 2.5, 1.0, 1.0, 1.0],
        vec![1.0, 1.0, 1.0, 1.0, f32::INFINITY],
    ]);
    // The bounds themselves are valid.
    Hopper::new().reset(0, &[4.0, 2.0, 0.5, 2.0, 0.5]).unwrap();
}

/// `cargo test --release -p coadapt-robots --test all planar_robots:: -- --ignored --nocapture`: each
/// physics setting's worst joint-limit violation (radians) for the low, original and high designs,
/// and the deepest any part went into the ground, over 10,000 held random full-torque steps per
/// design (the tables in the `walker` and `hopper` module docs).
fn sweep<R: Robot>(rows: &[(usize, usize, f32)]) {
    println!("{}: | steps | iters | armature | worst violation (rad) low / original / high | in ground (m) |", R::NAME);
    let [low, original, high, _] = corners::<R>();
    for &(substeps, solver_iterations, armature) in rows {
        let cfg = SimConfig { substeps, solver_iterations, armature, ..R::default_config() };
        let mut worst = Vec::new();
        let mut deepest = 0.0f32;
        for d in [&low, &original, &high] {
            let (w, p) = abuse::<R>(cfg, d, 10_000, 7);
            worst.push(format!("{w:.3}"));
            deepest = deepest.max(p);
        }
        println!("| {substeps} | {solver_iterations} | {armature} | {} | {deepest:.3} |", worst.join(" / "));
    }
}

#[test]
#[ignore = "a measurement sweep that takes minutes: run with -- --ignored --nocapture"]
fn measure_limit_violations() {
    sweep::<WalkerModel>(&[(2, 4, 0.01), (2, 8, 0.01), (4, 4, 0.01), (2, 4, 0.1), (2, 6, 0.1), (2, 8, 0.1), (4, 4, 0.1), (2, 4, 0.2)]);
    sweep::<HopperModel>(&[(2, 4, 0.2), (2, 6, 0.2), (2, 8, 0.2), (4, 4, 0.2), (2, 6, 0.1)]);
}

/// Env steps per second of each planar robot (uniform random actions, resets included), the best
/// of 5 one-second runs taken in turns, so that load from other processes hits them alike.
#[test]
#[ignore = "a measurement sweep that takes minutes: run with -- --ignored --nocapture"]
fn measure_speed() {
    let names = ["half-cheetah", "walker", "hopper"];
    let mut best = [0.0f64; 3];
    for _ in 0..5 {
        for (b, name) in best.iter_mut().zip(names) {
            *b = b.max(env_steps_per_second(name, 1.0).unwrap());
        }
    }
    // The 2 x 4 setting (HalfCheetah's) for scale.
    let walker_2x4 =
        steps_per_second(&mut Walker::with_config(SimConfig { solver_iterations: 4, ..WalkerModel::default_config() }), 2.0, 0);
    let hopper_2x4 =
        steps_per_second(&mut Hopper::with_config(SimConfig { solver_iterations: 4, ..HopperModel::default_config() }), 2.0, 0);
    println!(
        "env steps/s, best of 5: {:?}; walker 2x4 {walker_2x4:.0?}, hopper 2x4 {hopper_2x4:.0?}",
        names.iter().zip(best).collect::<Vec<_>>()
    );
}
