//! HalfCheetah env steps per second with random actions, as one JSON line:
//! `cargo run --release -p coadapt-robots --example cheetah_speed [-- --seconds S]` (add
//! `--substeps N --iterations N` to time another multibody setting).
//!
//! `-- --sweep [--steps N]` instead measures each physics setting (joint kind, physics steps per
//! control step, solver iterations): env steps/s and the worst joint-limit violation over N
//! (default 10,000) steps of random full-torque actions, each held for 1-20 steps, for the
//! designs at the bound corners and the original, as the rows of a markdown table.

use coadapt_core::{Env, rng};
use coadapt_robots::bench::{env_steps_per_second, steps_per_second};
use coadapt_robots::half_cheetah::{HalfCheetah, JointKind, SimConfig};
use rand::Rng;
use std::time::Instant;

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Steps/s, worst limit violation and deepest ground penetration of `steps` held random
/// full-torque steps on `design`.
fn stress(cfg: SimConfig, design: &[f32], steps: usize) -> Result<(f64, f32, f32), coadapt_core::EnvError> {
    let mut env = HalfCheetah::with_config(cfg);
    let mut r = rng(7, 3);
    let mut action = [0.0f32; 6];
    let (mut worst, mut hold, mut lowest) = (0.0f32, 0, 0.0f32);
    let start = Instant::now();
    for t in 0..steps {
        if t % 1000 == 0 {
            env.reset(t as u64, design)?;
        }
        if hold == 0 {
            action = std::array::from_fn(|_| if r.random::<bool>() { 1.0 } else { -1.0 });
            hold = r.random_range(1..=20);
        }
        hold -= 1;
        env.step(&action)?;
        worst = worst.max(env.limit_violation());
        lowest = lowest.min(env.lowest_point().unwrap_or(0.0));
    }
    Ok((steps as f64 / start.elapsed().as_secs_f64(), worst, -lowest))
}

fn sweep(steps: usize) {
    use JointKind::{Impulse, Multibody};
    // (joints, physics steps per control step, solver iterations, MuJoCo armature and damping,
    // warm-started impulse joints)
    let settings = [
        (Multibody, 1, 4, false, false),
        (Multibody, 2, 2, false, false),
        (Multibody, 4, 1, false, false),
        (Multibody, 1, 2, true, false),
        (Multibody, 1, 4, true, false),
        (Multibody, 1, 8, true, false),
        (Multibody, 1, 12, true, false),
        (Multibody, 2, 1, true, false),
        (Multibody, 2, 2, true, false),
        (Multibody, 2, 4, true, false),
        (Multibody, 2, 6, true, false),
        (Multibody, 4, 1, true, false),
        (Multibody, 4, 2, true, false),
        (Impulse, 1, 4, false, false),
        (Impulse, 1, 8, false, false),
        (Impulse, 2, 4, false, false),
        (Impulse, 4, 2, false, false),
        (Impulse, 4, 4, false, false),
        (Impulse, 4, 4, false, true),
        (Impulse, 8, 2, false, false),
    ];
    println!(
        "| joints | physics steps per control step | solver iterations | armature + damping | warm-started joints | env steps/s | worst violation (rad) [0.8]*6 / [1]*6 / [2]*6 | deepest in ground (m) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (joints, substeps, solver_iterations, mujoco_joints, warmstart_joints) in settings {
        let armature = if mujoco_joints { 0.1 } else { 0.0 };
        let cfg = SimConfig {
            joints,
            substeps,
            solver_iterations,
            warmstart_joints,
            armature,
            joint_damping: mujoco_joints,
            ..SimConfig::default()
        };
        let mut rates = Vec::new();
        let mut worst = Vec::new();
        let mut depth = 0.0f32;
        for d in [0.8f32, 1.0, 2.0] {
            match stress(cfg, &[d; 6], steps) {
                Ok((rate, w, pen)) => {
                    rates.push(rate);
                    worst.push(format!("{w:.3}"));
                    depth = depth.max(pen);
                }
                Err(e) => worst.push(format!("failed: {e}")),
            }
        }
        let original = rates.get(1).copied().unwrap_or(f64::NAN);
        println!(
            "| {joints:?} | {substeps} | {solver_iterations} | {mujoco_joints} | {warmstart_joints} | {original:.0} | {} | {depth:.3} |",
            worst.join(" / ")
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.iter().any(|a| a == "--sweep") {
        sweep(arg(&args, "--steps", 10_000));
        return;
    }
    let seconds = arg(&args, "--seconds", 5.0);
    // Other physics settings than the default: `--substeps N --iterations N`.
    let default = SimConfig::default();
    let cfg = SimConfig {
        substeps: arg(&args, "--substeps", default.substeps),
        solver_iterations: arg(&args, "--iterations", default.solver_iterations),
        ..default
    };
    let (config, rate) = if cfg == default {
        ("half-cheetah".to_string(), env_steps_per_second("half-cheetah", seconds).map_err(|e| e.to_string()))
    } else {
        let name = format!("half-cheetah {}x{}", cfg.substeps, cfg.solver_iterations);
        (name, steps_per_second(&mut HalfCheetah::with_config(cfg), seconds, 0).map_err(|e| e.to_string()))
    };
    match rate {
        Ok(v) => println!(r#"{{"bench": "env_steps", "config": "{config}", "value": {v:.0}, "unit": "steps/s"}}"#),
        Err(e) => {
            eprintln!("cheetah_speed: {e}");
            std::process::exit(1);
        }
    }
}
