//! The bf16 kernel's intrinsics. With `simd.rs`'s intrinsics, the workspace's only unsafe code
//! (`unsafe_code` is denied everywhere else): SIMD intrinsics under `target_feature` need it,
//! for their raw-pointer loads and stores and for the calls into functions compiled for
//! features the caller has only checked at run time.
#![allow(unsafe_code)]

use std::arch::x86_64::*;

/// Rows of `A` per micro-tile.
const MR: usize = 6;
/// 16-lane vectors of `B` per micro-tile (64 columns): 6 x 4 accumulators, 4 loads and a
/// broadcast, 29 of the 32 registers.
const NV: usize = 4;

#[target_feature(enable = "avx512f,avx512bf16")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn product(
    c: &mut [f32],
    accumulate: bool,
    m: usize,
    n: usize,
    kp: usize,
    n16: usize,
    a: &[u32],
    a_rs: usize,
    a_ps: usize,
    b: &[u32],
) {
    let mut j0 = 0;
    while j0 < n {
        let cols = (n - j0).min(16 * NV);
        let nv = cols.div_ceil(16);
        let mut i0 = 0;
        while i0 < m {
            let rows = (m - i0).min(MR);
            // SAFETY: rows x cols of C at (i0, j0) and the packed panels they read are in
            // bounds: i0 + rows <= m, j0 + 16 nv <= n16, and C's row stride is n.
            unsafe {
                let ap = a.as_ptr().add(i0 * a_rs);
                let bp = b.as_ptr().add(j0);
                let cp = c.as_mut_ptr().add(i0 * n + j0);
                macro_rules! tile {
                    ($r:literal, $v:literal) => {
                        micro::<$r, $v>(kp, ap, a_rs, a_ps, bp, n16, cp, n, cols, accumulate)
                    };
                }
                match (rows, nv) {
                    (6, 4) => tile!(6, 4),
                    (6, 3) => tile!(6, 3),
                    (6, 2) => tile!(6, 2),
                    (6, 1) => tile!(6, 1),
                    (5, 4) => tile!(5, 4),
                    (5, 3) => tile!(5, 3),
                    (5, 2) => tile!(5, 2),
                    (5, 1) => tile!(5, 1),
                    (4, 4) => tile!(4, 4),
                    (4, 3) => tile!(4, 3),
                    (4, 2) => tile!(4, 2),
                    (4, 1) => tile!(4, 1),
                    (3, 4) => tile!(3, 4),
                    (3, 3) => tile!(3, 3),
                    (3, 2) => tile!(3, 2),
                    (3, 1) => tile!(3, 1),
                    (2, 4) => tile!(2, 4),
                    (2, 3) => tile!(2, 3),
                    (2, 2) => tile!(2, 2),
                    (2, 1) => tile!(2, 1),
                    (1, 4) => tile!(1, 4),
                    (1, 3) => tile!(1, 3),
                    (1, 2) => tile!(1, 2),
                    _ => tile!(1, 1),
                }
            }
            i0 += rows;
        }
        j0 += cols;
    }
}

/// Converts `src` into pairs, 32 values at a time (`vcvtne2ps2bf16`, round to nearest
/// even), the tail through masked loads; returns the pairs written (all of them).
#[target_feature(enable = "avx512f,avx512bf16")]
pub(super) unsafe fn pack_contiguous(src: &[f32], dst: &mut [u32]) -> usize {
    let blocks = src.len() / 32;
    for q in 0..blocks {
        // SAFETY: values 32 q .. 32 q + 32 of src and pairs 16 q .. 16 q + 16 of dst exist
        // (dst holds ceil(len / 2) pairs).
        unsafe {
            let v0 = _mm512_loadu_ps(src.as_ptr().add(32 * q));
            let v1 = _mm512_loadu_ps(src.as_ptr().add(32 * q + 16));
            let h = _mm512_cvtne2ps_pbh(v1, v0);
            _mm512_storeu_si512(dst.as_mut_ptr().add(16 * q).cast(), std::mem::transmute::<__m512bh, __m512i>(h));
        }
    }
    let rest = src.len() - 32 * blocks;
    if rest > 0 {
        // The tail through masked loads (zeros past the end: an odd k's last pair gets a
        // zero high half, as the scalar packing gives it) and a masked store of its pairs.
        let m0: __mmask16 = if rest >= 16 { 0xffff } else { (1u16 << rest) - 1 };
        let m1: __mmask16 = if rest > 16 { (1u16 << (rest - 16)) - 1 } else { 0 };
        let pairs = rest.div_ceil(2);
        let mp: __mmask16 = if pairs == 16 { 0xffff } else { (1u16 << pairs) - 1 };
        // SAFETY: the masks keep the loads within src's last `rest` values and the store
        // within dst's last `pairs` pairs (dst holds ceil(len / 2)).
        unsafe {
            let v0 = _mm512_maskz_loadu_ps(m0, src.as_ptr().add(32 * blocks));
            let v1 = _mm512_maskz_loadu_ps(m1, src.as_ptr().add(32 * blocks + 16));
            let h = _mm512_cvtne2ps_pbh(v1, v0);
            _mm512_mask_storeu_epi32(dst.as_mut_ptr().add(16 * blocks).cast(), mp, std::mem::transmute::<__m512bh, __m512i>(h));
        }
    }
    src.len().div_ceil(2)
}

