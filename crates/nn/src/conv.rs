//! 2-D convolutions and their transposes over batches of images, by im2col and faer GEMM.
//!
//! Images are NCHW, row-major (`[n, c, h, w]`, each image contiguous), as PyTorch keeps them.
//! Parameters follow PyTorch's layouts so a PyTorch user loads them as they are:
//! [`Conv2d`]'s weight is `[c_out, c_in, k, k]` then its bias `[c_out]`; [`ConvTranspose2d`]'s
//! weight is `[c_in, c_out, k, k]` then its bias `[c_out]`.
//!
//! Both layers share one [`Grid`]: a "large" image (`c x h x w`, the convolution's input, the
//! transposed convolution's output) and the "small" grid of kernel positions on it (`oh x ow`).
//! `im2col` reads the large image into columns `[c k k, oh ow]`; `col2im` adds columns back
//! into a large image. A convolution is `W . im2col(x)`; its transpose is `col2im(W' . x)`, and
//! each one's backward pass is the other's forward. Per image one GEMM; the columns live in a
//! [`ConvScratch`] that grows to the largest shape seen, so warm passes do not allocate.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use crate::NnError;
use crate::bf16::{self, Precision, View};

/// The geometry shared by a convolution and its transpose (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Grid {
    /// Channels of the large image.
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub k: usize,
    pub stride: usize,
    pub pad: usize,
    /// Kernel positions (the small grid).
    pub oh: usize,
    pub ow: usize,
}

impl Grid {
    fn rows(&self) -> usize {
        self.c * self.k * self.k
    }

    fn cols(&self) -> usize {
        self.oh * self.ow
    }

    /// The kernel positions `o` (`0..n_out`) whose coordinate `o s + kk - pad` lies inside
    /// `0..n` (a line of width `w` for `kx`, a column of height `h` for `ky`): a range, found
    /// once per kernel offset so the inner loops need no bounds test.
    fn inside(&self, kk: usize, n: usize, n_out: usize) -> std::ops::Range<usize> {
        let (s, p) = (self.stride, self.pad);
        let lo = if kk >= p { 0 } else { (p - kk).div_ceil(s) };
        // x = o s + kk - p <= n - 1  <=>  o <= (n - 1 + p - kk) / s
        let hi = if n + p > kk { ((n - 1 + p - kk) / s + 1).min(n_out) } else { 0 };
        lo.min(hi)..hi
    }

    /// Sides of a phase plane: `(ceil(h / stride), ceil(w / stride))`.
    fn phase_sides(&self) -> (usize, usize) {
        (self.h.div_ceil(self.stride), self.w.div_ceil(self.stride))
    }

    /// Values between one channel's data and the next's: in the image (stride 1) or its
    /// phase planes.
    fn channel_len(&self) -> usize {
        if self.stride == 1 {
            self.h * self.w
        } else {
            let (ph_h, pw) = self.phase_sides();
            self.stride * self.stride * ph_h * pw
        }
    }

    /// Splits each channel of `img` (`c x h x w`) into its `stride^2` phase planes, plane
    /// `(ry, rx)` holding the pixels at `(y, x)` with `y mod s = ry`, `x mod s = rx`:
    /// `ph[(((ch s + ry) s + rx) ph_h + y / s) ph_w + x / s] = img[ch][y][x]`. A kernel offset
    /// then reads one plane with unit steps (most rows of the columns are a single copy of a
    /// plane), and each pixel is read once here instead of `k^2 / s^2` times strided.
    fn phases(&self, img: &[f32], ph: &mut Vec<f32>) {
        let (s, h, w) = (self.stride, self.h, self.w);
        let (ph_h, pw) = self.phase_sides();
        let plane = ph_h * pw;
        grow(ph, self.c * s * s * plane);
        if s == 2 {
            // Per channel and row parity: every other line of the image, the rows of a plane.
            for ch in 0..self.c {
                for ry in 0..2.min(h) {
                    let lines = (h - ry).div_ceil(2);
                    let (e0, o0) = (((ch * 2 + ry) * 2) * plane, ((ch * 2 + ry) * 2 + 1) * plane);
                    bf16::deinterleave_lines(&img[(ch * h + ry) * w..], 2 * w, lines, w, ph, (e0, o0, pw));
                }
            }
            return;
        }
        for (l, line) in img[..self.c * h * w].chunks_exact(w).enumerate() {
            let (ch, y) = (l / h, l % h);
            for (x, v) in line.iter().enumerate() {
                ph[(((ch * s + y % s) * s + x % s) * ph_h + y / s) * pw + x / s] = *v;
            }
        }
    }

