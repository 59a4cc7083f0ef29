//! The design landscape of thesis Fig. 5.9: the design objective on a grid over the first two
//! principal components of the designs tried so far.
//!
//! [`Pca2::fit`] finds the plane; [`grid`] lays an `n x n` grid over it and maps every grid
//! point back to a design (clipped to the design box) for the caller to score with the design
//! objective. Nothing here scores or draws: the run loop scores [`Grid::designs`] and writes the
//! `landscape.csv` that `coadapt plot` draws.
//!
//! **PCA** of the raw design coordinates (no scaling by the box), in f64: the covariance
//! `C = (1/k) sum_i (x_i - m)(x_i - m)^T` is decomposed with faer's self-adjoint solver
//! (`Mat::self_adjoint_eigen`, as in [`crate::cmaes`]); the two eigenvectors of the largest
//! eigenvalues are the axes and `lambda_j / trace(C)` their explained variance fractions. The
//! axes are made deterministic in sign: the entry of largest magnitude is positive.
//!
//! **Few designs.** With one design the covariance is zero: both axes are the first two
//! coordinate axes (`e_1`, `e_2`) and `explained` is `[0, 0]`. With two designs the second axis is
//! some unit vector orthogonal to the first (whatever the solver returns for the zero
//! eigenvalue) with zero variance. In a one-dimensional design space there is no second unit
//! vector orthogonal to the first: `axes[1]` is the zero vector `[0]`, so the second coordinate
//! [`Pca2::project`]s to 0 and [`Pca2::unproject`] ignores it.

use coadapt_core::BoxSpace;
use faer::{Mat, Side};

/// Why a PCA or a grid cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LandscapeError {
    #[error("no designs to fit")]
    Empty,
    #[error("design dimension must be at least 1")]
    ZeroDim,
    #[error("{len} values are not a whole number of designs of dimension {dim}")]
    Ragged { len: usize, dim: usize },
    #[error("design {design}, coordinate {coordinate} is not finite ({value})")]
    NonFinite { design: usize, coordinate: usize, value: f32 },
    #[error("the PCA has dimension {pca} but the {what} has dimension {got}")]
    Dim { what: &'static str, pca: usize, got: usize },
    #[error("the eigendecomposition of the design covariance failed")]
    Eigen,
}

/// The plane of the first two principal components of a set of designs.
#[derive(Clone, Debug, PartialEq)]
pub struct Pca2 {
    /// The mean design.
    pub mean: Vec<f32>,
    /// The first and second principal axes, unit vectors in design space (except `axes[1]`
    /// for a one-dimensional design space, which is `[0]`: see the module doc).
    pub axes: [Vec<f32>; 2],
    /// The fractions of the total variance along each axis, in `[0, 1]`; `[0, 0]` when every
    /// design is the same.
    pub explained: [f32; 2],
}

