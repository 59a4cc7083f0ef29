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

mod grid;

use grid::{Grid, GridScratch, grow};

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