    /// Writes the phase planes back into `img`: the inverse of [`Grid::phases`].
    fn unphases(&self, ph: &[f32], img: &mut [f32]) {
        let (s, h, w) = (self.stride, self.h, self.w);
        let (ph_h, pw) = self.phase_sides();
        let plane = ph_h * pw;
        if s == 2 {
            for ch in 0..self.c {
                for ry in 0..2.min(h) {
                    let lines = (h - ry).div_ceil(2);
                    let (e0, o0) = (((ch * 2 + ry) * 2) * plane, ((ch * 2 + ry) * 2 + 1) * plane);
                    bf16::interleave_lines(ph, (e0, o0, pw), lines, w, &mut img[(ch * h + ry) * w..], 2 * w);
                }
            }
            return;
        }
        for (l, line) in img[..self.c * h * w].chunks_exact_mut(w).enumerate() {
            let (ch, y) = (l / h, l % h);
            for (x, v) in line.iter_mut().enumerate() {
                *v = ph[(((ch * s + y % s) * s + x % s) * ph_h + y / s) * pw + x / s];
            }
        }
    }

    /// What kernel offset `(ky, kx)` of channel 0 reads: the kernel positions inside the
    /// image (rows `ys`, columns `xs`) and where the first of them is in `img` (stride 1) or
    /// its phase planes; position `(oy, ox)` of the ranges is at `base + (oy - ys.start) ls +
    /// (ox - xs.start)`, plus `ch` [`Grid::channel_len`] for channel `ch`. `None` when no
    /// position is inside.
    fn reach(&self, ky: usize, kx: usize) -> Option<Reach> {
        let (s, p) = (self.stride, self.pad);
        let (ys, xs) = (self.inside(ky, self.h, self.oh), self.inside(kx, self.w, self.ow));
        if ys.is_empty() || xs.is_empty() {
            return None;
        }
        let (y0, x0) = (ys.start * s + ky - p, xs.start * s + kx - p);
        let (base, ls) = if s == 1 {
            (y0 * self.w + x0, self.w)
        } else {
            let (ph_h, pw) = self.phase_sides();
            ((((y0 % s) * s + x0 % s) * ph_h + y0 / s) * pw + x0 / s, pw)
        };
        Some(Reach { ys, xs, base, ls })
    }

    /// Prepares `g` for one image: the reach of every kernel offset (the divisions, once),
    /// and at stride > 1 the phase planes of `img` when given.
    fn prepare(&self, img: Option<&[f32]>, g: &mut GridScratch) {
        g.reach.clear();
        for ky in 0..self.k {
            for kx in 0..self.k {
                g.reach.push(self.reach(ky, kx));
            }
        }
        if let (true, Some(img)) = (self.stride > 1, img) {
            self.phases(img, &mut g.planes);
        }
    }

