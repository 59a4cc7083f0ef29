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

    /// The kernel positions `ox` whose column `ox s + kx - pad` lies inside a line of width
    /// `self.w`: a range, found once per `kx` so the inner loops need no bounds test.
    fn inside(&self, kx: usize) -> std::ops::Range<usize> {
        let (s, p) = (self.stride, self.pad);
        let lo = if kx >= p { 0 } else { (p - kx).div_ceil(s) };
        // x = ox s + kx - p <= w - 1  <=>  ox <= (w - 1 + p - kx) / s
        let hi = if self.w + p > kx { ((self.w - 1 + p - kx) / s + 1).min(self.ow) } else { 0 };
        lo.min(hi)..hi
    }

    /// Columns `[c k k, oh ow]` of the large image `img` (`c x h x w`); zero outside it.
    fn im2col(&self, img: &[f32], cols: &mut [f32]) {
        let (k, s, p) = (self.k, self.stride, self.pad as isize);
        let n = self.cols();
        for ch in 0..self.c {
            let plane = &img[ch * self.h * self.w..(ch + 1) * self.h * self.w];
            for ky in 0..k {
                for kx in 0..k {
                    let row = &mut cols[((ch * k + ky) * k + kx) * n..][..n];
                    let inside = self.inside(kx);
                    // the first column read: ox = inside.start, x = ox s + kx - p >= 0
                    let x0 = (inside.start * s + kx) as isize - p;
                    for oy in 0..self.oh {
                        let y = (oy * s + ky) as isize - p;
                        let out = &mut row[oy * self.ow..(oy + 1) * self.ow];
                        if y < 0 || y >= self.h as isize || inside.is_empty() {
                            out.fill(0.0);
                            continue;
                        }
                        let line = &plane[y as usize * self.w..(y as usize + 1) * self.w];
                        out[..inside.start].fill(0.0);
                        out[inside.end..].fill(0.0);
                        let out = &mut out[inside.clone()];
                        let src = &line[x0 as usize..];
                        if s == 1 {
                            out.copy_from_slice(&src[..out.len()]);
                        } else {
                            for (o, v) in out.iter_mut().zip(src.iter().step_by(s)) {
                                *o = *v;
                            }
                        }
                    }
                }
            }
        }
    }

    /// Adds the columns `cols` (`[c k k, oh ow]`) into the large image `img` (`c x h x w`).
    fn col2im(&self, cols: &[f32], img: &mut [f32]) {
        let (k, s, p) = (self.k, self.stride, self.pad as isize);
        let n = self.cols();
        for ch in 0..self.c {
            let plane = &mut img[ch * self.h * self.w..(ch + 1) * self.h * self.w];
            for ky in 0..k {
                for kx in 0..k {
                    let row = &cols[((ch * k + ky) * k + kx) * n..][..n];
                    let inside = self.inside(kx);
                    if inside.is_empty() {
                        continue;
                    }
                    let x0 = (inside.start * s + kx) as isize - p;
                    for oy in 0..self.oh {
                        let y = (oy * s + ky) as isize - p;
                        if y < 0 || y >= self.h as isize {
                            continue;
                        }
                        let line = &mut plane[y as usize * self.w..(y as usize + 1) * self.w];
                        let vals = &row[oy * self.ow..(oy + 1) * self.ow][inside.clone()];
                        let dst = &mut line[x0 as usize..];
                        if s == 1 {
                            for (d, v) in dst.iter_mut().zip(vals) {
                                *d += v;
                            }
                        } else {
                            for (d, v) in dst.iter_mut().step_by(s).zip(vals) {
                                *d += v;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Scratch of the convolutions' passes: one image's columns. Reused across calls.
#[derive(Clone, Debug, Default)]
pub struct ConvScratch {
    cols: Vec<f32>,
}

impl ConvScratch {
    fn cols(&mut self, len: usize) -> &mut [f32] {
        if self.cols.len() < len {
            self.cols.resize(len, 0.0);
        }
        &mut self.cols[..len]
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
}

impl Conv2d {
    pub fn new(c_in: usize, c_out: usize, k: usize, stride: usize, pad: usize, h: usize, w: usize) -> Result<Self, NnError> {
        check(c_in, c_out, k, stride, h, w)?;
        if h + 2 * pad < k || w + 2 * pad < k {
            return Err(NnError::Shape { sizes: vec![h, w, k, pad], why: "the kernel is larger than the padded image" });
        }
        let (oh, ow) = ((h + 2 * pad - k) / stride + 1, (w + 2 * pad - k) / stride + 1);
        Ok(Self { c_in, c_out, grid: Grid { c: c_in, h, w, k, stride, pad, oh, ow } })
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
        let w = MatRef::from_row_major_slice(wt, self.c_out, rows);
        for i in 0..n {
            let c = s.cols(rows * cols);
            g.im2col(&x[i * self.in_len()..(i + 1) * self.in_len()], c);
            let o = &mut out[i * self.out_len()..(i + 1) * self.out_len()];
            for (plane, b) in o.chunks_exact_mut(cols).zip(bias) {
                plane.fill(*b);
            }
            let om = MatMut::from_row_major_slice_mut(o, self.c_out, cols);
            matmul(om, Accum::Add, w, MatRef::from_row_major_slice(c, rows, cols), 1.0f32, Par::Seq);
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
        let w = MatRef::from_row_major_slice(&params[..self.c_out * rows], self.c_out, rows);
        if let Some(grad) = grad {
            let (gw, gb) = grad.split_at_mut(self.c_out * rows);
            for i in 0..n {
                let d = &dy[i * self.out_len()..(i + 1) * self.out_len()];
                let c = s.cols(rows * cols);
                g.im2col(&x[i * self.in_len()..(i + 1) * self.in_len()], c);
                // dW += dy . cols'
                let gm = MatMut::from_row_major_slice_mut(gw, self.c_out, rows);
                matmul(
                    gm,
                    Accum::Add,
                    MatRef::from_row_major_slice(d, self.c_out, cols),
                    MatRef::from_row_major_slice(c, rows, cols).transpose(),
                    1.0f32,
                    Par::Seq,
                );
                for (b, plane) in gb.iter_mut().zip(d.chunks_exact(cols)) {
                    *b += plane.iter().sum::<f32>();
                }
            }
        }
        if let Some(dx) = dx {
            for i in 0..n {
                let d = &dy[i * self.out_len()..(i + 1) * self.out_len()];
                let c = s.cols(rows * cols);
                // dcols = W' . dy, then back into the image.
                let cm = MatMut::from_row_major_slice_mut(c, rows, cols);
                matmul(cm, Accum::Replace, w.transpose(), MatRef::from_row_major_slice(d, self.c_out, cols), 1.0f32, Par::Seq);
                let di = &mut dx[i * self.in_len()..(i + 1) * self.in_len()];
                di.fill(0.0);
                g.col2im(c, di);
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
        Ok(Self { c_in, c_out, grid: Grid { c: c_out, h: bh, w: bw, k, stride, pad, oh: h, ow: w } })
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
        let (wt, bias) = params.split_at(self.c_in * rows);
        let w = MatRef::from_row_major_slice(wt, self.c_in, rows);
        let plane = g.h * g.w;
        for i in 0..n {
            let c = s.cols(rows * cols);
            // cols = W' . x: every input pixel spread over its kernel's reach.
            let cm = MatMut::from_row_major_slice_mut(c, rows, cols);
            matmul(
                cm,
                Accum::Replace,
                w.transpose(),
                MatRef::from_row_major_slice(&x[i * self.in_len()..(i + 1) * self.in_len()], self.c_in, cols),
                1.0f32,
                Par::Seq,
            );
            let o = &mut out[i * self.out_len()..(i + 1) * self.out_len()];
            for (p, b) in o.chunks_exact_mut(plane).zip(bias) {
                p.fill(*b);
            }
            g.col2im(c, o);
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
        let w = MatRef::from_row_major_slice(&params[..self.c_in * rows], self.c_in, rows);
        let plane = g.h * g.w;
        let mut grad = grad;
        let mut dx = dx;
        for i in 0..n {
            let d = &dy[i * self.out_len()..(i + 1) * self.out_len()];
            let c = s.cols(rows * cols);
            g.im2col(d, c);
            let xi = &x[i * self.in_len()..(i + 1) * self.in_len()];
            if let Some(grad) = grad.as_deref_mut() {
                let (gw, gb) = grad.split_at_mut(self.c_in * rows);
                // dW += x . im2col(dy)'
                let gm = MatMut::from_row_major_slice_mut(gw, self.c_in, rows);
                matmul(
                    gm,
                    Accum::Add,
                    MatRef::from_row_major_slice(xi, self.c_in, cols),
                    MatRef::from_row_major_slice(c, rows, cols).transpose(),
                    1.0f32,
                    Par::Seq,
                );
                for (b, p) in gb.iter_mut().zip(d.chunks_exact(plane)) {
                    *b += p.iter().sum::<f32>();
                }
            }
            if let Some(dx) = dx.as_deref_mut() {
                // dx = W . im2col(dy)
                let dm = MatMut::from_row_major_slice_mut(&mut dx[i * self.in_len()..(i + 1) * self.in_len()], self.c_in, cols);
                matmul(dm, Accum::Replace, w, MatRef::from_row_major_slice(c, rows, cols), 1.0f32, Par::Seq);
            }
        }
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
                        g.im2col(&img, &mut got);
                        assert_eq!(got, want, "im2col {g:?}");
                        let grads: Vec<f32> = (0..len).map(|i| (i % 7) as f32 - 3.0).collect();
                        g.col2im(&grads, &mut got_back);
                        assert_eq!(got_back, want_back, "col2im {g:?}");
                        cases += 1;
                    }
                }
            }
        }
        assert!(cases > 150, "{cases} geometries");
    }
}
