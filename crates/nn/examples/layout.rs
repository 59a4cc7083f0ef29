//! Which faer layout multiplies a row-major batch by W^T fastest (a tuning aid).
#![allow(clippy::unwrap_used)]
use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

fn main() {
    let (rows, n_in, n_out) = (256usize, 256usize, 256usize);
    let x: Vec<f32> = (0..rows * n_in).map(|i| (i as f32 * 0.37).sin()).collect();
    let w: Vec<f32> = (0..n_out * n_in).map(|i| (i as f32 * 0.11).cos()).collect();
    let mut y = vec![0.0f32; rows * n_out];
    let flops = 2.0 * (rows * n_in * n_out) as f64;
    let run = |name: &str, f: &mut dyn FnMut()| {
        for _ in 0..50 {
            f();
        }
        let t = Instant::now();
        for _ in 0..2000 {
            f();
        }
        let s = t.elapsed().as_secs_f64() / 2000.0;
        println!("{name:<40} {:>7.1} us {:>6.1} GFLOP/s", s * 1e6, flops / s / 1e9);
    };
    run("Y(row) = X(row) W^T", &mut || {
        matmul(
            MatMut::from_row_major_slice_mut(&mut y, rows, n_out),
            Accum::Replace,
            MatRef::from_row_major_slice(&x, rows, n_in),
            MatRef::from_row_major_slice(&w, n_out, n_in).transpose(),
            1.0f32,
            Par::Seq,
        )
    });
    run("Y^T(col) = W(row) X^T(col)", &mut || {
        matmul(
            MatMut::from_column_major_slice_mut(&mut y, n_out, rows),
            Accum::Replace,
            MatRef::from_row_major_slice(&w, n_out, n_in),
            MatRef::from_column_major_slice(&x, n_in, rows),
            1.0f32,
            Par::Seq,
        )
    });
    // dW = dY^T X
    let mut gw = vec![0.0f32; n_out * n_in];
    run("dW(row) = dY^T X", &mut || {
        matmul(
            MatMut::from_row_major_slice_mut(&mut gw, n_out, n_in),
            Accum::Replace,
            MatRef::from_row_major_slice(&y, rows, n_out).transpose(),
            MatRef::from_row_major_slice(&x, rows, n_in),
            1.0f32,
            Par::Seq,
        )
    });
    let mut dx = vec![0.0f32; rows * n_in];
    run("dX(row) = dY W", &mut || {
        matmul(
            MatMut::from_row_major_slice_mut(&mut dx, rows, n_in),
            Accum::Replace,
            MatRef::from_row_major_slice(&y, rows, n_out),
            MatRef::from_row_major_slice(&w, n_out, n_in),
            1.0f32,
            Par::Seq,
        )
    });
}
