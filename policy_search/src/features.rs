//! Normalised Gaussian radial basis features of time.

/// `phi_i(t) = N(t | mu_i, width^2) / sum_j N(t | mu_j, width^2)` for `t = 1..=steps`, with
/// centres `mu_i = -width, 0, width, ...` up to `steps + width` (the port's `-3:3:T+3` for width
/// 3): 11 features for 25 steps, 8 for 15. The normalisation makes the features sum to 1 at
/// every step, so `M phi_t` interpolates the columns of M.
#[derive(Clone, Debug, PartialEq)]
pub struct TimeFeatures {
    steps: usize,
    n: usize,
    /// `steps x n`, row-major.
    values: Vec<f64>,
}

impl TimeFeatures {
    pub fn new(steps: usize, width: f64) -> Self {
        let mut centres = Vec::new();
        let mut c = -width;
        while c <= steps as f64 + width + 1e-9 {
            centres.push(c);
            c += width;
        }
        let n = centres.len();
        let mut values = Vec::with_capacity(steps * n);
        for t in 1..=steps {
            let row: Vec<f64> = centres.iter().map(|&m| (-0.5 * ((t as f64 - m) / width).powi(2)).exp()).collect();
            let sum: f64 = row.iter().sum();
            values.extend(row.iter().map(|v| v / sum));
        }
        Self { steps, n, values }
    }

    /// The thesis's features for `steps` steps (width 3).
    pub fn thesis(steps: usize) -> Self {
        Self::new(steps, 3.0)
    }

    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Features per step.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// phi at step `t` (0-based).
    pub fn at(&self, t: usize) -> &[f64] {
        &self.values[t * self.n..(t + 1) * self.n]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_thesis_counts_and_a_partition_of_unity() {
        assert_eq!(TimeFeatures::thesis(25).len(), 11);
        assert_eq!(TimeFeatures::thesis(15).len(), 8);
        let f = TimeFeatures::thesis(25);
        for t in 0..25 {
            let s: f64 = f.at(t).iter().sum();
            assert!((s - 1.0).abs() < 1e-12, "step {t}: {s}");
            assert!(f.at(t).iter().all(|&v| v > 0.0));
        }
        // Step 1 (t = 1) is nearest the centre 0 (feature 1), step 25 the centre 24 (feature 9).
        let argmax = |t: usize| f.at(t).iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).map(|(i, _)| i).unwrap_or(0);
        assert_eq!(argmax(0), 1);
        assert_eq!(argmax(24), 9);
    }
}
