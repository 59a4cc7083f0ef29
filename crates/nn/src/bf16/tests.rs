#![allow(clippy::unwrap_used, clippy::expect_used)]
use super::*;
use rand::{Rng, SeedableRng};

fn random(n: usize, rng: &mut rand_pcg::Pcg64) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

/// f64 product of the bf16-rounded operands: what the kernel computes, but for the order of
/// its f32 sums.
fn reference(a: View<'_>, b: View<'_>) -> Vec<f64> {
    let r = |x: f32| f64::from(from_bf16(to_bf16(x)));
    let mut c = vec![0.0; a.rows * b.cols];
    for i in 0..a.rows {
        for j in 0..b.cols {
            c[i * b.cols + j] = (0..a.cols).map(|p| r(a.at(i, p)) * r(b.at(p, j))).sum();
        }
    }
    c
}

#[test]
fn rounding_matches_round_to_nearest_even() {
    assert_eq!(to_bf16(1.0), 0x3f80);
    // 1 + 2^-8 is halfway between 1 and 1 + 2^-7: ties to even (1.0).
    assert_eq!(to_bf16(1.0 + 1.0 / 256.0), 0x3f80);
    // 1 + 3 * 2^-8 is halfway between 1 + 2^-7 and 1 + 2^-6: ties to even (1 + 2^-6).
    assert_eq!(to_bf16(1.0 + 3.0 / 256.0), 0x3f82);
    assert_eq!(to_bf16(1.0 + 1.0 / 256.0 + 1.0 / 65536.0), 0x3f81);
    assert_eq!(from_bf16(to_bf16(-2.5)), -2.5);
    assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
    assert_eq!(from_bf16(to_bf16(f32::INFINITY)), f32::INFINITY);
}

/// Every tile shape and tail (rows 1-13, columns 1-70 across the 64-column tiles, odd and
/// even depths), with plain and transposed operands, replaced and accumulated.
#[test]
fn the_product_equals_the_rounded_operands_product_in_every_shape() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let mut scratch = Scratch::default();
    for &(m, k, n) in &[
        (1, 1, 1),
        (6, 2, 16),
        (7, 5, 17),
        (13, 33, 70),
        (12, 200, 64),
        (5, 64, 65),
        (256, 23, 200),
        (16, 32, 16),
        (47, 65, 33),
        (64, 200, 40),
        (40, 64, 200),
    ] {
        let a = random(m * k, &mut rng);
        let b = random(n * k, &mut rng);
        // Every layout a layer product uses: A rows contiguous (X, delta) or columns
        // (delta transposed); B columns contiguous (a weight transposed) or rows (W, X).
        for (a_t, b_t, accumulate) in
            [(false, true, false), (false, true, true), (false, false, false), (true, false, true), (true, true, false)]
        {
            let av = if a_t { View::row_major(&a, k, m).t() } else { View::row_major(&a, m, k) };
            let bv = if b_t { View::row_major(&b, n, k).t() } else { View::row_major(&b, k, n) };
            let want = reference(av, bv);
            // Every kernel the CPU has (AMX tiles from 16 x 32 x 16 up).
            for kernel in [Kernel::Best, Kernel::Vector, Kernel::Scalar] {
                let start = random(m * n, &mut rng);
                let mut c = start.clone();
                matmul_on(&mut c, accumulate, av, bv, &mut scratch, kernel);
                for (idx, (&got, &w)) in c.iter().zip(&want).enumerate() {
                    let w = if accumulate { w + f64::from(start[idx]) } else { w };
                    // f32 accumulation over k terms of size <= 1: a few ulps of k.
                    let tol = 1e-6 * (k as f64) + 1e-6 * w.abs();
                    assert!(
                        (f64::from(got) - w).abs() <= tol,
                        "{m}x{k}x{n} At {a_t} Bt {b_t} acc {accumulate} {kernel:?} at {idx}: {got} vs {w}"
                    );
                }
            }
        }
    }
}