/// Pairs (lo[j], hi[j]) for every j; returns how many were written (all of them).
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
pub(super) unsafe fn pack_across(lo: &[f32], hi: Option<&[f32]>, dst: &mut [u32]) -> usize {
    // 16-bit lane 2t takes lo's t-th value (lane t of the conversion), lane 2t + 1 hi's
    // (lane 16 + t).
    let idx = _mm512_set_epi16(
        31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1, 16, 0,
    );
    let blocks = lo.len() / 16;
    for q in 0..blocks {
        // SAFETY: lo, hi and dst have at least 16 (q + 1) values.
        unsafe {
            let l = _mm512_loadu_ps(lo.as_ptr().add(16 * q));
            let h = match hi {
                Some(hi) => _mm512_loadu_ps(hi.as_ptr().add(16 * q)),
                None => _mm512_setzero_ps(),
            };
            let both = std::mem::transmute::<__m512bh, __m512i>(_mm512_cvtne2ps_pbh(h, l));
            _mm512_storeu_si512(dst.as_mut_ptr().add(16 * q).cast(), _mm512_permutexvar_epi16(idx, both));
        }
    }
    let rest = lo.len() - 16 * blocks;
    if rest > 0 {
        let mask: __mmask16 = (1u16 << rest) - 1;
        // SAFETY: the mask keeps every load and the store within the last `rest` values.
        unsafe {
            let l = _mm512_maskz_loadu_ps(mask, lo.as_ptr().add(16 * blocks));
            let h = match hi {
                Some(hi) => _mm512_maskz_loadu_ps(mask, hi.as_ptr().add(16 * blocks)),
                None => _mm512_setzero_ps(),
            };
            let both = std::mem::transmute::<__m512bh, __m512i>(_mm512_cvtne2ps_pbh(h, l));
            _mm512_mask_storeu_epi32(dst.as_mut_ptr().add(16 * blocks).cast(), mask, _mm512_permutexvar_epi16(idx, both));
        }
    }
    lo.len()
}

/// One `R x 16V` tile of C: `cols` (<= 16 V) of its columns are real, the rest padding.
#[target_feature(enable = "avx512f,avx512bf16")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn micro<const R: usize, const V: usize>(
    kp: usize,
    a: *const u32,
    a_rs: usize,
    a_ps: usize,
    b: *const u32,
    ldb: usize,
    c: *mut f32,
    ldc: usize,
    cols: usize,
    accumulate: bool,
) {
    let mut acc = [[_mm512_setzero_ps(); V]; R];
    for p in 0..kp {
        let mut bv = [_mm512_setzero_si512(); V];
        for (v, x) in bv.iter_mut().enumerate() {
            // SAFETY: row p of the packed B panel has 16 V lanes from here (n16 padding).
            *x = unsafe { _mm512_loadu_si512(b.add(p * ldb + 16 * v).cast()) };
        }
        for (r, row) in acc.iter_mut().enumerate() {
            // SAFETY: row r of the packed A has kp pairs.
            let ar = _mm512_set1_epi32(unsafe { *a.add(r * a_rs + p * a_ps) } as i32);
            for (v, x) in row.iter_mut().enumerate() {
                // SAFETY: both are 512 plain bits; __m512bh only renames them as 32 bf16.
                let (av, bw) = unsafe { (std::mem::transmute::<__m512i, __m512bh>(ar), std::mem::transmute::<__m512i, __m512bh>(bv[v])) };
                *x = _mm512_dpbf16_ps(*x, av, bw);
            }
        }
    }
    for (r, row) in acc.iter().enumerate() {
        for (v, x) in row.iter().enumerate() {
            let left = cols.saturating_sub(16 * v).min(16);
            let mask: __mmask16 = if left == 16 { 0xffff } else { (1u16 << left) - 1 };
            // SAFETY: the mask keeps the store within the tile's real columns.
            unsafe {
                let dst = c.add(r * ldc + 16 * v);
                let out = if accumulate { _mm512_add_ps(_mm512_maskz_loadu_ps(mask, dst), *x) } else { *x };
                _mm512_mask_storeu_ps(dst, mask, out);
            }
        }
    }
}