    /// Row `(ch, kk)` (kernel offset `kk = ky k + kx`) of the columns, `oh ow` values, from
    /// `src` (the image at stride 1, else its phase planes); zero outside the image.
    fn im2col_row(&self, src: &[f32], reach: &Option<Reach>, ch: usize, row: &mut [f32]) {
        let ow = self.ow;
        let Some(Reach { ys, xs, base, ls }) = reach else {
            row.fill(0.0);
            return;
        };
        let base = base + ch * self.channel_len();
        let (first, last) = (ys.start * ow + xs.start, (ys.end - 1) * ow + xs.end);
        row[..first].fill(0.0);
        row[last..].fill(0.0);
        if *ls == ow {
            // The plane's lines are as long as the rows: one copy, then zeros where a line's
            // ends fell outside the image.
            row[first..last].copy_from_slice(&src[base..base + last - first]);
            if xs.len() < ow {
                for oy in ys.clone() {
                    let line = &mut row[oy * ow..(oy + 1) * ow];
                    line[..xs.start].fill(0.0);
                    line[xs.end..].fill(0.0);
                }
            }
            return;
        }
        for (i, oy) in ys.clone().enumerate() {
            let line = &mut row[oy * ow..(oy + 1) * ow];
            line[..xs.start].fill(0.0);
            line[xs.end..].fill(0.0);
            let at = base + i * ls;
            bf16::copy_short(&src[at..at + xs.len()], &mut line[xs.clone()]);
        }
    }

    /// Columns `[c k k, oh ow]` of the large image `img` (`c x h x w`); zero outside it.
    fn im2col(&self, img: &[f32], cols: &mut [f32], g: &mut GridScratch) {
        let (n, kk) = (self.cols(), self.k * self.k);
        self.prepare(Some(img), g);
        let src = if self.stride == 1 { img } else { &g.planes };
        for (r, row) in cols[..self.rows() * n].chunks_exact_mut(n).enumerate() {
            self.im2col_row(src, &g.reach[r % kk], r / kk, row);
        }
    }

    /// The columns of `img` straight into bf16 pairs (`b`, `[c k k] x [oh ow]`): each pair of
    /// rows goes through `two` (2 rows of f32, in L1) and is rounded at once.
    fn im2col_packed(&self, img: &[f32], g: &mut GridScratch, two: &mut Vec<f32>, b: &mut bf16::PackedB) {
        let (rows, n, kk) = (self.rows(), self.cols(), self.k * self.k);
        grow(two, 2 * n);
        b.reset(rows, n);
        self.prepare(Some(img), g);
        let src = if self.stride == 1 { img } else { &g.planes };
        let (lo, hi) = two[..2 * n].split_at_mut(n);
        for p in 0..rows.div_ceil(2) {
            let (r0, r1) = (2 * p, 2 * p + 1);
            self.im2col_row(src, &g.reach[r0 % kk], r0 / kk, lo);
            if r1 < rows {
                self.im2col_row(src, &g.reach[r1 % kk], r1 / kk, hi);
                b.set_pair_row(p, lo, Some(hi));
            } else {
                b.set_pair_row(p, lo, None);
            }
        }
    }

    /// Adds the columns `cols` (`[c k k, oh ow]`) into the large image `img` (`c x h x w`).
    /// At stride > 1 the sums run in the image's phase planes, which start as the image's
    /// values and take the columns in the same order as a direct scatter would, so every
    /// pixel's sum is the same, bit for bit.
    /// `fresh`: the image's values are ignored and it is written as the sum of the columns
    /// alone (the same bits as zeroing it first, without reading it).
    fn col2im(&self, cols: &[f32], img: &mut [f32], g: &mut GridScratch, fresh: bool) {
        let (n, ow, kk) = (self.cols(), self.ow, self.k * self.k);
        if fresh {
            if self.stride == 1 {
                img[..self.c * self.h * self.w].fill(0.0);
            } else {
                let (ph_h, pw) = self.phase_sides();
                grow(&mut g.planes, self.c * self.stride * self.stride * ph_h * pw);
                g.planes.fill(0.0);
            }
        }
        self.prepare(if fresh { None } else { Some(img) }, g);
        let GridScratch { planes, reach } = g;
        let dst: &mut [f32] = if self.stride == 1 { img } else { planes };
        for (r, row) in cols[..self.rows() * n].chunks_exact(n).enumerate() {
            let Some(Reach { ys, xs, base, ls }) = &reach[r % kk] else {
                continue;
            };
            let base = base + r / kk * self.channel_len();
            for (i, oy) in ys.clone().enumerate() {
                let vals = &row[oy * ow + xs.start..oy * ow + xs.end];
                let at = base + i * ls;
                for (d, v) in dst[at..at + vals.len()].iter_mut().zip(vals) {
                    *d += v;
                }
            }
        }
        if self.stride > 1 {
            self.unphases(planes, img);
        }
    }
}

