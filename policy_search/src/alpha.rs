//! The log-linear model of the synergies' precisions (thesis ch. 3, Eq. 3.4, 3.17-3.21, with
//! the printing errors corrected as in `thesis-notes.md` 2.1): `log alpha = U V' + mu_u 1' +
//! 1 mu_v'` of rank R, U (groups x R) and V (K x R) with N(0, 1/lambda) priors, fitted as point
//! estimates by L-BFGS to
//! `l = sum_{m,k} [ (D_m / 2) L_mk - (1/2) Gamma_mk exp(L_mk) ] - (lambda / 2)(|U|^2 + |V|^2)`,
//! where `Gamma_mk = E|w_k^(m) - w-hat_k^(m)|^2`.

/// The model's parameters, packed `[U (M x R), V (K x R), mu_u (M), mu_v (K)]`.
#[derive(Clone, Debug, PartialEq)]
pub struct LogLinearAlpha {
    pub groups: usize,
    pub latent: usize,
    pub rank: usize,
    pub lambda: f64,
    pub params: Vec<f64>,
}

impl LogLinearAlpha {
    /// Zero means and small fixed U, V (alpha near 1 everywhere, the chapter-2 start). U = V = 0
    /// would be a saddle of the objective (both gradients vanish there): the fit could never
    /// leave rank 0.
    pub fn new(groups: usize, latent: usize, rank: usize, lambda: f64) -> Self {
        let n = (groups + latent) * rank;
        let mut params = vec![0.0; n + groups + latent];
        params.iter_mut().take(n).enumerate().for_each(|(i, p)| *p = 0.01 * ((i as f64 + 1.0) * 2.399).sin());
        Self { groups, latent, rank, lambda, params }
    }

    /// L (M x K) of `p`.
    pub fn log_alpha(&self, p: &[f64]) -> Vec<f64> {
        let (m, k, r) = (self.groups, self.latent, self.rank);
        let (u, rest) = p.split_at(m * r);
        let (v, rest) = rest.split_at(k * r);
        let (mu_u, mu_v) = rest.split_at(m);
        let mut l = vec![0.0; m * k];
        for a in 0..m {
            for b in 0..k {
                l[a * k + b] = (0..r).map(|c| u[a * r + c] * v[b * r + c]).sum::<f64>() + mu_u[a] + mu_v[b];
            }
        }
        l
    }

    /// `l` at `p` and its gradient in `grad` (same packing), for group sizes `d` and
    /// deviations `gamma` (M x K).
    pub fn objective(&self, p: &[f64], d: &[usize], gamma: &[f64], grad: &mut [f64]) -> f64 {
        let (m, k, r) = (self.groups, self.latent, self.rank);
        let l = self.log_alpha(p);
        let (u, rest) = p.split_at(m * r);
        let (v, _) = rest.split_at(k * r);
        grad.iter_mut().for_each(|g| *g = 0.0);
        let mut value = 0.0;
        let (gu, rest) = grad.split_at_mut(m * r);
        let (gv, rest) = rest.split_at_mut(k * r);
        let (gmu_u, gmu_v) = rest.split_at_mut(m);
        for a in 0..m {
            for b in 0..k {
                let e = l[a * k + b].exp();
                value += 0.5 * d[a] as f64 * l[a * k + b] - 0.5 * gamma[a * k + b] * e;
                // dl/dL_ab.
                let g = 0.5 * d[a] as f64 - 0.5 * gamma[a * k + b] * e;
                for c in 0..r {
                    gu[a * r + c] += g * v[b * r + c];
                    gv[b * r + c] += g * u[a * r + c];
                }
                gmu_u[a] += g;
                gmu_v[b] += g;
            }
        }
        let norm: f64 = u.iter().chain(v).map(|x| x * x).sum();
        value -= 0.5 * self.lambda * norm;
        gu.iter_mut().zip(u).for_each(|(g, x)| *g -= self.lambda * x);
        gv.iter_mut().zip(v).for_each(|(g, x)| *g -= self.lambda * x);
        value
    }

    /// Fits the parameters to `d` and `gamma` by L-BFGS (from the current ones) and returns
    /// E[alpha] = exp(L), M x K.
    pub fn fit(&mut self, d: &[usize], gamma: &[f64]) -> Vec<f64> {
        let mut p = self.params.clone();
        let model = self.clone();
        crate::lbfgs::minimise(&mut p, 1000, 1e-9, |x, g| {
            let v = model.objective(x, d, gamma, g);
            g.iter_mut().for_each(|gi| *gi = -*gi);
            -v
        });
        self.params = p;
        self.log_alpha(&self.params).iter().map(|l| l.exp()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup() -> (LogLinearAlpha, Vec<f64>, Vec<usize>, Vec<f64>) {
        let model = LogLinearAlpha { lambda: 0.1, ..LogLinearAlpha::new(3, 4, 2, 0.1) };
        let p: Vec<f64> = (0..model.params.len()).map(|i| ((i as f64) * 1.3).sin() * 0.4).collect();
        let d = vec![4, 2, 6];
        let gamma: Vec<f64> = (0..12).map(|i| 0.5 + (i as f64 * 0.7).cos().abs()).collect();
        (model, p, d, gamma)
    }

    #[test]
    fn the_gradient_matches_finite_differences() {
        let (model, p, d, gamma) = setup();
        let mut grad = vec![0.0; p.len()];
        model.objective(&p, &d, &gamma, &mut grad);
        let mut scratch = vec![0.0; p.len()];
        for i in 0..p.len() {
            let h = 1e-6;
            let (mut a, mut b) = (p.clone(), p.clone());
            a[i] += h;
            b[i] -= h;
            let fd = (model.objective(&a, &d, &gamma, &mut scratch) - model.objective(&b, &d, &gamma, &mut scratch)) / (2.0 * h);
            assert!((fd - grad[i]).abs() < 1e-6 * (1.0 + fd.abs()), "parameter {i}: analytic {} vs finite differences {fd}", grad[i]);
        }
    }

    #[test]
    fn at_full_rank_without_prior_alpha_is_the_maximum_likelihood_d_over_gamma() {
        // Rank min(M, K) spans every M x K matrix: each alpha_mk solves D_m / Gamma_mk.
        let (_, _, d, gamma) = setup();
        let mut model = LogLinearAlpha::new(3, 4, 3, 1e-9);
        let alpha = model.fit(&d, &gamma);
        for a in 0..3 {
            for b in 0..4 {
                let want = d[a] as f64 / gamma[a * 4 + b];
                assert!((alpha[a * 4 + b] - want).abs() < 1e-3 * want, "({a},{b}): {} vs {want}", alpha[a * 4 + b]);
            }
        }
    }
}
