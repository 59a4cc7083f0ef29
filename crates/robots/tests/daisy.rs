//! Daisy in rapier3d: settling, start height, joint limits under abuse, stability at the design
//! bounds, determinism, the observation layout and input validation. The ignored `measure_settings`
//! prints the measurement table of the module documentation.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, EnvError, rng};
use coadapt_robots::bench::steps_per_second;
use coadapt_robots::daisy::{Daisy, ORIGINAL_DESIGN, SimConfig, start_height};
use coadapt_robots::make;
use rand::Rng;
use std::time::Instant;

/// Worst joint-limit violation (radians) allowed under sustained full torque. The multibody limit
/// constraints only engage once a joint is past its limit, so a fast joint overshoots by about its
/// speed times a solver substep; the default setting measured 0.076 rad at worst over 10,000 steps
/// on each of three designs (module docs).
const LIMIT_TOLERANCE: f32 = 0.1;

/// Every length at `len`, every base offset at `offset`.
fn uniform(len: f32, offset: f32) -> [f32; 9] {
    let mut d = [len; 9];
    d[6..].fill(offset);
    d
}

fn no_settling() -> Daisy {
    Daisy::with_config(SimConfig { settle_steps: 0, ..SimConfig::default() })
}

#[test]
fn the_body_falls_and_comes_to_rest_on_the_ground() {
    let mut env = no_settling();
    env.reset(3, &ORIGINAL_DESIGN).unwrap();
    let start = env.torso_height().unwrap();
    assert!((start - start_height(&[[0.3; 2]; 3], 0.1)).abs() < 1e-4, "starts at {start}");
    let mut last = Vec::new();
    for _ in 0..100 {
        last = env.step(&[0.0; 18]).unwrap().observation.to_vec();
    }
    let rest = env.torso_height().unwrap();
    assert!(rest < start - 0.05, "did not fall: {start} -> {rest}");
    assert!(rest > 0.03, "torso sank into the ground: {rest}");
    assert!(env.lowest_point().unwrap() > -0.02, "a part is in the ground: {}", env.lowest_point().unwrap());
    // Joint velocities (scaled by 0.1) and torso velocity.
    for (i, v) in last[18..42].iter().enumerate() {
        if !(36..39).contains(&(18 + i)) {
            assert!(v.abs() < 0.02, "not at rest: observation[{}] = {v}", 18 + i);
        }
    }
    // The default reset holds the start pose while the body settles: the original design stands
    // on its legs, at rest.
    let mut env = Daisy::new();
    for seed in 0..3 {
        let obs = env.reset(seed, &ORIGINAL_DESIGN).unwrap().to_vec();
        let h = env.torso_height().unwrap();
        assert!(h > 0.2, "seed {seed}: the original design does not stand: torso at {h}");
        for (i, v) in obs[18..42].iter().enumerate() {
            assert!(v.abs() < 0.05, "seed {seed}: unsettled first observation[{}] = {v}", 18 + i);
        }
    }
}

#[test]
fn longer_legs_start_the_torso_higher() {
    let mut env = no_settling();
    let mut heights = Vec::new();
    for len in [0.12f32, 0.2, 0.3, 0.4, 0.5] {
        for seed in 0..10 {
            for offset in [-0.2, 0.2] {
                env.reset(seed, &uniform(len, offset)).unwrap();
                let low = env.lowest_point().unwrap();
                assert!(low > 0.0, "length {len}, seed {seed}: starts {low} m deep in the ground");
            }
        }
        heights.push(env.torso_height().unwrap());
    }
    assert!(heights.windows(2).all(|w| w[1] > w[0] + 0.05), "{heights:?}");
    // The longest tibia sets the height.
    let mut d = uniform(0.12, 0.0);
    d[3] = 0.5;
    env.reset(0, &d).unwrap();
    assert!(env.torso_height().unwrap() > heights[3]);
}

