//! SIMD helpers of the convolutions and the networks' element-wise passes: the stride-2
//! phases of an image (`deinterleave_lines`, `interleave_lines`), short copies, ReLU's backward
//! pass. Each is a safe function that runs AVX-512 code where the CPU has it and plain code
//! elsewhere (the same values). Written by hand where the compiler's own code was slow on AMD's
//! Zen 4: it emitted masked stores (`vmaskmovps`), which run at a fraction of a plain store's
//! rate there.

fn has_avx512f() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Line `l` of `lines` (`w` values from `src[l ss]`) split into its even values (written
/// to `dst` from `e0 + l ds` on) and its odd values (from `o0 + l ds` on): a stride-2
/// convolution's phases. AVX-512 shuffles where the CPU has them.
pub(crate) fn deinterleave_lines(src: &[f32], ss: usize, lines: usize, w: usize, dst: &mut [f32], place: (usize, usize, usize)) {
    #[cfg(target_arch = "x86_64")]
    if has_avx512f() {
        #[allow(unsafe_code)] // see the module avx512
        // SAFETY: the CPU has avx512f; the function asserts the lengths it relies on.
        unsafe {
            avx512::deinterleave_lines(src, ss, lines, w, dst, place)
        };
        return;
    }
    let (e0, o0, ds) = place;
    for l in 0..lines {
        for (x, v) in src[l * ss..l * ss + w].iter().enumerate() {
            dst[if x % 2 == 0 { e0 } else { o0 } + l * ds + x / 2] = *v;
        }
    }
}

/// The inverse of [`deinterleave_lines`]: line `l` (`w` values at `dst[l ds]`) from the even
/// values at `src[e0 + l ss]` and the odd at `src[o0 + l ss]`.
pub(crate) fn interleave_lines(src: &[f32], place: (usize, usize, usize), lines: usize, w: usize, dst: &mut [f32], ds: usize) {
    #[cfg(target_arch = "x86_64")]
    if has_avx512f() {
        #[allow(unsafe_code)] // see the module avx512
        // SAFETY: the CPU has avx512f; the function asserts the lengths it relies on.
        unsafe {
            avx512::interleave_lines(src, place, lines, w, dst, ds)
        };
        return;
    }
    let (e0, o0, ss) = place;
    for l in 0..lines {
        for (x, v) in dst[l * ds..l * ds + w].iter_mut().enumerate() {
            *v = src[if x % 2 == 0 { e0 } else { o0 } + l * ss + x / 2];
        }
    }
}

/// `d[i] = 0` where `h[i] <= 0` (ReLU's backward pass; a NaN `h` keeps its `d`; +0.0 where
/// zeroed). A blend and a plain store: written in Rust as a conditional store, a select or a bit
/// mask, it compiled to masked stores (`vmaskmovps`, `vpmaskmovd`), which AMD's Zen 4 runs so
/// slowly that the loop took 6 % of a SAC update; and, on a CPU without AVX-512 (AMD EPYC, Zen 3),
/// to a compare and a branch per value, which mispredicts on ReLU's half-random mask: 17 % of a
/// Hopper run's time (perf, 2026-12-02). Hence AVX-512 where the CPU has it, else AVX2.
pub fn relu_backward(d: &mut [f32], h: &[f32]) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if has_avx512f() {
        #[allow(unsafe_code)] // see the module avx512
        // SAFETY: the CPU has avx512f; the function stays inside both slices.
        {
            done = unsafe { avx512::relu_backward(d, h) };
        }
    }
    #[cfg(target_arch = "x86_64")]
    if done == 0 && std::arch::is_x86_feature_detected!("avx2") {
        #[allow(unsafe_code)] // see the module avx2
        // SAFETY: the CPU has avx2; the function stays inside both slices.
        {
            done = unsafe { avx2::relu_backward(d, h) };
        }
    }
    for (d, &h) in d.iter_mut().zip(h).skip(done) {
        if h <= 0.0 {
            *d = 0.0;
        }
    }
}

/// `dst.copy_from_slice(src)`, without a call into `memmove` for the short copies of im2col.
pub(crate) fn copy_short(src: &[f32], dst: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if has_avx512f() {
        #[allow(unsafe_code)] // see the module avx512
        // SAFETY: the CPU has avx512f; the function asserts equal lengths.
        unsafe {
            avx512::copy(src, dst)
        };
        return;
    }
    dst.copy_from_slice(src);
}

