//! The small dense algebra GrouPS needs (matrices of the features' or the latent factors' size:
//! 11 x 11, 6 x 6), in f64, row-major.

/// The inverse of the symmetric positive-definite `a` (`n x n`) by Cholesky; `None` when it is
/// not positive definite.
pub(crate) fn spd_inverse(a: &[f64], n: usize) -> Option<Vec<f64>> {
    // a = L L^T.
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            if i == j {
                if !(s > 0.0 && s.is_finite()) {
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    // L^-1 by forward substitution, then a^-1 = L^-T L^-1.
    let mut li = vec![0.0; n * n];
    for c in 0..n {
        for i in 0..n {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[i * n + k] * li[k * n + c];
            }
            li[i * n + c] = s / l[i * n + i];
        }
    }
    let mut inv = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            inv[i * n + j] = (0..n).map(|k| li[k * n + i] * li[k * n + j]).sum();
        }
    }
    Some(inv)
}

/// `y = a x` for `a` (`rows x cols`).
pub(crate) fn matvec(a: &[f64], rows: usize, cols: usize, x: &[f64], y: &mut [f64]) {
    for (r, yr) in y.iter_mut().enumerate().take(rows) {
        *yr = a[r * cols..(r + 1) * cols].iter().zip(x).map(|(p, q)| p * q).sum();
    }
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p * q).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_inverse_times_the_matrix_is_the_identity() {
        let n = 4;
        // B B^T + I: positive definite.
        let b: Vec<f64> = (0..n * n).map(|i| ((i * 7 % 5) as f64 - 2.0) * 0.5).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| b[i * n + k] * b[j * n + k]).sum::<f64>() + if i == j { 1.0 } else { 0.0 };
            }
        }
        let inv = spd_inverse(&a, n).unwrap_or_default();
        for i in 0..n {
            for j in 0..n {
                let v: f64 = (0..n).map(|k| a[i * n + k] * inv[k * n + j]).sum();
                assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12, "({i},{j}) {v}");
            }
        }
        assert!(spd_inverse(&[1.0, 2.0, 2.0, 1.0], 2).is_none(), "indefinite");
    }
}
