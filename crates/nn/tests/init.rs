//! Initialisation schemes: rlkit's (the reference FEAR's networks) and PyTorch's default.

#![allow(clippy::unwrap_used)] // tests: a panic is the failure report

use coadapt_nn::{HiddenInit, Mlp, mlp::RLKIT_HIDDEN_BIAS};
use rand::SeedableRng;

fn range(v: &[f32]) -> (f32, f32) {
    v.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &x| (lo.min(x), hi.max(x)))
}

#[test]
fn rlkit_init_bounds_hidden_weights_by_the_output_width_and_sets_biases_to_a_tenth() {
    // 23 -> 200 -> 50 -> 6: rlkit's fanin_init reads weight.size(0), the OUTPUT width, so layer 0
    // is bounded by 1/sqrt(200) (not 1/sqrt(23)) and layer 1 by 1/sqrt(50) (not 1/sqrt(200)).
    let mlp = Mlp::new(&[23, 200, 50, 6]).unwrap();
    let mut p = mlp.zeros();
    mlp.init_with(HiddenInit::Rlkit, &mut p, 1e-3, &mut rand_pcg::Pcg64Mcg::seed_from_u64(1));
    let l = mlp.layers();
    for (i, bound) in [(0, 1.0 / 200f32.sqrt()), (1, 1.0 / 50f32.sqrt())] {
        let (lo, hi) = range(&p[l[i].w..l[i].b]);
        assert!(lo >= -bound && hi <= bound, "layer {i}: [{lo}, {hi}] outside +-{bound}");
        assert!(lo < -0.9 * bound && hi > 0.9 * bound, "layer {i}: [{lo}, {hi}] does not fill +-{bound}");
        assert!(p[l[i].b..l[i].b + l[i].n_out].iter().all(|&b| b == RLKIT_HIDDEN_BIAS), "layer {i} biases");
    }
    let last = l[2];
    let (lo, hi) = range(&p[last.w..last.b + last.n_out]);
    assert!(lo >= -1e-3 && hi <= 1e-3 && hi > 0.0 && lo < 0.0, "last layer: [{lo}, {hi}]");

    // PyTorch's default: weights and biases within 1/sqrt(n_in).
    mlp.init_with(HiddenInit::Pytorch, &mut p, 1e-3, &mut rand_pcg::Pcg64Mcg::seed_from_u64(1));
    let bound = 1.0 / 23f32.sqrt();
    let (lo, hi) = range(&p[l[0].w..l[0].b + l[0].n_out]);
    assert!(lo >= -bound && hi <= bound && hi > 0.9 * bound, "pytorch layer 0: [{lo}, {hi}]");
    assert_eq!(HiddenInit::default(), HiddenInit::Rlkit);
}
