//! Rough speed of the bf16 product against faer's f32 product at the SAC layer shapes and the
//! three layouts of a layer (forward X W^T, weight gradient D^T X, input gradient D W). Not a
//! benchmark (`coadapt bench nn` is): `cargo run --release -p coadapt-nn --example bf16_speed`
use coadapt_nn::bf16::{Scratch, View, matmul};
use faer::linalg::matmul::matmul as fmatmul;
use faer::{Accum, MatMut, MatRef, Par};
use std::time::Instant;

/// A case: name, C's shape, faer's operands, ours.
type Case<'a> = (&'static str, usize, usize, MatRef<'a, f32>, MatRef<'a, f32>, View<'a>, View<'a>);

fn main() {
    let (rows, n_in, n_out) = (256usize, 200usize, 200usize);
    let x: Vec<f32> = (0..rows * n_in).map(|i| ((i * 7919) % 1000) as f32 / 1000.0 - 0.5).collect();
    let w: Vec<f32> = (0..n_out * n_in).map(|i| ((i * 104729) % 1000) as f32 / 1000.0 - 0.5).collect();
    let d: Vec<f32> = (0..rows * n_out).map(|i| ((i * 31) % 1000) as f32 / 1000.0 - 0.5).collect();
    let xm = MatRef::from_row_major_slice(&x, rows, n_in);
    let wm = MatRef::from_row_major_slice(&w, n_out, n_in);
    let dm = MatRef::from_row_major_slice(&d, rows, n_out);
    let xv = View::row_major(&x, rows, n_in);
    let wv = View::row_major(&w, n_out, n_in);
    let dv = View::row_major(&d, rows, n_out);
    let mut scratch = Scratch::default();
    let cases: [Case; 3] = [
        ("forward X W^T", rows, n_out, xm, wm.transpose(), xv, wv.t()),
        ("weight grad D^T X", n_out, n_in, dm.transpose(), xm, dv.t(), xv),
        ("input grad D W", rows, n_in, dm, wm, dv, wv),
    ];
    for (name, m, n, fa, fb, ba, bb) in cases {
        let mut c = vec![0.0f32; m * n];
        let reps = 2000;
        let (mut best_f, mut best_b) = (f64::MAX, f64::MAX);
        for _ in 0..5 {
            let t = Instant::now();
            for _ in 0..reps {
                fmatmul(MatMut::from_row_major_slice_mut(&mut c, m, n), Accum::Replace, fa, fb, 1.0f32, Par::Seq);
            }
            best_f = best_f.min(t.elapsed().as_secs_f64() / reps as f64);
            let t = Instant::now();
            for _ in 0..reps {
                matmul(&mut c, false, ba, bb, &mut scratch);
            }
            best_b = best_b.min(t.elapsed().as_secs_f64() / reps as f64);
        }
        println!(
            "{name} ({m}x{}x{n}): f32 faer {:.1} us, bf16 {:.1} us, ratio {:.2}",
            ba.cols,
            best_f * 1e6,
            best_b * 1e6,
            best_f / best_b
        );
    }
}