impl Pca2 {
    /// The PCA of `designs` (`k x dim`, row-major). Works for any `k >= 1` and `dim >= 1` (see
    /// the module doc for `k <= 2` and `dim = 1`); errors for no designs, `dim = 0`, a length
    /// that is not a multiple of `dim`, or a non-finite value.
    pub fn fit(designs: &[f32], dim: usize) -> Result<Self, LandscapeError> {
        if dim == 0 {
            return Err(LandscapeError::ZeroDim);
        }
        if designs.is_empty() {
            return Err(LandscapeError::Empty);
        }
        if !designs.len().is_multiple_of(dim) {
            return Err(LandscapeError::Ragged { len: designs.len(), dim });
        }
        if let Some(i) = designs.iter().position(|v| !v.is_finite()) {
            return Err(LandscapeError::NonFinite { design: i / dim, coordinate: i % dim, value: designs[i] });
        }
        let k = designs.len() / dim;
        let mut mean = vec![0.0f64; dim];
        for x in designs.chunks_exact(dim) {
            for (m, &v) in mean.iter_mut().zip(x) {
                *m += f64::from(v);
            }
        }
        for m in &mut mean {
            *m /= k as f64;
        }
        let mut cov = vec![0.0f64; dim * dim];
        for x in designs.chunks_exact(dim) {
            for i in 0..dim {
                let di = f64::from(x[i]) - mean[i];
                for j in 0..dim {
                    cov[i * dim + j] += di * (f64::from(x[j]) - mean[j]);
                }
            }
        }
        for c in &mut cov {
            *c /= k as f64;
        }
        let trace: f64 = (0..dim).map(|i| cov[i * dim + i]).sum();
        let mean32: Vec<f32> = mean.iter().map(|&m| m as f32).collect();

        if dim == 1 {
            let explained = if trace > 0.0 { [1.0, 0.0] } else { [0.0, 0.0] };
            return Ok(Self { mean: mean32, axes: [vec![1.0], vec![0.0]], explained });
        }
        if trace <= 0.0 {
            // Every design the same: any orthonormal pair will do; take e_1 and e_2.
            let mut e1 = vec![0.0; dim];
            let mut e2 = vec![0.0; dim];
            e1[0] = 1.0;
            e2[1] = 1.0;
            return Ok(Self { mean: mean32, axes: [e1, e2], explained: [0.0, 0.0] });
        }

        let c = Mat::<f64>::from_fn(dim, dim, |i, j| cov[i * dim + j]);
        let evd = c.self_adjoint_eigen(Side::Lower).map_err(|_| LandscapeError::Eigen)?;
        let (u, s) = (evd.U(), evd.S().column_vector());
        let mut order: Vec<usize> = (0..dim).collect();
        order.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
        let axis = |col: usize| -> Result<Vec<f32>, LandscapeError> {
            let mut v: Vec<f64> = (0..dim).map(|i| u[(i, col)]).collect();
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(norm.is_finite() && norm > 0.0) {
                return Err(LandscapeError::Eigen);
            }
            // Sign: the entry of largest magnitude (the first such) is positive.
            let big = v.iter().enumerate().fold(0, |best, (i, x)| if x.abs() > v[best].abs() { i } else { best });
            let sign = if v[big] < 0.0 { -1.0 } else { 1.0 };
            for x in &mut v {
                *x *= sign / norm;
            }
            Ok(v.iter().map(|&x| x as f32).collect())
        };
        let axes = [axis(order[0])?, axis(order[1])?];
        let frac = |col: usize| (s[col].max(0.0) / trace).clamp(0.0, 1.0) as f32;
        Ok(Self { mean: mean32, axes, explained: [frac(order[0]), frac(order[1])] })
    }

    /// The design space's dimension.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// The coordinates of `design` (of [`Pca2::dim`] values) in the PC plane:
    /// `(a_j . (design - mean))_j`.
    pub fn project(&self, design: &[f32]) -> [f32; 2] {
        let along = |axis: &[f32]| -> f32 {
            let dot: f64 = design.iter().zip(&self.mean).zip(axis).map(|((&x, &m), &a)| (f64::from(x) - f64::from(m)) * f64::from(a)).sum();
            dot as f32
        };
        [along(&self.axes[0]), along(&self.axes[1])]
    }

    /// The design at plane coordinates `pc`: `mean + pc_1 a_1 + pc_2 a_2` (not clipped to any
    /// bounds). Inverts [`Pca2::project`] for designs in the plane.
    pub fn unproject(&self, pc: [f32; 2]) -> Vec<f32> {
        (0..self.dim()).map(|i| self.mean[i] + pc[0] * self.axes[0][i] + pc[1] * self.axes[1][i]).collect()
    }
}

/// An `n x n` grid over the PC plane and the designs at its points.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    /// Points per side.
    pub n: usize,
    /// The plane coordinates of the `n * n` grid points, row by row: point `r * n + c` is at
    /// `[pc1_c, pc2_r]` (pc2 the outer index, pc1 the inner one, both increasing).
    pub pc: Vec<[f32; 2]>,
    /// The design at each grid point (`n * n x dim`, row-major, same order as `pc`), clipped to
    /// the bounds; a clipped design no longer projects exactly onto its grid point.
    pub designs: Vec<f32>,
}