/// Runs `steps` steps of random full-torque actions (each held for 1-20 steps, which pushes joints
/// into their limits far harder than a per-step coin flip), new episodes every 1000 steps;
/// returns the worst limit violation and the deepest any part went into the ground, or the step
/// at which the simulation failed.
fn try_abuse(cfg: SimConfig, design: &[f32], steps: usize, seed: u64) -> Result<(f32, f32), String> {
    let mut env = Daisy::with_config(cfg);
    let mut r = rng(seed, 9);
    let (mut action, mut hold, mut worst, mut deepest) = ([0.0f32; 18], 0, 0.0f32, 0.0f32);
    for t in 0..steps {
        if t % 1000 == 0 {
            env.reset(seed + t as u64, design).map_err(|e| format!("reset at step {t}: {e}"))?;
        }
        if hold == 0 {
            action = std::array::from_fn(|_| if r.random::<bool>() { 1.0 } else { -1.0 });
            hold = r.random_range(1..=20);
        }
        hold -= 1;
        let s = env.step(&action).map_err(|e| format!("step {t}: {e}"))?;
        if let Some(x) = s.observation.iter().find(|x| !x.is_finite()) {
            return Err(format!("step {t}: observation {x}"));
        }
        worst = worst.max(env.limit_violation());
        deepest = deepest.max(-env.lowest_point().unwrap());
    }
    Ok((worst, deepest))
}

fn abuse(cfg: SimConfig, design: &[f32], steps: usize, seed: u64) -> (f32, f32) {
    try_abuse(cfg, design, steps, seed).unwrap()
}

#[test]
fn joint_limits_hold_under_random_full_torque() {
    let (worst, _) = abuse(SimConfig::default(), &ORIGINAL_DESIGN, 10_000, 1);
    assert!(worst < LIMIT_TOLERANCE, "worst violation {worst} rad");
}

#[test]
fn no_nan_and_limits_hold_at_the_design_bound_corners() {
    // 5,000 steps per corner keeps this test near 5 s; `measure_settings` runs 10,000 on the
    // short and long corners (module documentation).
    for (len, offset) in [(0.12f32, -0.2f32), (0.5, 0.2)] {
        let (worst, _) = abuse(SimConfig::default(), &uniform(len, offset), 5_000, 2);
        assert!(worst < LIMIT_TOLERANCE, "lengths {len}, offsets {offset}: worst violation {worst} rad");
    }
    // Uniform random actions on mixed corners.
    let mut env = Daisy::new();
    let mut r = rng(4, 0);
    let mut a = [0.0f32; 18];
    for design in [[0.5, 0.12, 0.12, 0.5, 0.5, 0.12, -0.2, 0.2, -0.2], [0.12, 0.5, 0.5, 0.12, 0.12, 0.5, 0.2, -0.2, 0.2]] {
        env.reset(4, &design).unwrap();
        for _ in 0..1000 {
            env.spec().action.sample(&mut r, &mut a);
            assert!(env.step(&a).unwrap().observation.iter().all(|x| x.is_finite()));
        }
    }
}

fn rollout(seed: u64, design: &[f32], steps: usize) -> Vec<f32> {
    let mut env = Daisy::new();
    let mut out = env.reset(seed, design).unwrap().to_vec();
    let mut r = rng(seed, 5);
    let mut a = [0.0f32; 18];
    for _ in 0..steps {
        env.spec().action.sample(&mut r, &mut a);
        let s = env.step(&a).unwrap();
        out.extend_from_slice(s.observation);
        out.push(s.reward);
    }
    out
}

#[test]
fn same_seed_and_design_give_the_same_episode() {
    let design = [0.41, 0.26, 0.19, 0.33, 0.47, 0.14, 0.05, -0.17, 0.12];
    let a = rollout(11, &design, 200);
    let b = rollout(11, &design, 200);
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_ne!(rollout(12, &design, 0), a[..52].to_vec(), "the seed must change the start");
    // Reusing one environment across resets gives the same episode too.
    let mut env = Daisy::new();
    env.reset(99, &ORIGINAL_DESIGN).unwrap();
    env.step(&[1.0; 18]).unwrap();
    let first = env.reset(11, &design).unwrap().to_vec();
    assert_eq!(first, a[..52].to_vec());
}