/// The kernel positions a kernel offset reaches inside the image, and where they are read
/// (see [`Grid::reach`]).
#[derive(Clone, Debug)]
struct Reach {
    ys: std::ops::Range<usize>,
    xs: std::ops::Range<usize>,
    base: usize,
    ls: usize,
}

/// A [`Grid`]'s scratch for one image: its phase planes and the reach of each kernel offset.
#[derive(Clone, Debug, Default)]
struct GridScratch {
    planes: Vec<f32>,
    reach: Vec<Option<Reach>>,
}

fn grow(v: &mut Vec<f32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
    }
}

/// Scratch of the convolutions' passes: one image's columns and the bf16 products' packing.
/// Reused across calls.
#[derive(Clone, Debug, Default)]
pub struct ConvScratch {
    cols: Vec<f32>,
    /// The stride phases of one image and the kernel offsets' reach.
    grid: GridScratch,
    packed: bf16::Scratch,
    /// Two rows of columns and the columns as bf16 pairs (the bf16 forward pass).
    two: Vec<f32>,
    packed_cols: bf16::PackedB,
    /// A weight gradient's transpose, accumulated over a batch (see `WeightGrad`).
    gt: Vec<f32>,
}

impl ConvScratch {
    /// The columns (`len` values), the phases' scratch and the packing buffers, at once.
    fn split(&mut self, len: usize) -> (&mut [f32], &mut GridScratch, &mut bf16::Scratch) {
        grow(&mut self.cols, len);
        (&mut self.cols[..len], &mut self.grid, &mut self.packed)
    }
}

/// A row-major `rows x cols` matrix.
fn rm(data: &[f32], rows: usize, cols: usize) -> View<'_> {
    View::row_major(&data[..rows * cols], rows, cols)
}

/// `c = a b` (`accumulate`: `c += a b`), `c` row-major `a.rows x b.cols`: bf16 operands with
/// f32 accumulation where `precision` asks for them and [`bf16::runs_in_bf16`] admits the
/// shape, else faer's f32 product (the same calls, so the same bits, as before precision
/// existed). `a` and `b` are row-major or the transpose of a row-major matrix.
fn product(c: &mut [f32], accumulate: bool, a: View<'_>, b: View<'_>, precision: Precision, packed: &mut bf16::Scratch) {
    if precision == Precision::Bf16 && bf16::runs_in_bf16(a.rows, a.cols, b.cols) {
        bf16::matmul(c, accumulate, a, b, packed);
        return;
    }
    let cm = MatMut::from_row_major_slice_mut(c, a.rows, b.cols);
    let accum = if accumulate { Accum::Add } else { Accum::Replace };
    matmul(cm, accum, mat(a), mat(b), 1.0f32, Par::Seq);
}

fn mat(v: View<'_>) -> MatRef<'_, f32> {
    if v.cs == 1 {
        MatRef::from_row_major_slice(v.data, v.rows, v.cols)
    } else {
        debug_assert_eq!(v.rs, 1, "a transposed row-major view");
        MatRef::from_row_major_slice(v.data, v.cols, v.rows).transpose()
    }
}

fn check(c_in: usize, c_out: usize, k: usize, stride: usize, h: usize, w: usize) -> Result<(), NnError> {
    let sizes = vec![c_in, c_out, k, stride, h, w];
    if sizes.contains(&0) {
        return Err(NnError::Shape { sizes, why: "channels, kernel, stride and image sides must be positive" });
    }
    Ok(())
}

/// `torch.nn.Conv2d(c_in, c_out, k, stride, pad)` on `c_in x h x w` images.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Conv2d {
    pub c_in: usize,
    pub c_out: usize,
    grid: Grid,
    precision: Precision,
}

