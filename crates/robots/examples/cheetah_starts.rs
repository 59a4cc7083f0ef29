//! How HalfCheetah's episodes start (issue 28, section 4): over many reset seeds, how often the
//! settled body rests on its torso or head, has a joint folded to its limit, or lies beyond a
//! quarter turn of pitch, with the joints limp while settling (the setting before the fix) and
//! held at their start angles (the reference's reset, which holds every joint at its drawn angle
//! while the body settles).
//!
//! `cargo run --release -p coadapt-robots --example cheetah_starts -- [SEEDS, default 1000] [DESIGN, e.g. 1,1,1,1,1,1]`

use coadapt_core::Env;
use coadapt_robots::half_cheetah::{HalfCheetah, JOINT_LIMITS, SimConfig};

fn main() {
    let mut args = std::env::args().skip(1);
    let seeds: u64 = args.next().map_or(1000, |s| s.parse().expect("SEEDS: a number"));
    let design: Vec<f32> = args.next().map_or(vec![1.0; 6], |s| s.split(',').map(|x| x.parse().expect("DESIGN: numbers")).collect());
    let limp = SimConfig { hold_while_settling: false, settle_steps: 60, settle_gravity: 9.81, ..SimConfig::default() };
    let held = SimConfig { hold_while_settling: true, ..limp };
    let reference = SimConfig { hold_while_settling: true, settle_steps: 50, settle_gravity: 0.5, ..limp };
    for (name, cfg) in [
        ("joints limp, 60 steps at 9.81", limp),
        ("joints held, 60 steps at 9.81", held),
        ("joints held, 50 steps at 0.5 (the reference)", reference),
    ] {
        let mut env = HalfCheetah::with_config(cfg);
        let (mut on_torso, mut at_limit, mut tilted, mut airborne) = (0, 0, 0, 0);
        let mut heights = Vec::new();
        for seed in 0..seeds {
            env.reset(seed, &design).expect("reset");
            env.part_heights(&mut heights);
            // The torso's capsule and the head are the first two parts.
            on_torso += usize::from(heights[0] < 0.005 || heights[1] < 0.005);
            let q = env.joint_angles().expect("a body");
            at_limit += usize::from(q.iter().zip(JOINT_LIMITS).any(|(q, [lo, hi])| *q < lo + 0.02 || *q > hi - 0.02));
            tilted += usize::from(env.torso().expect("a body").pitch.abs() > std::f32::consts::FRAC_PI_4);
            airborne += usize::from(heights.iter().all(|h| *h > 0.005));
        }
        let pct = |n: usize| 100.0 * n as f64 / seeds as f64;
        println!(
            "{{\"settling\":\"{name}\",\"seeds\":{seeds},\"torso_or_head_on_ground_pct\":{:.1},\"joint_at_limit_pct\":{:.1},\"pitch_beyond_45deg_pct\":{:.1},\"in_the_air_pct\":{:.1}}}",
            pct(on_torso),
            pct(at_limit),
            pct(tilted),
            pct(airborne)
        );
    }
}
