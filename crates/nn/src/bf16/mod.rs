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

impl Precision {
    /// The config name: `f32` or `bf16`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
        }
    }
}

/// By config name (what command-line flags parse).
impl std::str::FromStr for Precision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f32" => Ok(Precision::F32),
            "bf16" => Ok(Precision::Bf16),
            _ => Err(format!("`{s}`: the precision is f32 or bf16")),
        }
    }
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

/// Packing f32 operands into bf16 pairs.
mod pack;
use pack::{grow, pack_a, pack_across, pack_contiguous, pack_pair_row, pair};
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
use pack::{pack_contiguous_ld, transpose_pairs};

/// The kernels' intrinsics (see the module for why they need `unsafe`).
#[cfg(target_arch = "x86_64")]
mod avx512;

/// Intel AMX: `tdpbf16ps` multiplies a 16 x 32 bf16 tile by a 32 x 16 one into a 16 x 16 f32
/// tile, 8,192 multiply-adds per instruction. Its operand layouts are the packed ones above: a
/// tile of A is 16 rows of 16 pairs, a tile of B 16 rows of pairs (the "VNNI" layout) of 16
/// columns. The instructions are written in inline assembly (Rust's AMX intrinsics are not
/// stable); Linux must first grant the process the tile state (`arch_prctl`).
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
pub(crate) mod amx;

#[cfg(test)]
mod tests;
