//! The time-contrastive autoencoder's loss and gradients against PyTorch float64 (the script:
//! tests/reference/embedding.py) and against central finite differences.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_latent::{Embedding, EmbeddingConfig, EmbeddingWork};
use coadapt_test_support::reference::{self as reference, stats};

/// Within 0.0002 of PyTorch's statistics (f32 against float64).
fn close(name: &str, got: [f64; 3], want: [f64; 3]) {
    reference::close(name, got, want, 0.0002);
}

fn small() -> (Embedding, Vec<f32>, Vec<f32>, Vec<f32>) {
    let cfg = EmbeddingConfig { image: 8, in_channels: 2, channels: [3, 3, 2], latent: 4, margin: 1.9 };
    let e = Embedding::new(cfg).unwrap();
    let enc: Vec<f32> = (0..e.encoder_params()).map(|i| (0.4 * (0.37 * i as f64 + 0.1).sin()) as f32).collect();
    let dec: Vec<f32> = (0..e.decoder_params()).map(|i| (0.3 * (0.23 * i as f64).cos()) as f32).collect();
    let frames: Vec<f32> = (0..3 * 2 * e.image_len()).map(|i| (0.5 + 0.5 * (0.11 * i as f64).sin()) as f32).collect();
    (e, enc, dec, frames)
}

#[test]
fn loss_and_gradients_match_pytorch() {
    let (e, enc, dec, frames) = small();
    assert_eq!((e.encoder_params(), e.decoder_params()), (209, 207), "the same parameter counts as PyTorch's modules");
    let (mut ge, mut gd) = (vec![0.0; enc.len()], vec![0.0; dec.len()]);
    let mut w = EmbeddingWork::default();
    let parts = e.loss_and_grad(&enc, &dec, &frames, 2, &mut ge, &mut gd, &mut w);
    // .venv-peers/bin/python latent/tests/reference/embedding.py
    let want = [8.136661594895e-01, 1.135783929113e-01, 1.863054480101e+00];
    for (g, w) in [parts.reconstruction, parts.pull, parts.push].iter().zip(want) {
        assert!((f64::from(*g) - w).abs() < 1e-5 * w.max(1.0), "loss parts {parts:?} vs PyTorch {want:?}");
    }
    close("grad_enc", stats(&ge), [-8.102542061131e+00, -1.183468476237e+01, 1.525687653201e+01]);
    close("grad_dec", stats(&gd), [-1.660609197894e+00, -3.429125363771e+02, 1.378832748247e+00]);
}

#[test]
fn gradients_match_finite_differences() {
    let (e, enc, dec, frames) = small();
    let mut w = EmbeddingWork::default();
    let (mut ge, mut gd) = (vec![0.0; enc.len()], vec![0.0; dec.len()]);
    e.loss_and_grad(&enc, &dec, &frames, 2, &mut ge, &mut gd, &mut w);
    let mut loss = |enc: &[f32], dec: &[f32]| {
        let (mut a, mut b) = (vec![0.0; enc.len()], vec![0.0; dec.len()]);
        f64::from(e.loss_and_grad(enc, dec, &frames, 2, &mut a, &mut b, &mut w).total())
    };
    // Central differences in f32 arithmetic. Measured worst relative differences: 5e-2 at h =
    // 1e-2 and 1.5e-2 at 3e-3 (ReLU kinks and the normalisation's curvature), 1.8e-4 at 1e-3,
    // 6.5e-4 at 3e-4 (rounding): h = 1e-3, with ten times the measured worst as the bound.
    let h = 1e-3f32;
    let mut worst = 0.0f64;
    let mut check = |name: &str, i: usize, g: f32, fd: f64| {
        let err = (fd - f64::from(g)).abs() / (1.0 + fd.abs());
        worst = worst.max(err);
        assert!(err < 2e-3, "{name}[{i}]: {g} vs finite difference {fd}");
    };
    for i in 0..enc.len() {
        let (mut up, mut dn) = (enc.clone(), enc.clone());
        up[i] += h;
        dn[i] -= h;
        check("encoder", i, ge[i], (loss(&up, &dec) - loss(&dn, &dec)) / (2.0 * f64::from(h)));
    }
    for i in 0..dec.len() {
        let (mut up, mut dn) = (dec.clone(), dec.clone());
        up[i] += h;
        dn[i] -= h;
        check("decoder", i, gd[i], (loss(&enc, &up) - loss(&enc, &dn)) / (2.0 * f64::from(h)));
    }
    eprintln!("largest relative difference from finite differences: {worst:.2e}");
}

#[test]
fn codes_are_unit_length_and_the_thesis_shape_builds() {
    let e = Embedding::new(EmbeddingConfig::default()).unwrap();
    let (mut enc, mut dec) = (vec![0.0; e.encoder_params()], vec![0.0; e.decoder_params()]);
    e.init(&mut enc, &mut dec, &mut rand::rng());
    let x: Vec<f32> = (0..2 * e.image_len()).map(|i| ((i % 97) as f32) / 97.0).collect();
    let mut w = EmbeddingWork::default();
    let z = e.encode(&enc, &x, 2, &mut w).to_vec();
    assert_eq!(z.len(), 40);
    for c in z.chunks_exact(20) {
        let n: f32 = c.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((n - 1.0).abs() < 1e-5, "code norm {n}");
    }
    assert_eq!(e.decode(&dec, &z, 2, &mut w).len(), 2 * 3 * 64 * 64);
}

/// The thesis-shaped embedding with bf16 products (issue 34): the codes of the same frames stay
/// within bf16's precision of the f32 codes (unit vectors: an absolute bound), and differ from
/// them where the CPU runs bf16 products at all.
#[test]
fn bf16_products_encode_the_same_frames_to_nearly_the_same_codes() {
    use coadapt_nn::Precision;
    let e = Embedding::new(EmbeddingConfig::default()).unwrap();
    let (mut enc, mut dec) = (vec![0.0; e.encoder_params()], vec![0.0; e.decoder_params()]);
    e.init(&mut enc, &mut dec, &mut rand::rng());
    let x: Vec<f32> = (0..4 * e.image_len()).map(|i| ((i % 97) as f32) / 97.0).collect();
    let mut w = EmbeddingWork::default();
    let z32 = e.encode(&enc, &x, 4, &mut w).to_vec();
    let e16 = e.clone().with_precision(Precision::Bf16);
    let z16 = e16.encode(&enc, &x, 4, &mut EmbeddingWork::default()).to_vec();
    let worst = z32.iter().zip(&z16).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    eprintln!("bf16 codes against f32: largest difference {worst:.2e}");
    assert!(worst < 2e-2, "codes differ by {worst}");
    if coadapt_nn::bf16::bf16_available() {
        assert!(worst > 0.0, "the bf16 products did not run");
    }
}
