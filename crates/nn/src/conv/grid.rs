//! The geometry of a convolution and its transpose, and the two data movements everything
//! else is built on: `im2col` (an image into columns, through its stride phases) and `col2im`
//! (columns added back into an image). See the module doc of `conv`.

use crate::bf16;
use crate::simd;

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
    pub(super) fn rows(&self) -> usize {
        self.c * self.k * self.k
    }

    pub(super) fn cols(&self) -> usize {
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
                    simd::deinterleave_lines(&img[(ch * h + ry) * w..], 2 * w, lines, w, ph, (e0, o0, pw));
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
                    simd::interleave_lines(ph, (e0, o0, pw), lines, w, &mut img[(ch * h + ry) * w..], 2 * w);
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
            simd::copy_short(&src[at..at + xs.len()], &mut line[xs.clone()]);
        }
    }

    /// Columns `[c k k, oh ow]` of the large image `img` (`c x h x w`); zero outside it.
    pub(super) fn im2col(&self, img: &[f32], cols: &mut [f32], g: &mut GridScratch) {
        let (n, kk) = (self.cols(), self.k * self.k);
        self.prepare(Some(img), g);
        let src = if self.stride == 1 { img } else { &g.planes };
        for (r, row) in cols[..self.rows() * n].chunks_exact_mut(n).enumerate() {
            self.im2col_row(src, &g.reach[r % kk], r / kk, row);
        }
    }

    /// The columns of `img` straight into bf16 pairs (`b`, `[c k k] x [oh ow]`): each pair of
    /// rows goes through `two` (2 rows of f32, in L1) and is rounded at once.
    pub(super) fn im2col_packed(&self, img: &[f32], g: &mut GridScratch, two: &mut Vec<f32>, b: &mut bf16::PackedB) {
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
    pub(super) fn col2im(&self, cols: &[f32], img: &mut [f32], g: &mut GridScratch, fresh: bool) {
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
pub(super) struct GridScratch {
    planes: Vec<f32>,
    reach: Vec<Option<Reach>>,
}

pub(super) fn grow(v: &mut Vec<f32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
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