impl Conv2d {
    pub fn new(c_in: usize, c_out: usize, k: usize, stride: usize, pad: usize, h: usize, w: usize) -> Result<Self, NnError> {
        check(c_in, c_out, k, stride, h, w)?;
        if h + 2 * pad < k || w + 2 * pad < k {
            return Err(NnError::Shape { sizes: vec![h, w, k, pad], why: "the kernel is larger than the padded image" });
        }
        let (oh, ow) = ((h + 2 * pad - k) / stride + 1, (w + 2 * pad - k) / stride + 1);
        Ok(Self { c_in, c_out, grid: Grid { c: c_in, h, w, k, stride, pad, oh, ow }, precision: Precision::F32 })
    }

    /// The products' arithmetic (f32 by default): under [`Precision::Bf16`] every product of
    /// the forward and backward passes whose shape [`bf16::runs_in_bf16`] admits takes bf16
    /// operands with f32 accumulation; im2col, biases and sums stay f32.
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// The output's `(channels, height, width)`.
    pub fn out_shape(&self) -> (usize, usize, usize) {
        (self.c_out, self.grid.oh, self.grid.ow)
    }

    pub fn in_len(&self) -> usize {
        self.c_in * self.grid.h * self.grid.w
    }

    pub fn out_len(&self) -> usize {
        self.c_out * self.grid.oh * self.grid.ow
    }

    pub fn n_params(&self) -> usize {
        self.c_out * self.grid.rows() + self.c_out
    }

    /// Multiply-adds per image of a forward pass.
    pub fn macs(&self) -> usize {
        self.c_out * self.grid.rows() * self.grid.cols()
    }

    /// `out = conv(x)` for `n` images (`x`: `n x in_len`, `out`: `n x out_len`).
    pub fn forward(&self, params: &[f32], x: &[f32], n: usize, out: &mut [f32], s: &mut ConvScratch) {
        let (g, rows, cols) = (&self.grid, self.grid.rows(), self.grid.cols());
        assert_eq!(params.len(), self.n_params(), "parameter buffer length");
        assert!(x.len() >= n * self.in_len() && out.len() >= n * self.out_len(), "buffers shorter than n images");
        let (wt, bias) = params.split_at(self.c_out * rows);
        let w = rm(wt, self.c_out, rows);
        if self.precision == Precision::Bf16 && bf16::runs_in_bf16(self.c_out, rows, cols) {
            // The columns go straight into bf16 pairs: no f32 matrix of columns.
            for i in 0..n {
                let ConvScratch { grid, packed, two, packed_cols, .. } = &mut *s;
                g.im2col_packed(&x[i * self.in_len()..(i + 1) * self.in_len()], grid, two, packed_cols);
                let o = &mut out[i * self.out_len()..(i + 1) * self.out_len()];
                for (plane, b) in o.chunks_exact_mut(cols).zip(bias) {
                    plane.fill(*b);
                }
                bf16::matmul_packed(o, true, w, packed_cols, packed);
            }
            return;
        }
        for i in 0..n {
            let (c, ph, packed) = s.split(rows * cols);
            g.im2col(&x[i * self.in_len()..(i + 1) * self.in_len()], c, ph);
            let o = &mut out[i * self.out_len()..(i + 1) * self.out_len()];
            for (plane, b) in o.chunks_exact_mut(cols).zip(bias) {
                plane.fill(*b);
            }
            product(o, true, w, rm(c, rows, cols), self.precision, packed);
        }
    }

