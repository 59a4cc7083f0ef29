//! Packing f32 operands into the kernels' bf16 pairs (the layout in the parent module's doc):
//! rows of pairs, pairs across rows, and the blocked transpose between them.

#[cfg(target_arch = "x86_64")]
use super::avx512;
use super::{Scratch, View, to_bf16};

#[inline]
pub(super) fn pair(lo: f32, hi: f32) -> u32 {
    u32::from(to_bf16(lo)) | (u32::from(to_bf16(hi)) << 16)
}

/// Packs `lines` lines of `k` values, each contiguous from `data[l * ls]`, as `lines x kp`
/// pairs.
pub(super) fn pack_contiguous(data: &[f32], lines: usize, ls: usize, k: usize, out: &mut [u32], simd: bool) {
    let kp = k.div_ceil(2);
    for l in 0..lines {
        let src = &data[l * ls..l * ls + k];
        let dst = &mut out[l * kp..(l + 1) * kp];
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if simd {
            #[allow(unsafe_code)] // see the module avx512
            // SAFETY: the CPU has the kernel's features (`simd` is bf16_available()); src has k
            // values and dst k / 2 pairs, of which the function writes whole 32-value blocks.
            {
                done = unsafe { avx512::pack_contiguous(src, dst) };
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = simd;
        for (p, w) in dst.iter_mut().enumerate().skip(done) {
            let hi = if 2 * p + 1 < k { src[2 * p + 1] } else { 0.0 };
            *w = pair(src[2 * p], hi);
        }
    }
}

/// Packs pairs across lines: pair p of element j is `(row 2p, row 2p + 1)` at column j, each
/// row `len` values contiguous from `data[r * rs]`; out is `kp x ld` (ld >= len).
#[allow(clippy::too_many_arguments)] // the source and destination shapes, spelled out
pub(super) fn pack_across(data: &[f32], k: usize, rs: usize, len: usize, out: &mut [u32], ld: usize, simd: bool) {
    for p in 0..k.div_ceil(2) {
        let lo = &data[2 * p * rs..2 * p * rs + len];
        let hi = (2 * p + 1 < k).then(|| &data[(2 * p + 1) * rs..(2 * p + 1) * rs + len]);
        pack_pair_row(lo, hi, &mut out[p * ld..p * ld + len], simd);
    }
}

/// `dst[j] = (lo[j], hi[j])` as a pair (`hi` absent: zero).
pub(super) fn pack_pair_row(lo: &[f32], hi: Option<&[f32]>, dst: &mut [u32], simd: bool) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if simd {
        #[allow(unsafe_code)] // see the module avx512
        // SAFETY: the kernel's features are there; lo, hi and dst have len values each.
        {
            done = unsafe { avx512::pack_across(lo, hi, dst) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = simd;
    for j in done..dst.len() {
        dst[j] = pair(lo[j], hi.map_or(0.0, |h| h[j]));
    }
}

/// Makes `v` at least `len` long, keeping what it holds (the callers overwrite what they read).
pub(super) fn grow(v: &mut Vec<u32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0);
    }
}

/// `dst[c * ld + r] = src[r * cols + c]` for a `rows x cols` matrix of pairs, in 16 x 16
/// blocks so that the block's reads and writes both stay in L1 (the plain loop's writes, one
/// per cache line, ran at a fifth of this speed on the forward pass's `W^T`).
pub(super) fn transpose_pairs(src: &[u32], rows: usize, cols: usize, dst: &mut [u32], ld: usize) {
    const B: usize = 16;
    for r0 in (0..rows).step_by(B) {
        let r1 = (r0 + B).min(rows);
        for c0 in (0..cols).step_by(B) {
            let c1 = (c0 + B).min(cols);
            for c in c0..c1 {
                let out = &mut dst[c * ld + r0..c * ld + r1];
                for (o, r) in out.iter_mut().zip(r0..r1) {
                    *o = src[r * cols + c];
                }
            }
        }
    }
}

/// Packs `A` into `scratch.a` as pairs, rows along m: `[m][kp]` (returns `(kp, 1)`, the
/// strides of a row and of a pair) or `[kp][m]` (`(1, m)`).
pub(super) fn pack_a(a: View<'_>, scratch: &mut Scratch, simd: bool) -> (usize, usize) {
    let (m, k) = (a.rows, a.cols);
    let kp = k.div_ceil(2);
    // A as pairs, rows along m: [m][kp] (a_rs = kp, a_ps = 1) or [kp][m] (a_rs = 1, a_ps = m).
    grow(&mut scratch.a, m * kp);
    if a.cs == 1 {
        pack_contiguous(a.data, m, a.rs, k, &mut scratch.a, simd);
        (kp, 1)
    } else if a.rs == 1 {
        pack_across(a.data, k, a.cs, m, &mut scratch.a, m, simd);
        (1, m)
    } else {
        for i in 0..m {
            for p in 0..kp {
                let hi = if 2 * p + 1 < k { a.at(i, 2 * p + 1) } else { 0.0 };
                scratch.a[i * kp + p] = pair(a.at(i, 2 * p), hi);
            }
        }
        (kp, 1)
    }
}

/// [`pack_contiguous`] into rows of `ld` pairs (zero padding after the `ceil(k / 2)` real ones).
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
pub(super) fn pack_contiguous_ld(data: &[f32], lines: usize, ls: usize, k: usize, out: &mut [u32], ld: usize) {
    let kp = k.div_ceil(2);
    for l in 0..lines {
        pack_contiguous(&data[l * ls..l * ls + k], 1, k, k, &mut out[l * ld..l * ld + kp], true);
    }
}
