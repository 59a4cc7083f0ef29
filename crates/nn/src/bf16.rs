//! Matrix products in bfloat16 with f32 accumulation (issue 34): `C = A B` (or `C += A B`)
//! with `A`, `B` and `C` in f32, the operands rounded to bfloat16 (round to nearest even) as
//! they are packed, every product accumulated in f32. On x86-64 with AVX-512 BF16 the inner
//! loop is `vdpbf16ps`: 32 multiply-adds per instruction against the 16 of an f32 FMA.
//!
//! Why our own kernel: faer and the `gemm` crates it uses have f32, f64 and f16 products but no
//! bf16; `gemmkit` (0.1) has a `vdpbf16ps` kernel but stores `C` in bf16, and the networks
//! keep activations and gradients in f32 (only the products' operands are rounded).
//!
//! Layout of the packed operands (what `vdpbf16ps` multiplies lane by lane): each 32-bit lane
//! holds a pair of consecutive-k values, the even one in the low half. `A` is packed row by row
//! as `m x ceil(k/2)` pairs; `B` as `ceil(k/2) x n16` pairs (n rounded up to 16, zero
//! padding), so that lane j of a 512-bit load holds `(B[2p][j], B[2p+1][j])`. A broadcast pair
//! of `A` times that load adds `A[i][2p] B[2p][j] + A[i][2p+1] B[2p+1][j]` into lane j.

/// Which arithmetic the products use (`f32` or `bf16` in a config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// f32 products (faer), on every CPU.
    #[default]
    F32,
    /// bf16 products with f32 accumulation where [`runs_in_bf16`] says so, f32 elsewhere.
    Bf16,
}

/// Whether this CPU runs the bf16 kernel (AVX-512F, BW and BF16), detected at run time.
pub fn bf16_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// What [`Precision::Bf16`] products run on, on this CPU: `"amx+avx512-bf16"` (AMX tiles for
/// the products that fill them, AVX-512 BF16 for the rest), `"avx512-bf16"`, or `"f32"`
/// (neither: f32 products, the same bits as [`Precision::F32`]). Run summaries record it.
pub fn bf16_kernel() -> &'static str {
    if !bf16_available() {
        return "f32";
    }
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    if amx::available() {
        return "amx+avx512-bf16";
    }
    "avx512-bf16"
}

/// Whether an `m x k` by `k x n` product runs in bf16 under [`Precision::Bf16`]: on AMX tiles
/// when the CPU has them and the product fills at least one (16 x 32 x 16); with AVX-512 BF16
/// alone, always (its `vdpbf16ps` doubles the f32 rate on the AMD cores issue 34 measured; on
/// Intel cores with AMX it runs at the f32 rate, so there small products stay f32). Else never.
pub fn runs_in_bf16(m: usize, k: usize, n: usize) -> bool {
    if !bf16_available() {
        return false;
    }
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    if amx::available() {
        return m >= 16 && n >= 16 && k >= 32;
    }
    let _ = (m, k, n);
    true
}

/// f32 to bfloat16 bits, rounding to nearest even (as `vcvtneps2bf16` and PyTorch do); NaN
/// stays a (quiet) NaN.
#[inline]
pub fn to_bf16(x: f32) -> u16 {
    let b = x.to_bits();
    if x.is_nan() {
        return ((b >> 16) | 0x40) as u16;
    }
    let round = 0x7fff + ((b >> 16) & 1);
    (b.wrapping_add(round) >> 16) as u16
}

/// bfloat16 bits back to f32 (exact).
#[inline]
pub fn from_bf16(h: u16) -> f32 {
    f32::from_bits(u32::from(h) << 16)
}

/// A strided read-only view of an f32 matrix: element (i, j) at `i * rs + j * cs`.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    pub data: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub rs: usize,
    pub cs: usize,
}

impl<'a> View<'a> {
    /// A row-major `rows x cols` matrix.
    pub fn row_major(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self { data, rows, cols, rs: cols, cs: 1 }
    }

    /// The transpose (no copy).
    pub fn t(self) -> Self {
        Self { data: self.data, rows: self.cols, cols: self.rows, rs: self.cs, cs: self.rs }
    }

