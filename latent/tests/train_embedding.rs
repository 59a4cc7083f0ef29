//! The embedding learns on real pixel frames: HalfCheetah through the camera with random
//! actions, a short training run lowers every part of the loss on held-out triples.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_latent::{Embedding, EmbeddingConfig, EmbeddingTrainer, FrameSet};
use rand::{Rng, SeedableRng};

fn frames(side: usize, episodes: usize, steps: usize, seed: u64) -> FrameSet {
    let cfg = PixelsConfig { width: side, height: side, frames: 1, action_repeat: 2 };
    let mut env = Pixels::new(coadapt_robots::make("half-cheetah").unwrap(), cfg).unwrap();
    let design = env.spec().default_design.clone();
    let n = 3 * side * side;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut set = FrameSet::new(n);
    for e in 0..episodes {
        let mut ep = env.reset(seed * 100 + e as u64, &design).unwrap()[..n].to_vec();
        let a_dim = env.spec().act_dim();
        for _ in 0..steps {
            let a: Vec<f32> = (0..a_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
            let s = env.step(&a).unwrap();
            ep.extend_from_slice(&s.observation[..n]);
        }
        set.push_episode(&ep).unwrap();
    }
    set
}

#[test]
fn training_on_half_cheetah_frames_lowers_every_part_of_the_loss() {
    let side = 32;
    let train = frames(side, 4, 60, 1);
    let held_out = frames(side, 2, 60, 2);
    let cfg = EmbeddingConfig { image: side, in_channels: 3, channels: [16, 16, 16], latent: 20, margin: 1.0 };
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let mut t = EmbeddingTrainer::new(Embedding::new(cfg).unwrap(), 1e-3, &mut rng);
    let mut eval_rng = rand::rngs::StdRng::seed_from_u64(9);
    let before = t.evaluate(&held_out, 64, &mut eval_rng);
    for _ in 0..200 {
        t.step(&train, 16, &mut rng);
    }
    let mut eval_rng = rand::rngs::StdRng::seed_from_u64(9);
    let after = t.evaluate(&held_out, 64, &mut eval_rng);
    eprintln!("held-out loss parts before {before:?}, after 200 steps {after:?}");
    assert!(after.reconstruction < 0.5 * before.reconstruction, "{before:?} -> {after:?}");
    assert!(after.total() < 0.7 * before.total(), "{before:?} -> {after:?}");
    // On frames never trained on, random frames' codes spread out (mean distance at least
    // margin - push > 0.5; at the start every code sits together, 0.16) and consecutive frames'
    // codes sit at less than half that distance (root mean square).
    let spread = 1.0 - after.push;
    assert!(spread > 0.5 && after.pull.sqrt() < 0.5 * spread, "{after:?}");
}

#[test]
fn a_frame_set_refuses_a_partial_or_single_frame_episode() {
    let mut s = FrameSet::new(12);
    assert!(s.push_episode(&[0.0; 12]).is_err());
    assert!(s.push_episode(&[0.0; 30]).is_err());
    s.push_episode(&[0.0; 36]).unwrap();
    assert_eq!(s.len(), 3);
}
