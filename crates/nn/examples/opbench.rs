//! Times the MLP's forward and backward passes on one core (a tuning aid, not a benchmark).
#![allow(clippy::unwrap_used)]
use std::time::Instant;

use coadapt_nn::Mlp;
use rand::SeedableRng;

fn time(name: &str, flops: f64, mut f: impl FnMut()) {
    for _ in 0..20 {
        f();
    }
    let n = 300;
    let t = Instant::now();
    for _ in 0..n {
        f();
    }
    let s = t.elapsed().as_secs_f64() / n as f64;
    println!("{name:<28} {:>8.1} us {:>6.1} GFLOP/s", s * 1e6, flops / s / 1e9);
}

fn main() {
    let mlp = Mlp::new(&[23, 256, 256, 256, 1]).unwrap();
    let mut p = mlp.zeros();
    mlp.init(&mut p, 0.003, &mut rand_pcg::Pcg64Mcg::seed_from_u64(1));
    for rows in [256usize, 512] {
        let x: Vec<f32> = (0..rows * 23).map(|i| (i as f32 * 0.37).sin()).collect();
        let mut act = mlp.activations(rows);
        let f = 2.0 * rows as f64 * mlp.macs_per_row() as f64;
        time(&format!("forward {rows}"), f, || {
            mlp.forward(&p, &x, rows, &mut act);
        });
        let dy = vec![0.01; rows];
        let mut g = mlp.zeros();
        let mut dx = vec![0.0; rows * 23];
        time(&format!("backward weights {rows}"), 2.0 * f, || mlp.backward(&p, &x, &mut act, 0..rows, &dy, Some(&mut g), None));
        time(&format!("backward input {rows}"), f, || mlp.backward(&p, &x, &mut act, 0..rows, &dy, None, Some(&mut dx)));
    }
    let mut adam = coadapt_nn::Adam::new(p.len(), Default::default());
    let g: Vec<f32> = (0..p.len()).map(|i| (i as f32).cos() * 1e-3).collect();
    let mut q = p.clone();
    time("adam 140k", 0.0, || adam.step(&mut q, &g));
    let mut t = p.clone();
    time("polyak 140k", 0.0, || coadapt_nn::polyak(&mut t, &q, 0.005));
    let mut gg = g.clone();
    time("clamp 140k", 0.0, || coadapt_nn::clamp_elementwise(&mut gg, 1.0));
}

#[allow(dead_code)]
fn unused() {}