/// The AVX-512 intrinsics behind the helpers above. With `bf16/avx512.rs`, the workspace's only unsafe
/// code (see there).
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx512 {
    use std::arch::x86_64::*;

    /// Mask of the first `n` lanes (n <= 16).
    #[inline]
    fn lanes(n: usize) -> __mmask16 {
        if n >= 16 { 0xffff } else { ((1u32 << n) - 1) as __mmask16 }
    }

    /// Stores the first `n` lanes of `v` (n <= 16) at `p`. Whole vectors and halves without a
    /// mask: AMD's Zen 4 runs masked stores at a fraction of a plain store's rate (measured:
    /// the masked copies of im2col took 44 % of their function's time on one instruction).
    ///
    /// # Safety
    /// `p .. p + n` is writable.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn store_first(p: *mut f32, v: __m512, n: usize) {
        // SAFETY: each store writes exactly the first n values (the caller's range).
        unsafe {
            match n {
                16.. => _mm512_storeu_ps(p, v),
                8 => _mm256_storeu_ps(p, _mm512_castps512_ps256(v)),
                0 => {}
                _ => _mm512_mask_storeu_ps(p, lanes(n), v),
            }
        }
    }

    /// Line `l` of `lines` (`w` values from `src[l ss]`): its even values to `dst` from
    /// `e0 + l ds` on, its odd values from `o0 + l ds` on; the tails through masked loads.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn deinterleave_lines(
        src: &[f32],
        ss: usize,
        lines: usize,
        w: usize,
        dst: &mut [f32],
        (e0, o0, ds): (usize, usize, usize),
    ) {
        if lines == 0 || w == 0 {
            return;
        }
        assert!((lines - 1) * ss + w <= src.len(), "the source is shorter than its lines");
        assert!(e0.max(o0) + (lines - 1) * ds + w.div_ceil(2) <= dst.len(), "the lines are placed past the end");
        let ie = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let io = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
        for l in 0..lines {
            let mut x = 0;
            while x < w {
                let rest = w - x;
                // SAFETY: the loads read values x .. x + min(rest, 32) of line l (masked past
                // it); the stores write values x / 2 .. of the two halves, inside dst (asserted).
                unsafe {
                    let sp = src.as_ptr().add(l * ss + x);
                    let a = _mm512_maskz_loadu_ps(lanes(rest), sp);
                    let b = if rest > 16 { _mm512_maskz_loadu_ps(lanes(rest - 16), sp.add(16)) } else { _mm512_setzero_ps() };
                    let (ep, op) = (dst.as_mut_ptr().add(e0 + l * ds + x / 2), dst.as_mut_ptr().add(o0 + l * ds + x / 2));
                    store_first(ep, _mm512_permutex2var_ps(a, ie, b), rest.div_ceil(2).min(16));
                    store_first(op, _mm512_permutex2var_ps(a, io, b), (rest / 2).min(16));
                }
                x += 32;
            }
        }
    }

    /// The inverse of [`deinterleave_lines`]: line `l` (`w` values at `dst[l ds]`) from the
    /// even values at `src[e0 + l ss]` and the odd at `src[o0 + l ss]`.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn interleave_lines(
        src: &[f32],
        (e0, o0, ss): (usize, usize, usize),
        lines: usize,
        w: usize,
        dst: &mut [f32],
        ds: usize,
    ) {
        if lines == 0 || w == 0 {
            return;
        }
        assert!((lines - 1) * ds + w <= dst.len(), "the destination is shorter than its lines");
        assert!(e0.max(o0) + (lines - 1) * ss + w.div_ceil(2) <= src.len(), "the lines are placed past the end");
        let lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
        let hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
        for l in 0..lines {
            let mut x = 0;
            while x < w {
                let rest = w - x;
                // SAFETY: the mirror of deinterleave_lines: masked reads inside the two halves
                // (asserted), writes of values x .. x + min(rest, 32) of line l.
                unsafe {
                    let e = _mm512_maskz_loadu_ps(lanes(rest.div_ceil(2)), src.as_ptr().add(e0 + l * ss + x / 2));
                    let o = _mm512_maskz_loadu_ps(lanes(rest / 2), src.as_ptr().add(o0 + l * ss + x / 2));
                    let dp = dst.as_mut_ptr().add(l * ds + x);
                    store_first(dp, _mm512_permutex2var_ps(e, lo, o), rest.min(16));
                    if rest > 16 {
                        store_first(dp.add(16), _mm512_permutex2var_ps(e, hi, o), (rest - 16).min(16));
                    }
                }
                x += 32;
            }
        }
    }

    /// `d[i] = 0` where `h[i] <= 0` over whole blocks of 16 (a blend and a plain store);
    /// returns the values done.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn relu_backward(d: &mut [f32], h: &[f32]) -> usize {
        let blocks = d.len().min(h.len()) / 16;
        let zero = _mm512_setzero_ps();
        for q in 0..blocks {
            // SAFETY: values 16 q .. 16 q + 16 of both slices exist (blocks bounds both).
            unsafe {
                let hv = _mm512_loadu_ps(h.as_ptr().add(16 * q));
                // keep where !(h <= 0): a NaN h keeps its d, as the scalar loop.
                let keep = _mm512_cmp_ps_mask::<_CMP_NLE_UQ>(hv, zero);
                let dv = _mm512_loadu_ps(d.as_ptr().add(16 * q));
                _mm512_storeu_ps(d.as_mut_ptr().add(16 * q), _mm512_maskz_mov_ps(keep, dv));
            }
        }
        16 * blocks
    }

    /// `dst.copy_from_slice(src)` for short slices, 16 values at a time, the tail masked: no
    /// call into `memmove` (whose set-up cost dominated copies of 8-32 values).
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn copy(src: &[f32], dst: &mut [f32]) {
        assert_eq!(src.len(), dst.len(), "copy between slices of one length");
        let mut x = 0;
        while x < src.len() {
            let n = (src.len() - x).min(16);
            // SAFETY: the lanes loaded and stored stay inside both slices (equal lengths).
            unsafe { store_first(dst.as_mut_ptr().add(x), _mm512_maskz_loadu_ps(lanes(n), src.as_ptr().add(x)), n) };
            x += 16;
        }
    }
}