    #[inline]
    fn at(&self, i: usize, j: usize) -> f32 {
        self.data[i * self.rs + j * self.cs]
    }
}

/// Packing buffers, kept between calls so that a product allocates nothing once warm.
#[derive(Debug, Default, Clone)]
pub struct Scratch {
    a: Vec<u32>,
    b: Vec<u32>,
    t: Vec<u32>,
}

#[inline]
fn pair(lo: f32, hi: f32) -> u32 {
    u32::from(to_bf16(lo)) | (u32::from(to_bf16(hi)) << 16)
}

/// Packs `lines` lines of `k` values, each contiguous from `data[l * ls]`, as `lines x kp`
/// pairs.
fn pack_contiguous(data: &[f32], lines: usize, ls: usize, k: usize, out: &mut [u32], simd: bool) {
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
fn pack_across(data: &[f32], k: usize, rs: usize, len: usize, out: &mut [u32], ld: usize, simd: bool) {
    for p in 0..k.div_ceil(2) {
        let lo = &data[2 * p * rs..2 * p * rs + len];
        let hi = (2 * p + 1 < k).then(|| &data[(2 * p + 1) * rs..(2 * p + 1) * rs + len]);
        pack_pair_row(lo, hi, &mut out[p * ld..p * ld + len], simd);
    }
}

/// `dst[j] = (lo[j], hi[j])` as a pair (`hi` absent: zero).
fn pack_pair_row(lo: &[f32], hi: Option<&[f32]>, dst: &mut [u32], simd: bool) {
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

/// A `k x n` right-hand operand packed by its owner, pair row by pair row, in the layout the
/// kernel reads (see the module doc): for a product whose `B` is built on the fly (a
/// convolution's columns), so that each pair of rows goes from a small f32 buffer still in L1
/// straight into bf16, instead of through a whole f32 matrix and a second pass.
#[derive(Debug, Default, Clone)]
pub struct PackedB {
    k: usize,
    n: usize,
    n16: usize,
    pairs: Vec<u32>,
}

impl PackedB {
    /// Room for a `k x n` matrix; every pair row `0..ceil(k/2)` must be set before a product.
    pub fn reset(&mut self, k: usize, n: usize) {
        self.k = k;
        self.n = n;
        self.n16 = n.div_ceil(16) * 16;
        grow(&mut self.pairs, k.div_ceil(2) * self.n16);
    }

    /// Sets pair row `p` from rows `2p` (`lo`) and `2p + 1` (`hi`; `None` for the last row of
    /// an odd `k`), each `n` values, rounded to bf16.
    ///
    /// # Panics
    /// On a row past `ceil(k/2)` or rows of the wrong length.
    pub fn set_pair_row(&mut self, p: usize, lo: &[f32], hi: Option<&[f32]>) {
        assert!(p < self.k.div_ceil(2), "pair row {p} of a {}-row matrix", self.k);
        assert!(lo.len() == self.n && hi.is_none_or(|h| h.len() == self.n), "rows of {} values", self.n);
        pack_pair_row(lo, hi, &mut self.pairs[p * self.n16..p * self.n16 + self.n], bf16_available());
    }
}

/// [`matmul`] with `B` packed by the caller: `C = A B` (`accumulate`: `C += A B`), bf16
/// operands, f32 accumulation, on the AVX-512 BF16 kernel (also where AMX exists: the tiles
/// want another layout) or in scalar code.
///
/// # Panics
/// On mismatched shapes.
pub fn matmul_packed(c: &mut [f32], accumulate: bool, a: View<'_>, b: &PackedB, scratch: &mut Scratch) {
    let (m, k, n) = (a.rows, a.cols, b.n);
    assert_eq!(b.k, k, "inner dimensions");
    assert_eq!(c.len(), m * n, "C is m x n");
    check_view(&a, "A");
    if m == 0 || n == 0 {
        return;
    }
    let simd = bf16_available();
    let (a_rs, a_ps) = pack_a(a, scratch, simd);
    let kp = k.div_ceil(2);
    #[cfg(target_arch = "x86_64")]
    if simd {
        #[allow(unsafe_code)] // the intrinsics' kernel: see the module avx512
        // SAFETY: the CPU has avx512f and avx512bf16; the packed A has m x kp pairs at strides
        // (a_rs, a_ps), B kp x n16 (reset sized it), and C is m x n (asserted).
        unsafe {
            avx512::product(c, accumulate, m, n, kp, b.n16, &scratch.a, a_rs, a_ps, &b.pairs)
        };
        return;
    }
    scalar_product(c, accumulate, m, n, kp, b.n16, &scratch.a, a_rs, a_ps, &b.pairs);
}

/// Makes `v` at least `len` long, keeping what it holds (the callers overwrite what they read).
fn grow(v: &mut Vec<u32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0);
    }
}