/// The scalar path (CPUs without AVX-512 BF16) and the kernel agree on the same packing.
#[test]
fn the_scalar_path_and_the_kernel_agree() {
    if !bf16_available() {
        eprintln!("SKIPPED: no AVX-512 BF16 here; the scalar path is what the other tests ran");
        return;
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let (m, k, n) = (19, 47, 83);
    let a = random(m * k, &mut rng);
    let b = random(k * n, &mut rng);
    let mut scratch = Scratch::default();
    let mut fast = vec![0.0; m * n];
    matmul_on(&mut fast, false, View::row_major(&a, m, k), View::row_major(&b, k, n), &mut scratch, Kernel::Vector);
    let mut slow = vec![0.0; m * n];
    let kp = k.div_ceil(2);
    scalar_product(&mut slow, false, m, n, kp, n.div_ceil(16) * 16, &scratch.a, kp, 1, &scratch.b);
    for (x, y) in fast.iter().zip(&slow) {
        assert!((x - y).abs() <= 1e-5 * (1.0 + y.abs()), "{x} vs {y}");
    }
}

/// Against the f32 product of the unrounded operands the error is bf16's: each operand
/// rounded by at most 2^-9 relative, so a k-term dot product of values in [-1, 1] is off by
/// about sqrt(k) 2^-9 at the typical entry, never more than k 2^-8.
#[test]
fn the_error_against_f32_is_that_of_bf16_operands() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
    let (m, k, n) = (64, 200, 200);
    let a = random(m * k, &mut rng);
    let b = random(k * n, &mut rng);
    let mut c = vec![0.0; m * n];
    matmul(&mut c, false, View::row_major(&a, m, k), View::row_major(&b, k, n), &mut Scratch::default());
    let mut sq = 0.0f64;
    let mut worst = 0.0f64;
    for i in 0..m {
        for j in 0..n {
            let exact: f64 = (0..k).map(|p| f64::from(a[i * k + p]) * f64::from(b[p * n + j])).sum();
            let e = (f64::from(c[i * n + j]) - exact).abs();
            sq += e * e;
            worst = worst.max(e);
        }
    }
    let rms = (sq / (m * n) as f64).sqrt();
    let typical = (k as f64).sqrt() * 2f64.powi(-9);
    assert!(rms < typical, "rms error {rms} against sqrt(k) 2^-9 = {typical}");
    assert!(rms > typical / 100.0, "rms error {rms}: the operands were not rounded to bf16?");
    assert!(worst < k as f64 * 2f64.powi(-8), "worst error {worst}");
}

#[test]
fn a_product_with_b_packed_by_rows_is_the_same_product() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    for (m, k, n) in [(32, 27, 1024), (5, 7, 3), (19, 48, 33)] {
        let a = random(m * k, &mut rng);
        let b = random(k * n, &mut rng);
        let mut scratch = Scratch::default();
        let mut want = random(m * n, &mut rng);
        let mut got = want.clone();
        matmul(&mut want, true, View::row_major(&a, m, k), View::row_major(&b, k, n), &mut scratch);
        let mut packed = PackedB::default();
        packed.reset(k, n);
        for p in 0..k.div_ceil(2) {
            let hi = (2 * p + 1 < k).then(|| &b[(2 * p + 1) * n..(2 * p + 2) * n]);
            packed.set_pair_row(p, &b[2 * p * n..(2 * p + 1) * n], hi);
        }
        matmul_packed(&mut got, true, View::row_major(&a, m, k), &packed, &mut scratch);
        // Where AMX runs `matmul`, its sums come in another order.
        #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
        let amx = amx::available();
        #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
        let amx = false;
        for (x, y) in got.iter().zip(&want) {
            assert!(if amx { (x - y).abs() <= 1e-4 * (1.0 + y.abs()) } else { x == y }, "{m}x{k}x{n}: {x} vs {y}");
        }
    }
}

/// The config's names (serde), the flags' (`FromStr`) and what summaries print (`name()`) are
/// written in three places; they must stay one set of names.
#[test]
fn precision_names_agree_in_config_flags_and_summaries() {
    for p in [Precision::F32, Precision::Bf16] {
        assert_eq!(serde_json::to_string(&p).unwrap(), format!("\"{}\"", p.name()));
        assert_eq!(serde_json::from_str::<Precision>(&format!("\"{}\"", p.name())).unwrap(), p);
        assert_eq!(p.name().parse::<Precision>().unwrap(), p);
    }
    let err = "f16".parse::<Precision>().unwrap_err();
    assert!(err.contains("f16") && err.contains("f32 or bf16"), "{err}");
}