#[test]
fn observation_layout_and_reward() {
    let mut env = make("daisy").unwrap();
    let spec = env.spec().clone();
    assert_eq!((spec.state_dim, spec.obs_dim(), spec.act_dim(), spec.design_dim()), (43, 52, 18, 9));
    assert_eq!(spec.max_episode_steps, 1000);
    assert_eq!(spec.default_design, ORIGINAL_DESIGN.to_vec());
    assert_eq!((spec.design.low[0], spec.design.high[5], spec.design.low[6], spec.design.high[8]), (0.12, 0.5, -0.2, 0.2));
    let design = [0.21, 0.36, 0.29, 0.44, 0.15, 0.27, 0.13, -0.08, 0.02];
    let obs = env.reset(2, &design).unwrap().to_vec();
    assert_eq!(obs.len(), 52);
    assert_eq!(&obs[43..], &design);
    assert_eq!(&obs[36..39], &[0.0; 3], "rotation is measured from the settled start");
    assert_eq!(obs[42], 0.0, "height change is measured from the settled start");
    let mut r = rng(2, 1);
    let mut a = [0.0f32; 18];
    let mut steps = 0;
    loop {
        spec.action.sample(&mut r, &mut a);
        let s = env.step(&a).unwrap();
        steps += 1;
        let o = s.observation;
        assert!(o[..18].iter().all(|q| q.abs() < 1.0 + 2.0 * LIMIT_TOLERANCE), "normalised angles {:?}", &o[..18]);
        let angle = (o[36] * o[36] + o[37] * o[37] + o[38] * o[38]).sqrt();
        assert!(angle <= std::f32::consts::PI + 1e-4);
        assert!(s.reward >= -0.25 * angle - 1e-6 && s.reward.is_finite());
        assert!(!s.terminated);
        if s.truncated {
            break;
        }
    }
    assert_eq!(steps, 1000);
    assert!(matches!(env.step(&a), Err(EnvError::NotRunning)));
}

#[test]
fn reward_follows_progress_and_rotation() {
    let mut env = Daisy::new();
    let mut prev = env.reset(5, &ORIGINAL_DESIGN).unwrap().to_vec();
    let mut y = env.torso_position().unwrap()[1];
    let mut r = rng(5, 2);
    let mut a = [0.0f32; 18];
    for _ in 0..200 {
        env.spec().action.sample(&mut r, &mut a);
        let s = env.step(&a).unwrap();
        let o = s.observation.to_vec();
        let reward = s.reward;
        let new_y = env.torso_position().unwrap()[1];
        let angle = (o[36] * o[36] + o[37] * o[37] + o[38] * o[38]).sqrt();
        let expected = (new_y - y).max(0.0) / 0.066 - 0.25 * angle;
        assert!((reward - expected).abs() < 1e-5, "{reward} vs {expected}");
        // The forward velocity is the progress rate, roughly.
        assert!(((new_y - y) / 0.05 - 0.5 * (o[40] + prev[40])).abs() < 0.5, "{} vs {}", (new_y - y) / 0.05, o[40]);
        (prev, y) = (o, new_y);
    }
}

#[test]
fn normalised_angles_match_the_joint_angles() {
    let mut env = no_settling();
    let design = [0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.2, -0.2, 0.1];
    let obs = env.reset(8, &design).unwrap().to_vec();
    let q = env.joint_angles().unwrap();
    let limits = *env.limits();
    for j in 0..18 {
        let [lo, hi] = limits[j];
        assert!((obs[j] - (2.0 * (q[j] - lo) / (hi - lo) - 1.0)).abs() < 1e-5);
        // Reset draws angles within 0.1 rad of the standing pose: the base at its range's centre
        // (the design's offset), the other joints at zero.
        let stand = if j % 3 == 0 { design[6 + j / 6] } else { 0.0 };
        assert!((q[j] - stand).abs() <= 0.1 + 1e-4, "joint {j}: {}", q[j]);
        if j % 3 == 0 {
            assert!(((lo + hi) / 2.0 - stand).abs() < 1e-5, "joint {j}: [{lo}, {hi}]");
        }
    }
}

