//! The SAC update spreads its work over the cores of rayon's pool (the policy's and the
//! critics' backward passes split into deltas and weight gradients, `Sac::update`); what it
//! computes must not depend on how the halves land: updates on one thread and on two give the
//! same bits, in f32 and in bf16 products alike.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Batch, rng};
use coadapt_learner::{Sac, SacConfig};
use coadapt_nn::Precision;
use rand::Rng;

fn batch(rows: usize, obs: usize, act: usize) -> Batch {
    let mut r = rng(11, 3);
    let mut b = Batch::new(rows, obs, act);
    for v in b.obs.iter_mut().chain(b.next_obs.iter_mut()).chain(b.rew.iter_mut()).chain(b.act.iter_mut()) {
        *v = r.random_range(-1.0..1.0);
    }
    for d in b.done.iter_mut() {
        *d = if r.random_range(0.0..1.0) < 0.1 { 1.0 } else { 0.0 };
    }
    b
}

/// Every parameter after five updates on a pool of `threads`.
fn after_updates(threads: usize, precision: Precision) -> Vec<f32> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let cfg = SacConfig { hidden: vec![48, 40, 40], auto_alpha: true, precision, ..SacConfig::default() };
        let mut sac = Sac::new(23, 6, cfg, 4).unwrap();
        let b = batch(64, 23, 6);
        for _ in 0..5 {
            sac.update(&b);
        }
        let (q1, q1_bar) = sac.critic_params(0);
        let (q2, q2_bar) = sac.critic_params(1);
        [sac.policy_params(), q1, q1_bar, q2, q2_bar].concat()
    })
}

#[test]
fn an_update_on_two_threads_equals_one_on_one_thread_bit_for_bit() {
    for precision in [Precision::F32, Precision::Bf16] {
        let one = after_updates(1, precision);
        let two = after_updates(2, precision);
        assert_eq!(one.len(), two.len());
        let start = Sac::new(23, 6, SacConfig { hidden: vec![48, 40, 40], ..SacConfig::default() }, 4).unwrap();
        assert_ne!(one[..10], start.policy_params()[..10], "{precision:?}: the updates changed nothing");
        let differing = one.iter().zip(&two).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert_eq!(differing, 0, "{precision:?}: {differing} of {} parameters differ between 1 and 2 threads", one.len());
    }
}