/// The fraction of the designs' spread along an axis added as a margin on each side of the grid.
pub const GRID_MARGIN: f32 = 0.15;
/// The least half-width of the grid along an axis, as a fraction of the width of the box's
/// projection onto that axis (`sum_i |a_i| (high_i - low_i)`).
pub const GRID_MIN_HALF_WIDTH: f32 = 0.1;

/// An `n x n` grid over the PC plane covering the projected `designs` with a margin, each grid
/// point mapped back to design space and clipped to `bounds`.
///
/// Along each axis the grid spans `[lo - pad, hi + pad]`, where `[lo, hi]` is the range of the
/// projected designs and `pad = GRID_MARGIN * (hi - lo)`; when that is narrower than
/// `2 * GRID_MIN_HALF_WIDTH` times the width of the box's projection onto the axis (few designs,
/// a zero-variance axis), it is widened about its centre to that, so the grid always shows some
/// of the box around the designs. If both are zero (an axis along which the box is flat), the
/// axis spans `[-0.5, 0.5]` around the centre. The grid need not cover the whole box: Fig. 5.9
/// is about the region the designs explored. `n = 1` gives the centre; `n = 0` an empty grid.
///
/// Errors when `designs` is empty, not a whole number of designs of the PCA's dimension, or
/// when the bounds have another dimension.
pub fn grid(pca: &Pca2, designs: &[f32], bounds: &BoxSpace, n: usize) -> Result<Grid, LandscapeError> {
    let dim = pca.dim();
    if dim == 0 {
        return Err(LandscapeError::ZeroDim);
    }
    if designs.is_empty() {
        return Err(LandscapeError::Empty);
    }
    if !designs.len().is_multiple_of(dim) {
        return Err(LandscapeError::Ragged { len: designs.len(), dim });
    }
    if bounds.low.len() != dim || bounds.high.len() != dim {
        return Err(LandscapeError::Dim { what: "bounds", pca: dim, got: bounds.low.len().max(bounds.high.len()) });
    }
    let mut lo = [f32::INFINITY; 2];
    let mut hi = [f32::NEG_INFINITY; 2];
    for (d, x) in designs.chunks_exact(dim).enumerate() {
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(LandscapeError::NonFinite { design: d, coordinate: i, value: x[i] });
        }
        let p = pca.project(x);
        for j in 0..2 {
            lo[j] = lo[j].min(p[j]);
            hi[j] = hi[j].max(p[j]);
        }
    }
    let mut ticks: [Vec<f32>; 2] = [Vec::with_capacity(n), Vec::with_capacity(n)];
    for j in 0..2 {
        let box_width: f32 = pca.axes[j].iter().zip(bounds.low.iter().zip(&bounds.high)).map(|(a, (l, h))| a.abs() * (h - l).abs()).sum();
        let centre = 0.5 * (lo[j] + hi[j]);
        let mut half = 0.5 * (hi[j] - lo[j]) * (1.0 + 2.0 * GRID_MARGIN);
        half = half.max(GRID_MIN_HALF_WIDTH * box_width);
        if !(half > 0.0 && half.is_finite()) {
            half = 0.5;
        }
        ticks[j] = match n {
            0 => Vec::new(),
            1 => vec![centre],
            _ => (0..n).map(|i| centre - half + 2.0 * half * i as f32 / (n - 1) as f32).collect(),
        };
    }
    let mut pc = Vec::with_capacity(n * n);
    let mut out = Vec::with_capacity(n * n * dim);
    for &p2 in &ticks[1] {
        for &p1 in &ticks[0] {
            pc.push([p1, p2]);
            let x = pca.unproject([p1, p2]);
            out.extend(x.iter().zip(bounds.low.iter().zip(&bounds.high)).map(|(&v, (&l, &h))| v.clamp(l.min(h), h.max(l))));
        }
    }
    Ok(Grid { n, pc, designs: out })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn designs_on_a_line_have_one_axis_along_it() {
        // x = p + t d for t in -2..=2, d = (1, 2, -2)/3.
        let p = [0.5f32, 1.0, 1.5];
        let d = [1.0f32 / 3.0, 2.0 / 3.0, -2.0 / 3.0];
        let designs: Vec<f32> = (-2..=2).flat_map(|t| (0..3).map(move |i| p[i] + t as f32 * d[i])).collect();
        let pca = Pca2::fit(&designs, 3).unwrap();
        assert!(close(pca.explained[0], 1.0, 1e-5), "{:?}", pca.explained);
        assert!(close(pca.explained[1], 0.0, 1e-5), "{:?}", pca.explained);
        let dot: f32 = pca.axes[0].iter().zip(&d).map(|(a, b)| a * b).sum();
        assert!(close(dot.abs(), 1.0, 1e-5), "axis {:?} not along {d:?}", pca.axes[0]);
        // Sign convention: the largest entry is positive.
        assert!(pca.axes[0][1] > 0.0 || pca.axes[0][2] > 0.0);
        for (m, pi) in pca.mean.iter().zip(&p) {
            assert!(close(*m, *pi, 1e-5));
        }
        // Orthonormal axes.
        let n1: f32 = pca.axes[1].iter().map(|a| a * a).sum();
        let ortho: f32 = pca.axes[0].iter().zip(&pca.axes[1]).map(|(a, b)| a * b).sum();
        assert!(close(n1, 1.0, 1e-5) && close(ortho, 0.0, 1e-5));
    }

    #[test]
    fn explained_fractions_follow_the_variances() {
        // Independent spreads 3 and 1 along e_2 and e_1: fractions 9/10 and 1/10.
        let designs = [1.0f32, 3.0, -1.0, 3.0, 0.0, 6.0, 0.0, 0.0];
        let pca = Pca2::fit(&designs, 2).unwrap();
        assert!(close(pca.explained[0], 0.9, 1e-5) && close(pca.explained[1], 0.1, 1e-5), "{:?}", pca.explained);
        assert!(close(pca.axes[0][1].abs(), 1.0, 1e-5), "{:?}", pca.axes);
    }

    #[test]
    fn project_and_unproject_round_trip() {
        let designs = [1.0f32, 0.5, 2.0, 1.5, 1.2, 0.8, 0.9, 1.1, 1.7, 1.3, 0.7, 1.4, 0.6, 0.9, 1.0];
        let pca = Pca2::fit(&designs, 3).unwrap();
        for pc in [[0.0f32, 0.0], [0.3, -0.2], [-1.5, 2.0]] {
            let back = pca.project(&pca.unproject(pc));
            assert!(close(back[0], pc[0], 1e-5) && close(back[1], pc[1], 1e-5), "{pc:?} -> {back:?}");
        }
        assert_eq!(pca.project(&pca.mean), [0.0, 0.0]);
        // A design in the plane (the mean plus a little of each axis) comes back.
        let x = pca.unproject([0.25, -0.1]);
        let y = pca.unproject(pca.project(&x));
        for (a, b) in x.iter().zip(&y) {
            assert!(close(*a, *b, 1e-5));
        }
    }

    #[test]
    fn grid_designs_are_within_bounds_and_cover_the_designs() {
        let bounds = BoxSpace::new(vec![0.5, 0.5, 0.5], vec![1.5, 1.5, 1.5]).unwrap();
        let designs = [1.0f32, 1.0, 1.0, 1.45, 0.6, 1.2, 0.55, 1.4, 0.9, 1.3, 1.3, 1.45];
        let pca = Pca2::fit(&designs, 3).unwrap();
        let g = grid(&pca, &designs, &bounds, 7).unwrap();
        assert_eq!(g.n, 7);
        assert_eq!(g.pc.len(), 49);
        assert_eq!(g.designs.len(), 49 * 3);
        for x in g.designs.chunks_exact(3) {
            for (i, v) in x.iter().enumerate() {
                assert!((bounds.low[i]..=bounds.high[i]).contains(v), "{x:?}");
            }
        }
        // pc1 inner, pc2 outer, both increasing, covering every projected design.
        assert!(g.pc[1][0] > g.pc[0][0] && g.pc[1][1] == g.pc[0][1]);
        assert!(g.pc[7][1] > g.pc[0][1] && g.pc[7][0] == g.pc[0][0]);
        for x in designs.chunks_exact(3) {
            let p = pca.project(x);
            assert!(p[0] > g.pc[0][0] && p[0] < g.pc[48][0] && p[1] > g.pc[0][1] && p[1] < g.pc[48][1], "{p:?}");
        }
        assert!(grid(&pca, &designs, &BoxSpace::uniform(2, 0.0, 1.0), 3).is_err());
        assert!(grid(&pca, &designs[..4], &bounds, 3).is_err());
        assert!(grid(&pca, &designs, &bounds, 0).unwrap().pc.is_empty());
        assert_eq!(grid(&pca, &designs, &bounds, 1).unwrap().pc.len(), 1);
    }

    #[test]
    fn one_or_two_designs_and_one_dimension_work() {
        let bounds = BoxSpace::uniform(4, 0.0, 2.0);
        let one = [1.0f32, 1.0, 1.5, 0.5];
        let pca = Pca2::fit(&one, 4).unwrap();
        assert_eq!(pca.explained, [0.0, 0.0]);
        assert_eq!(pca.project(&one), [0.0, 0.0]);
        let g = grid(&pca, &one, &bounds, 5).unwrap();
        assert_eq!(g.designs.len(), 25 * 4);
        assert!(g.pc[0][0] < 0.0 && g.pc[24][0] > 0.0 && g.pc[0][1] < 0.0 && g.pc[24][1] > 0.0, "{:?}", g.pc);
        assert!(g.designs.iter().all(|v| (0.0..=2.0).contains(v)));

        let two = [1.0f32, 1.0, 1.5, 0.5, 1.2, 1.0, 1.5, 0.5];
        let pca = Pca2::fit(&two, 4).unwrap();
        assert!(close(pca.explained[0], 1.0, 1e-5) && close(pca.explained[1], 0.0, 1e-5));
        assert!(close(pca.axes[0][0], 1.0, 1e-5));
        let g = grid(&pca, &two, &bounds, 4).unwrap();
        assert!(g.pc[0][1] < g.pc[15][1], "second axis has some extent");

        let line = [0.5f32, 1.5, 1.0];
        let pca = Pca2::fit(&line, 1).unwrap();
        assert_eq!(pca.axes, [vec![1.0], vec![0.0]]);
        assert_eq!(pca.explained, [1.0, 0.0]);
        assert!(close(pca.unproject(pca.project(&[0.7]))[0], 0.7, 1e-6));
        let g = grid(&pca, &line, &BoxSpace::uniform(1, 0.0, 2.0), 3).unwrap();
        assert_eq!(g.designs.len(), 9);
    }

    #[test]
    fn bad_input_is_an_error() {
        assert_eq!(Pca2::fit(&[], 3), Err(LandscapeError::Empty));
        assert_eq!(Pca2::fit(&[1.0], 0), Err(LandscapeError::ZeroDim));
        assert!(matches!(Pca2::fit(&[1.0, 2.0, 3.0], 2), Err(LandscapeError::Ragged { .. })));
        assert!(matches!(Pca2::fit(&[1.0, f32::NAN, 3.0, 4.0], 2), Err(LandscapeError::NonFinite { design: 0, coordinate: 1, .. })));
        assert!(matches!(Pca2::fit(&[1.0, 2.0, 3.0, f32::INFINITY], 2), Err(LandscapeError::NonFinite { design: 1, coordinate: 1, .. })));
    }
}