    /// Backward of [`Conv2d::forward`] on the same `x`: `dy` is dL/d(out). Adds dL/d(params)
    /// into `grad` (so batches can be accumulated; zero it first for one batch) and writes
    /// dL/dx into `dx` when given.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        n: usize,
        dy: &[f32],
        grad: Option<&mut [f32]>,
        dx: Option<&mut [f32]>,
        s: &mut ConvScratch,
    ) {
        let (g, rows, cols) = (&self.grid, self.grid.rows(), self.grid.cols());
        assert!(dy.len() >= n * self.out_len(), "dy shorter than n images");
        let w = rm(params, self.c_out, rows);
        if let Some(grad) = grad {
            let (gw, gb) = grad.split_at_mut(self.c_out * rows);
            let mut gt = WeightGrad::start(self.precision, self.c_out, rows, cols, &mut s.gt);
            for i in 0..n {
                let d = &dy[i * self.out_len()..(i + 1) * self.out_len()];
                let (c, ph, packed) = s.split(rows * cols);
                g.im2col(&x[i * self.in_len()..(i + 1) * self.in_len()], c, ph);
                // dW += dy . cols'
                gt.add(gw, rm(d, self.c_out, cols), rm(c, rows, cols), self.precision, packed);
                for (b, plane) in gb.iter_mut().zip(d.chunks_exact(cols)) {
                    *b += plane.iter().sum::<f32>();
                }
            }
            gt.finish(gw, &mut s.gt);
        }
        if let Some(dx) = dx {
            for i in 0..n {
                let d = &dy[i * self.out_len()..(i + 1) * self.out_len()];
                let (c, ph, packed) = s.split(rows * cols);
                // dcols = W' . dy, then back into the image.
                product(c, false, w.t(), rm(d, self.c_out, cols), self.precision, packed);
                let di = &mut dx[i * self.in_len()..(i + 1) * self.in_len()];
                g.col2im(c, di, ph, true);
            }
        }
    }
}

/// `torch.nn.ConvTranspose2d(c_in, c_out, k, stride, pad, output_padding)` on `c_in x h x w`
/// images: the output is `c_out x ((h-1) s - 2 pad + k + output_padding)` and likewise wide.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConvTranspose2d {
    pub c_in: usize,
    pub c_out: usize,
    grid: Grid,
    precision: Precision,
}

impl ConvTranspose2d {
    pub fn new(
        c_in: usize,
        c_out: usize,
        k: usize,
        stride: usize,
        pad: usize,
        output_padding: usize,
        h: usize,
        w: usize,
    ) -> Result<Self, NnError> {
        check(c_in, c_out, k, stride, h, w)?;
        if output_padding >= stride {
            return Err(NnError::Shape { sizes: vec![output_padding, stride], why: "output padding must be smaller than the stride" });
        }
        let big = |n: usize| ((n - 1) * stride + k + output_padding).checked_sub(2 * pad);
        let (Some(bh), Some(bw)) = (big(h), big(w)) else {
            return Err(NnError::Shape { sizes: vec![h, w, k, stride, pad], why: "the padding removes the whole output" });
        };
        Ok(Self { c_in, c_out, grid: Grid { c: c_out, h: bh, w: bw, k, stride, pad, oh: h, ow: w }, precision: Precision::F32 })
    }

    /// The products' arithmetic, as [`Conv2d::with_precision`].
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// The output's `(channels, height, width)`.
    pub fn out_shape(&self) -> (usize, usize, usize) {
        (self.c_out, self.grid.h, self.grid.w)
    }

    pub fn in_len(&self) -> usize {
        self.c_in * self.grid.oh * self.grid.ow
    }

    pub fn out_len(&self) -> usize {
        self.c_out * self.grid.h * self.grid.w
    }

    pub fn n_params(&self) -> usize {
        self.c_in * self.grid.rows() + self.c_out
    }

    /// Multiply-adds per image of a forward pass.
    pub fn macs(&self) -> usize {
        self.c_in * self.grid.rows() * self.grid.cols()
    }