/// ReLU's backward pass with AVX2, for CPUs without AVX-512. The same safety rules as `avx512`.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx2 {
    use std::arch::x86_64::*;

    /// `d[i] = 0` where `h[i] <= 0` over whole blocks of 8 (a compare, an AND, a plain store);
    /// returns the values done.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn relu_backward(d: &mut [f32], h: &[f32]) -> usize {
        let blocks = d.len().min(h.len()) / 8;
        let zero = _mm256_setzero_ps();
        for q in 0..blocks {
            // SAFETY: values 8 q .. 8 q + 8 of both slices exist (blocks bounds both).
            unsafe {
                let hv = _mm256_loadu_ps(h.as_ptr().add(8 * q));
                // keep where !(h <= 0) (all ones), else +0.0: a NaN h keeps its d.
                let keep = _mm256_cmp_ps::<_CMP_NLE_UQ>(hv, zero);
                let dv = _mm256_loadu_ps(d.as_ptr().add(8 * q));
                _mm256_storeu_ps(d.as_mut_ptr().add(8 * q), _mm256_and_ps(keep, dv));
            }
        }
        8 * blocks
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stride_two_phases_split_and_rejoin_every_line_width() {
        for w in 1..=70usize {
            let lines = 3;
            let pw = w.div_ceil(2);
            let src: Vec<f32> = (0..lines * w).map(|i| i as f32 + 0.5).collect();
            let mut ph = vec![f32::NAN; lines * 2 * pw];
            let place = (0, pw, 2 * pw);
            deinterleave_lines(&src, w, lines, w, &mut ph, place);
            for l in 0..lines {
                for x in 0..w {
                    assert_eq!(ph[l * 2 * pw + x % 2 * pw + x / 2], src[l * w + x], "w {w} line {l} x {x}");
                }
            }
            let mut back = vec![f32::NAN; lines * w];
            interleave_lines(&ph, place, lines, w, &mut back, w);
            assert_eq!(back, src, "w {w}");
            let mut copied = vec![0.0; w];
            copy_short(&src[1..=w], &mut copied);
            assert_eq!(copied[..], src[1..=w], "w {w}");
        }
    }

    #[test]
    fn relu_backward_zeroes_exactly_where_the_output_was_not_positive() {
        for n in [0usize, 5, 8, 13, 16, 37] {
            let h: Vec<f32> = (0..n).map(|i| [1.0, 0.0, -0.0, -2.0, f32::NAN, 3e-38][i % 6]).collect();
            let mut d: Vec<f32> = (0..n).map(|i| i as f32 - 7.5).collect();
            let want: Vec<f32> = d.iter().zip(&h).map(|(&d, &h)| if h <= 0.0 { 0.0 } else { d }).collect();
            relu_backward(&mut d, &h);
            assert_eq!(d.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "n {n}");
        }
    }
}