#[test]
fn positive_offsets_turn_the_legs_forwards_and_the_picture_faces_forwards() {
    // Drawn shapes: 18 leg capsules and the torso box's 4 top edges, the robot's forward as the
    // picture's x. Mean x of the leg capsules' ends, relative to the torso's.
    fn legs_forward(env: &Daisy) -> f32 {
        let mut shapes = Vec::new();
        env.draw(&mut shapes);
        assert_eq!(shapes.len(), 22);
        let ends: Vec<[f32; 3]> = shapes
            .iter()
            .filter_map(|s| match s {
                coadapt_core::Shape::Capsule { a, b, radius } if *radius < 0.045 => Some([*a, *b]),
                _ => None,
            })
            .flatten()
            .collect();
        assert_eq!(ends.len(), 36);
        let torso_y = env.torso_position().unwrap()[1];
        ends.iter().map(|p| p[0]).sum::<f32>() / 36.0 - torso_y
    }
    // One step in the air (the colliders follow their bodies once the world has stepped).
    let mut env = no_settling();
    env.reset(1, &uniform(0.3, -0.2)).unwrap();
    env.step(&[0.0; 18]).unwrap();
    let back = legs_forward(&env);
    env.reset(1, &uniform(0.3, 0.2)).unwrap();
    env.step(&[0.0; 18]).unwrap();
    let front = legs_forward(&env);
    assert!(front > back + 0.05, "legs at {back} with offsets -0.2, {front} with +0.2");
}

#[test]
fn bad_designs_and_actions_are_rejected() {
    let mut env = Daisy::new();
    assert!(matches!(env.step(&[0.0; 18]), Err(EnvError::NotRunning)));
    let mut nan = ORIGINAL_DESIGN.to_vec();
    nan[4] = f32::NAN;
    for bad in [vec![0.3; 8], vec![0.3; 10], uniform(0.1, 0.0).to_vec(), uniform(0.55, 0.0).to_vec(), uniform(0.3, 0.25).to_vec(), nan] {
        assert!(matches!(env.reset(0, &bad), Err(EnvError::Design(_))), "{bad:?}");
    }
    env.reset(0, &ORIGINAL_DESIGN).unwrap();
    let mut inf = vec![0.0; 18];
    inf[7] = f32::INFINITY;
    for bad in [vec![0.0; 17], vec![0.0; 19], inf] {
        assert!(matches!(env.step(&bad), Err(EnvError::Action(_))), "{bad:?}");
    }
    // Out-of-range actions are clipped: 5 acts as 1.
    let mut clipped = Daisy::new();
    let mut unit = Daisy::new();
    clipped.reset(6, &ORIGINAL_DESIGN).unwrap();
    unit.reset(6, &ORIGINAL_DESIGN).unwrap();
    let big: Vec<f32> = (0..18).map(|j| [5.0, -3.0, 0.5][j % 3]).collect();
    let unit_action: Vec<f32> = big.iter().map(|a| a.clamp(-1.0, 1.0)).collect();
    let a = clipped.step(&big).unwrap().observation.to_vec();
    let b = unit.step(&unit_action).unwrap().observation.to_vec();
    assert_eq!(a, b);
}

/// This thread's CPU time in seconds (user + system, from `/proc/thread-self/stat`, in 10 ms
/// ticks): on a shared machine it is steadier than the wall clock.
fn thread_cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    // The fields after the command name (which ends with the last `)`): utime is the 12th, stime the 13th.
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks: f64 = fields.get(11..13).map_or(0.0, |f| f.iter().filter_map(|x| x.parse::<f64>().ok()).sum());
    ticks / 100.0
}