    /// `out = conv_transpose(x)` for `n` images.
    pub fn forward(&self, params: &[f32], x: &[f32], n: usize, out: &mut [f32], s: &mut ConvScratch) {
        let (g, rows, cols) = (&self.grid, self.grid.rows(), self.grid.cols());
        assert_eq!(params.len(), self.n_params(), "parameter buffer length");
        assert!(x.len() >= n * self.in_len() && out.len() >= n * self.out_len(), "buffers shorter than n images");
        let w = rm(params, self.c_in, rows);
        let bias = &params[self.c_in * rows..];
        let plane = g.h * g.w;
        for i in 0..n {
            let (c, ph, packed) = s.split(rows * cols);
            // cols = W' . x: every input pixel spread over its kernel's reach.
            let xi = rm(&x[i * self.in_len()..], self.c_in, cols);
            product(c, false, w.t(), xi, self.precision, packed);
            let o = &mut out[i * self.out_len()..(i + 1) * self.out_len()];
            for (p, b) in o.chunks_exact_mut(plane).zip(bias) {
                p.fill(*b);
            }
            g.col2im(c, o, ph, false);
        }
    }

    /// Backward of [`ConvTranspose2d::forward`] on the same `x` (see [`Conv2d::backward`]).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        n: usize,
        dy: &[f32],
        grad: Option<&mut [f32]>,
        dx: Option<&mut [f32]>,
        s: &mut ConvScratch,
    ) {
        let (g, rows, cols) = (&self.grid, self.grid.rows(), self.grid.cols());
        assert!(dy.len() >= n * self.out_len(), "dy shorter than n images");
        let w = rm(params, self.c_in, rows);
        let plane = g.h * g.w;
        let mut grad = grad;
        let mut dx = dx;
        let mut gt = WeightGrad::start(self.precision, self.c_in, rows, cols, &mut s.gt);
        for i in 0..n {
            let d = &dy[i * self.out_len()..(i + 1) * self.out_len()];
            let (c, ph, packed) = s.split(rows * cols);
            g.im2col(d, c, ph);
            let xi = rm(&x[i * self.in_len()..], self.c_in, cols);
            if let Some(grad) = grad.as_deref_mut() {
                let (gw, gb) = grad.split_at_mut(self.c_in * rows);
                // dW += x . im2col(dy)'
                gt.add(gw, xi, rm(c, rows, cols), self.precision, packed);
                for (b, p) in gb.iter_mut().zip(d.chunks_exact(plane)) {
                    *b += p.iter().sum::<f32>();
                }
            }
            if let Some(dx) = dx.as_deref_mut() {
                // dx = W . im2col(dy)
                let di = &mut dx[i * self.in_len()..(i + 1) * self.in_len()];
                product(di, false, w, rm(c, rows, cols), self.precision, packed);
            }
        }
        if let Some(grad) = grad {
            gt.finish(&mut grad[..self.c_in * rows], &mut s.gt);
        }
    }
}

/// A weight gradient `gw` (`m x rows`) accumulated as `gw += a . c'` image by image (`a`:
/// `m x cols`, `c`: the image's columns, `rows x cols`). In f32, faer's product straight into
/// `gw` (the bits of every archived run). In bf16 the transposed product `c . a'` accumulates
/// into a `rows x m` buffer that is added into `gw` once per batch: packing `c'` for the
/// kernel would transpose the whole columns matrix pair by pair for every image, packing `c`
/// reads it as it lies.
struct WeightGrad {
    transposed: Option<(usize, usize)>,
    buf: Vec<f32>,
}

impl WeightGrad {
    /// Takes the buffer out of `keep` (given back by [`WeightGrad::finish`]).
    fn start(precision: Precision, m: usize, rows: usize, cols: usize, keep: &mut Vec<f32>) -> Self {
        let mut buf = std::mem::take(keep);
        let transposed = (precision == Precision::Bf16 && bf16::runs_in_bf16(rows, cols, m)).then_some((m, rows));
        if transposed.is_some() {
            buf.clear();
            buf.resize(rows * m, 0.0);
        }
        Self { transposed, buf }
    }