/// `dst[c * ld + r] = src[r * cols + c]` for a `rows x cols` matrix of pairs, in 16 x 16
/// blocks so that the block's reads and writes both stay in L1 (the plain loop's writes, one
/// per cache line, ran at a fifth of this speed on the forward pass's `W^T`).
fn transpose_pairs(src: &[u32], rows: usize, cols: usize, dst: &mut [u32], ld: usize) {
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

fn check_view(v: &View<'_>, what: &str) {
    if v.rows > 0 && v.cols > 0 {
        let last = (v.rows - 1) * v.rs + (v.cols - 1) * v.cs;
        assert!(
            last < v.data.len(),
            "{what}: a {}x{} view with strides ({}, {}) reads past its {} values",
            v.rows,
            v.cols,
            v.rs,
            v.cs,
            v.data.len()
        );
    }
}

/// `C = A B` (`accumulate`: `C += A B`) with bf16 operands and f32 accumulation; `C` is
/// row-major `a.rows x b.cols`. Runs the AVX-512 BF16 kernel where the CPU has it, else the
/// same arithmetic in scalar code (the reference the kernel is tested against). Packing is
/// fastest when an operand is contiguous along either of its dimensions (every layer product
/// of [`crate::Mlp`] is).
///
/// # Panics
/// On mismatched shapes or a `C` of the wrong length: the callers size them.
pub fn matmul(c: &mut [f32], accumulate: bool, a: View<'_>, b: View<'_>, scratch: &mut Scratch) {
    matmul_on(c, accumulate, a, b, scratch, Kernel::Best);
}

/// Which kernel [`matmul_on`] may use: tests run each one the CPU has.
#[cfg_attr(not(test), allow(dead_code))] // only the tests ask for less than the best
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kernel {
    /// AMX tiles where available, else AVX-512 BF16, else scalar.
    Best,
    /// AVX-512 BF16 where available, else scalar.
    Vector,
    /// Scalar code only.
    Scalar,
}

/// [`matmul`] with the kernels `kernel` allows.
fn matmul_on(c: &mut [f32], accumulate: bool, a: View<'_>, b: View<'_>, scratch: &mut Scratch, kernel: Kernel) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    assert_eq!(b.rows, k, "inner dimensions");
    assert_eq!(c.len(), m * n, "C is m x n");
    check_view(&a, "A");
    check_view(&b, "B");
    if m == 0 || n == 0 {
        return;
    }
    let simd = kernel != Kernel::Scalar && bf16_available();
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    if kernel == Kernel::Best && simd && amx::available() && m >= 16 && n >= 16 && k >= 32 {
        amx_matmul(c, accumulate, a, b, scratch);
        return;
    }
    let kp = k.div_ceil(2);
    let n16 = n.div_ceil(16) * 16;
    // Every packed value the kernel reads is written below (B's padding columns are read but
    // land only in masked-off lanes), so the buffers only grow: no zeroing per call.
    let (a_rs, a_ps) = pack_a(a, scratch, simd);
    // B as pairs, [kp][n16] with zero padding.
    grow(&mut scratch.b, kp * n16);
    if b.cs == 1 {
        pack_across(b.data, k, b.rs, n, &mut scratch.b, n16, simd);
    } else if b.rs == 1 {
        // Columns contiguous along k (a layer's weight seen transposed): pack them as lines,
        // then transpose the pairs.
        grow(&mut scratch.t, n * kp);
        pack_contiguous(b.data, n, b.cs, k, &mut scratch.t, simd);
        transpose_pairs(&scratch.t, n, kp, &mut scratch.b, n16);
    } else {
        for p in 0..kp {
            for j in 0..n {
                let hi = if 2 * p + 1 < k { b.at(2 * p + 1, j) } else { 0.0 };
                scratch.b[p * n16 + j] = pair(b.at(2 * p, j), hi);
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    if simd {
        #[allow(unsafe_code)] // the intrinsics' kernel: see the module avx512
        // SAFETY: the CPU has avx512f and avx512bf16 (checked above); the packed A has m x kp
        // pairs at strides (a_rs, a_ps), the packed B kp x n16, and C is m x n (asserted).
        unsafe {
            avx512::product(c, accumulate, m, n, kp, n16, &scratch.a, a_rs, a_ps, &scratch.b)
        };
        return;
    }
    scalar_product(c, accumulate, m, n, kp, n16, &scratch.a, a_rs, a_ps, &scratch.b);
}

/// Packs `A` into `scratch.a` as pairs, rows along m: `[m][kp]` (returns `(kp, 1)`, the
/// strides of a row and of a pair) or `[kp][m]` (`(1, m)`).
fn pack_a(a: View<'_>, scratch: &mut Scratch, simd: bool) -> (usize, usize) {
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

/// The product on AMX tiles: A packed as `m32 x kp16` pairs, B as `kp16 x n32`, zero-padded.
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn amx_matmul(c: &mut [f32], accumulate: bool, a: View<'_>, b: View<'_>, scratch: &mut Scratch) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    let kp16 = k.div_ceil(32) * 16;
    let m32 = m.div_ceil(32) * 32;
    let n32 = n.div_ceil(32) * 32;
    // Row strides off powers of two: tile loads of 16 rows 512 or 1024 bytes apart fall into
    // the same cache sets (measured: 256 x 256 x 256 at half the speed of 200 x 256 x 200).
    let lda = if kp16 % 64 == 0 { kp16 + 16 } else { kp16 };
    let ldb = if n32 % 128 == 0 { n32 + 32 } else { n32 };
    scratch.a.clear();
    scratch.a.resize(m32 * lda, 0);
    if a.cs == 1 {
        pack_contiguous_ld(a.data, m, a.rs, k, &mut scratch.a, lda);
    } else {
        // Pairs across A's rows come out as [kp][m]: transpose them to rows of pairs.
        let kp = k.div_ceil(2);
        scratch.t.clear();
        scratch.t.resize(kp * m, 0);
        if a.rs == 1 {
            pack_across(a.data, k, a.cs, m, &mut scratch.t, m, true);
        } else {
            for p in 0..kp {
                for i in 0..m {
                    let hi = if 2 * p + 1 < k { a.at(i, 2 * p + 1) } else { 0.0 };
                    scratch.t[p * m + i] = pair(a.at(i, 2 * p), hi);
                }
            }
        }
        transpose_pairs(&scratch.t, kp, m, &mut scratch.a, lda);
    }
    scratch.b.clear();
    scratch.b.resize(kp16 * ldb, 0);
    if b.cs == 1 {
        pack_across(b.data, k, b.rs, n, &mut scratch.b, ldb, true);
    } else {
        let kp = k.div_ceil(2);
        scratch.t.clear();
        scratch.t.resize(n * kp, 0);
        if b.rs == 1 {
            pack_contiguous(b.data, n, b.cs, k, &mut scratch.t, true);
        } else {
            for j in 0..n {
                for p in 0..kp {
                    let hi = if 2 * p + 1 < k { b.at(2 * p + 1, j) } else { 0.0 };
                    scratch.t[j * kp + p] = pair(b.at(2 * p, j), hi);
                }
            }
        }
        transpose_pairs(&scratch.t, n, kp, &mut scratch.b, ldb);
    }
    #[allow(unsafe_code)] // see the module amx
    // SAFETY: AMX is available (the caller checked); A is m32 x kp16, B kp16 x n32, C m x n.
    unsafe {
        amx::product(c, accumulate, m, n, kp16, lda, ldb, &scratch.a, &scratch.b)
    };
}

/// [`pack_contiguous`] into rows of `ld` pairs (zero padding after the `ceil(k / 2)` real ones).
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn pack_contiguous_ld(data: &[f32], lines: usize, ls: usize, k: usize, out: &mut [u32], ld: usize) {
    let kp = k.div_ceil(2);
    for l in 0..lines {
        pack_contiguous(&data[l * ls..l * ls + k], 1, k, k, &mut out[l * ld..l * ld + kp], true);
    }
}

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
/// slowly that the loop took 6 % of a SAC update.
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

/// The packed product in scalar code: the same pairs, each pair's two products summed first
/// and then added, as `vdpbf16ps` does per lane (the order of the f32 sums may differ).
#[allow(clippy::too_many_arguments)] // the packed shapes, spelled out
fn scalar_product(
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
    for i in 0..m {
        for j in 0..n {
            let mut s = 0.0f32;
            for p in 0..kp {
                let (x, y) = (a[i * a_rs + p * a_ps], b[p * n16 + j]);
                s += from_bf16(x as u16) * from_bf16(y as u16) + from_bf16((x >> 16) as u16) * from_bf16((y >> 16) as u16);
            }
            let out = &mut c[i * n + j];
            *out = if accumulate { *out + s } else { s };
        }
    }
}

/// The workspace's only unsafe code (`unsafe_code` is denied everywhere else): SIMD
/// intrinsics under `target_feature` need it, for their raw-pointer loads and stores and for the
/// calls into functions compiled for features the caller has only checked at run time.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx512 {
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
                    let (av, bw) =
                        unsafe { (std::mem::transmute::<__m512i, __m512bh>(ar), std::mem::transmute::<__m512i, __m512bh>(bv[v])) };
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
}

/// Intel AMX: `tdpbf16ps` multiplies a 16 x 32 bf16 tile by a 32 x 16 one into a 16 x 16 f32
/// tile, 8,192 multiply-adds per instruction. Its operand layouts are the packed ones above: a
/// tile of A is 16 rows of 16 pairs, a tile of B 16 rows of pairs (the "VNNI" layout) of 16
/// columns. The instructions are written in inline assembly (Rust's AMX intrinsics are not
/// stable); Linux must first grant the process the tile state (`arch_prctl`).
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
#[allow(unsafe_code)]
pub(crate) mod amx {
    use std::arch::asm;
    use std::arch::x86_64::__cpuid_count;
    use std::sync::OnceLock;

    /// AMX-TILE and AMX-BF16 in CPUID, and Linux's permission for the tile data granted.
    pub(crate) fn available() -> bool {
        static OK: OnceLock<bool> = OnceLock::new();
        *OK.get_or_init(|| {
            // CPUID leaf 7, subleaf 0, EDX: bit 22 AMX-BF16, bit 24 AMX-TILE.
            let edx = __cpuid_count(7, 0).edx;
            if edx & (1 << 22) == 0 || edx & (1 << 24) == 0 {
                return false;
            }
            let ret: i64;
            // SAFETY: arch_prctl(ARCH_REQ_XCOMP_PERM = 0x1023, XFEATURE_XTILEDATA = 18) only
            // asks the kernel to allow the tile state in this process; it touches no memory.
            unsafe {
                asm!("syscall", inlateout("rax") 158i64 => ret, in("rdi") 0x1023i64, in("rsi") 18i64,
                     lateout("rcx") _, lateout("r11") _, options(nostack));
            }
            ret == 0
        })
    }

    /// The tile configuration: palette 1; tmm0-3 the 2 x 2 tiles of C (16 rows of 16 f32),
    /// tmm4-5 two tiles of A and tmm6-7 two of B (16 rows of 64 bytes each).
    #[repr(C, align(64))]
    struct Config([u8; 64]);

    fn config() -> Config {
        let mut c = [0u8; 64];
        c[0] = 1;
        for t in 0..8 {
            c[16 + 2 * t..18 + 2 * t].copy_from_slice(&64u16.to_le_bytes());
            c[48 + t] = 16;
        }
        Config(c)
    }

    /// C (m x n, row-major) = or += A B from packed A (`m32` rows of `kp16` pairs, row stride
    /// lda) and packed B (`kp16` rows of `n32` pairs, stride ldb), zero-padded to whole tiles.
    ///
    /// # Safety
    /// `available()` is true; the packed buffers have the sizes above; `c` is m x n.
    #[allow(clippy::too_many_arguments)]
    pub(crate) unsafe fn product(
        c: &mut [f32],
        accumulate: bool,
        m: usize,
        n: usize,
        kp16: usize,
        lda: usize,
        ldb: usize,
        a: &[u32],
        b: &[u32],
    ) {
        let cfg = config();
        let mut out = [0f32; 32 * 32];
        let (sa, sb, so) = (4 * lda, 4 * ldb, 4 * 32usize);
        // SAFETY: loads the configuration above (valid for palette 1).
        unsafe { asm!("ldtilecfg [{}]", in(reg) cfg.0.as_ptr(), options(nostack)) };
        for i0 in (0..m).step_by(32) {
            for j0 in (0..n).step_by(32) {
                // SAFETY: every tile load reads 16 rows of 64 bytes inside the padded buffers
                // (rows i0..i0 + 32 < m32 of A, pair rows < kp16 of B, columns j0..j0 + 32 <= n32);
                // the stores write the 32 x 32 f32 of `out`.
                unsafe {
                    asm!("tilezero tmm0", "tilezero tmm1", "tilezero tmm2", "tilezero tmm3", options(nostack));
                    for q in (0..kp16).step_by(16) {
                        let a0 = a.as_ptr().add(i0 * lda + q);
                        let a1 = a.as_ptr().add((i0 + 16) * lda + q);
                        let b0 = b.as_ptr().add(q * ldb + j0);
                        let b1 = b.as_ptr().add(q * ldb + j0 + 16);
                        asm!(
                            "tileloadd tmm4, [{a0} + {sa} * 1]",
                            "tileloadd tmm5, [{a1} + {sa} * 1]",
                            "tileloadd tmm6, [{b0} + {sb} * 1]",
                            "tileloadd tmm7, [{b1} + {sb} * 1]",
                            "tdpbf16ps tmm0, tmm4, tmm6",
                            "tdpbf16ps tmm1, tmm4, tmm7",
                            "tdpbf16ps tmm2, tmm5, tmm6",
                            "tdpbf16ps tmm3, tmm5, tmm7",
                            a0 = in(reg) a0, a1 = in(reg) a1, b0 = in(reg) b0, b1 = in(reg) b1,
                            sa = in(reg) sa, sb = in(reg) sb, options(nostack, readonly),
                        );
                    }
                    let o = out.as_mut_ptr();
                    asm!(
                        "tilestored [{o0} + {so} * 1], tmm0",
                        "tilestored [{o1} + {so} * 1], tmm1",
                        "tilestored [{o2} + {so} * 1], tmm2",
                        "tilestored [{o3} + {so} * 1], tmm3",
                        o0 = in(reg) o, o1 = in(reg) o.add(16), o2 = in(reg) o.add(16 * 32), o3 = in(reg) o.add(16 * 32 + 16),
                        so = in(reg) so, options(nostack),
                    );
                }
                for r in 0..32.min(m - i0) {
                    let cols = 32.min(n - j0);
                    let dst = &mut c[(i0 + r) * n + j0..(i0 + r) * n + j0 + cols];
                    let src = &out[r * 32..r * 32 + cols];
                    if accumulate {
                        dst.iter_mut().zip(src).for_each(|(d, s)| *d += s);
                    } else {
                        dst.copy_from_slice(src);
                    }
                }
            }
        }
        // SAFETY: releases the tile state this function configured.
        unsafe { asm!("tilerelease", options(nostack)) };
    }
}

#[cfg(test)]
mod tests {
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
        for n in [0usize, 5, 16, 37] {
            let h: Vec<f32> = (0..n).map(|i| [1.0, 0.0, -0.0, -2.0, f32::NAN, 3e-38][i % 6]).collect();
            let mut d: Vec<f32> = (0..n).map(|i| i as f32 - 7.5).collect();
            let want: Vec<f32> = d.iter().zip(&h).map(|(&d, &h)| if h <= 0.0 { 0.0 } else { d }).collect();
            relu_backward(&mut d, &h);
            assert_eq!(d.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "n {n}");
        }
    }
}