/// Env steps per second of wall time and of CPU time (uniform random actions on the original
/// design, resets included), over about `seconds`.
fn speed(cfg: SimConfig, seconds: f64) -> (f64, f64) {
    let mut env = Daisy::with_config(cfg);
    let (wall, cpu) = (Instant::now(), thread_cpu_seconds());
    let rate = steps_per_second(&mut env, seconds, 0).unwrap();
    let steps = rate * wall.elapsed().as_secs_f64();
    (rate, steps / (thread_cpu_seconds() - cpu))
}

/// The measurement table of the module documentation:
/// `cargo test --release -p coadapt-robots --test all daisy:: -- --ignored --nocapture`
/// (`DAISY_STEPS=N` changes the 10,000 abuse steps per design).
#[test]
#[ignore = "a measurement that takes minutes"]
fn measure_settings() {
    let steps = std::env::var("DAISY_STEPS").ok().and_then(|s| s.parse().ok()).unwrap_or(10_000);
    // (control step, physics steps per control step, solver iterations, Gauss-Seidel sweeps per
    // iteration, prediction distance)
    let settings = [
        (0.05, 1, 4, 1, 0.2),
        (0.05, 2, 1, 1, 0.2),
        (0.05, 2, 2, 1, 0.02),
        (0.05, 2, 2, 1, 0.1),
        (0.05, 2, 2, 1, 0.2),
        (0.05, 2, 2, 4, 0.2),
        (0.05, 2, 3, 1, 0.2),
        (0.05, 2, 4, 1, 0.2),
        (0.05, 3, 1, 1, 0.2),
        (0.05, 3, 2, 1, 0.2),
        (0.05, 4, 1, 1, 0.2),
        (0.05, 4, 2, 1, 0.2),
        (0.0165, 1, 2, 1, 0.2),
        (0.0165, 1, 4, 1, 0.2),
    ];
    println!(
        "| control step (s) | substeps | iters | sweeps | prediction (m) | env steps/s wall (CPU) | worst violation (rad) short / original / long | in ground (m) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (control_dt, substeps, solver_iterations, pgs_iterations, prediction_distance) in settings {
        let cfg = SimConfig { control_dt, substeps, solver_iterations, pgs_iterations, prediction_distance, ..SimConfig::default() };
        let (rate, cpu_rate) = speed(cfg, 3.0);
        let mut worst = Vec::new();
        let mut depth = 0.0f32;
        let start = Instant::now();
        for design in [uniform(0.12, 0.2), ORIGINAL_DESIGN, uniform(0.5, 0.2)] {
            match try_abuse(cfg, &design, steps, 7) {
                Ok((w, d)) => {
                    worst.push(format!("{w:.3}"));
                    depth = depth.max(d);
                }
                Err(e) => worst.push(format!("failed: {e}")),
            }
        }
        println!(
            "| {control_dt} | {substeps} | {solver_iterations} | {pgs_iterations} | {prediction_distance} | {rate:.0} ({cpu_rate:.0}) | {} | {depth:.3} | ({:.1} s)",
            worst.join(" / "),
            start.elapsed().as_secs_f64()
        );
    }
}

/// Env steps per second of the default Daisy against HalfCheetah, alternated three times in one
/// run (medians): `cargo test --release -p coadapt-robots --test all daisy::speed -- --ignored --nocapture`.
#[test]
#[ignore = "a measurement"]
fn speed_against_half_cheetah() {
    let (mut daisy, mut cheetah) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        daisy.push(speed(SimConfig::default(), 5.0).0);
        cheetah.push(coadapt_robots::bench::env_steps_per_second("half-cheetah", 5.0).unwrap());
    }
    daisy.sort_by(f64::total_cmp);
    cheetah.sort_by(f64::total_cmp);
    println!("daisy {daisy:.0?} env steps/s, half-cheetah {cheetah:.0?}: ratio {:.1}", cheetah[1] / daisy[1]);
}