    fn add(&mut self, gw: &mut [f32], a: View<'_>, c: View<'_>, precision: Precision, packed: &mut bf16::Scratch) {
        match self.transposed {
            Some(_) => bf16::matmul(&mut self.buf, true, c, a.t(), packed),
            None => product(gw, true, a, c.t(), precision, packed),
        }
    }

    /// Adds what was accumulated into `gw` and gives the buffer back to `keep`.
    fn finish(self, gw: &mut [f32], keep: &mut Vec<f32>) {
        if let Some((m, rows)) = self.transposed {
            for (r, line) in self.buf.chunks_exact(m).enumerate() {
                for (i, v) in line.iter().enumerate() {
                    gw[i * rows + r] += v;
                }
            }
        }
        *keep = self.buf;
    }
}

#[cfg(test)]
mod tests {
    use super::Grid;

    /// The definition, one bounds test per value: what `im2col` and `col2im` must equal.
    fn naive(g: &Grid, img: &[f32], cols: &mut [f32], back: &mut [f32]) {
        let (k, s, p) = (g.k, g.stride, g.pad as isize);
        let n = g.oh * g.ow;
        for ch in 0..g.c {
            for ky in 0..k {
                for kx in 0..k {
                    for oy in 0..g.oh {
                        for ox in 0..g.ow {
                            let (y, x) = ((oy * s + ky) as isize - p, (ox * s + kx) as isize - p);
                            let i = ((ch * k + ky) * k + kx) * n + oy * g.ow + ox;
                            let inside = y >= 0 && y < g.h as isize && x >= 0 && x < g.w as isize;
                            let at = ch * g.h * g.w + (y.max(0) as usize) * g.w + x.max(0) as usize;
                            cols[i] = if inside { img[at] } else { 0.0 };
                            if inside {
                                back[at] += (i % 7) as f32 - 3.0;
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn im2col_and_col2im_equal_the_definition_for_every_geometry() {
        let mut cases = 0;
        for (h, w) in [(1, 1), (5, 7), (8, 8), (9, 4)] {
            for k in 1..=5 {
                for stride in 1..=3 {
                    for pad in 0..=3 {
                        if h + 2 * pad < k || w + 2 * pad < k {
                            continue;
                        }
                        let (oh, ow) = ((h + 2 * pad - k) / stride + 1, (w + 2 * pad - k) / stride + 1);
                        let g = Grid { c: 2, h, w, k, stride, pad, oh, ow };
                        let img: Vec<f32> = (0..2 * h * w).map(|i| i as f32 + 1.0).collect();
                        let len = g.rows() * g.cols();
                        let (mut want, mut got) = (vec![f32::NAN; len], vec![f32::NAN; len]);
                        let (mut want_back, mut got_back) = (vec![0.5; img.len()], vec![0.5; img.len()]);
                        naive(&g, &img, &mut want, &mut want_back);
                        let mut ph = super::GridScratch { planes: vec![f32::NAN; 3], reach: Vec::new() };
                        g.im2col(&img, &mut got, &mut ph);
                        assert_eq!(got, want, "im2col {g:?}");
                        let grads: Vec<f32> = (0..len).map(|i| (i % 7) as f32 - 3.0).collect();
                        g.col2im(&grads, &mut got_back, &mut ph, false);
                        let mut fresh = vec![f32::NAN; img.len()];
                        g.col2im(&grads, &mut fresh, &mut ph, true);
                        let from_zero: Vec<f32> = want_back.iter().map(|v| v - 0.5).collect();
                        // the sums started at 0.5 above; from zero they are exact small integers
                        assert_eq!(fresh, from_zero, "col2im into a fresh image {g:?}");
                        assert_eq!(got_back, want_back, "col2im {g:?}");
                        cases += 1;
                    }
                }
            }
        }
        assert!(cases > 150, "{cases} geometries");
    }
}
