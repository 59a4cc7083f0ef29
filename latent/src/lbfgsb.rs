//! L-BFGS within box bounds, for the planner (Alg. 3 optimises the actions with L-BFGS, 20
//! iterations; the actions live in a box). A projected variant: the two-loop direction over the
//! variables that are free (not held at a bound by their gradient), a backtracking line search
//! along the projected path (Armijo), curvature pairs kept only when `s'y > 0`.
//!
//! Why our own: the planner calls it at every control step with tens of variables, so it must
//! not allocate per call (the buffers live in [`Lbfgsb`]); argmin's L-BFGS has no bounds, and the
//! Fortran L-BFGS-B bindings would bring a C toolchain to the build for a 100-line method.

/// A reusable minimiser (its buffers grow to the largest problem seen).
#[derive(Clone, Debug)]
pub struct Lbfgsb {
    /// Curvature pairs kept.
    pub memory: usize,
    s: Vec<Vec<f64>>,
    y: Vec<Vec<f64>>,
    rho: Vec<f64>,
    alpha: Vec<f64>,
    g: Vec<f64>,
    g_new: Vec<f64>,
    d: Vec<f64>,
    x_new: Vec<f64>,
}

/// What a minimisation ended with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LbfgsbResult {
    pub value: f64,
    pub iterations: usize,
    pub evaluations: usize,
}

impl Default for Lbfgsb {
    fn default() -> Self {
        Self::new(10)
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl Lbfgsb {
    pub fn new(memory: usize) -> Self {
        Self {
            memory: memory.max(1),
            s: Vec::new(),
            y: Vec::new(),
            rho: Vec::new(),
            alpha: Vec::new(),
            g: Vec::new(),
            g_new: Vec::new(),
            d: Vec::new(),
            x_new: Vec::new(),
        }
    }

    /// Minimises `f` (which returns the value and writes the gradient) from `x` within
    /// `[lo, hi]`, for at most `iterations`; `x` holds the best point found.
    pub fn minimize(
        &mut self,
        x: &mut [f64],
        lo: &[f64],
        hi: &[f64],
        iterations: usize,
        mut f: impl FnMut(&[f64], &mut [f64]) -> f64,
    ) -> LbfgsbResult {
        let n = x.len();
        assert!(lo.len() == n && hi.len() == n, "bounds of another length");
        for (v, (l, h)) in x.iter_mut().zip(lo.iter().zip(hi)) {
            *v = v.clamp(*l, *h);
        }
        self.g.resize(n, 0.0);
        self.g_new.resize(n, 0.0);
        self.d.resize(n, 0.0);
        self.x_new.resize(n, 0.0);
        self.alpha.resize(self.memory, 0.0);
        // History of this call only: pairs from another problem mean nothing here.
        let mut kept = 0usize;
        let mut next = 0usize;
        if self.s.len() < self.memory {
            self.s.resize(self.memory, Vec::new());
            self.y.resize(self.memory, Vec::new());
            self.rho.resize(self.memory, 0.0);
        }
        for v in self.s.iter_mut().chain(self.y.iter_mut()) {
            v.resize(n, 0.0);
        }
        let mut value = f(x, &mut self.g);
        let mut evaluations = 1;
        let mut it = 0;
        while it < iterations {
            it += 1;
            // Variables held at a bound by their gradient stay there this step.
            let free = |i: usize, x: &[f64], g: &[f64]| !((x[i] <= lo[i] && g[i] > 0.0) || (x[i] >= hi[i] && g[i] < 0.0));
            for i in 0..n {
                self.d[i] = if free(i, x, &self.g) { -self.g[i] } else { 0.0 };
            }
            // Two-loop recursion on the free variables, newest pair first.
            for k in 0..kept {
                let j = (next + self.memory - 1 - k) % self.memory;
                let a = self.rho[j] * dot(&self.s[j], &self.d);
                self.alpha[j] = a;
                for (d, y) in self.d.iter_mut().zip(&self.y[j]) {
                    *d -= a * y;
                }
            }
            if kept > 0 {
                let j = (next + self.memory - 1) % self.memory;
                let gamma = dot(&self.s[j], &self.y[j]) / dot(&self.y[j], &self.y[j]).max(1e-300);
                self.d.iter_mut().for_each(|d| *d *= gamma);
            }
            for k in (0..kept).rev() {
                let j = (next + self.memory - 1 - k) % self.memory;
                let b = self.rho[j] * dot(&self.y[j], &self.d);
                let a = self.alpha[j];
                for (d, s) in self.d.iter_mut().zip(&self.s[j]) {
                    *d += (a - b) * s;
                }
            }
            for i in 0..n {
                if !free(i, x, &self.g) {
                    self.d[i] = 0.0;
                }
            }
            if dot(&self.d, &self.g) >= 0.0 {
                // Not a descent direction (stale curvature): steepest descent, history dropped.
                for i in 0..n {
                    self.d[i] = if free(i, x, &self.g) { -self.g[i] } else { 0.0 };
                }
                kept = 0;
            }
            if self.d.iter().all(|v| *v == 0.0) {
                break;
            }
            // Backtracking along the projected path.
            let mut t = if kept == 0 { 1.0 / self.d.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1.0) } else { 1.0 };
            let mut accepted = false;
            for _ in 0..30 {
                for i in 0..n {
                    self.x_new[i] = (x[i] + t * self.d[i]).clamp(lo[i], hi[i]);
                }
                let v = f(&self.x_new, &mut self.g_new);
                evaluations += 1;
                let decrease: f64 = self.g.iter().zip(self.x_new.iter().zip(x.iter())).map(|(g, (a, b))| g * (a - b)).sum();
                if v.is_finite() && v <= value + 1e-4 * decrease {
                    let j = next;
                    for i in 0..n {
                        self.s[j][i] = self.x_new[i] - x[i];
                        self.y[j][i] = self.g_new[i] - self.g[i];
                    }
                    let sy = dot(&self.s[j], &self.y[j]);
                    if sy > 1e-12 {
                        self.rho[j] = 1.0 / sy;
                        next = (next + 1) % self.memory;
                        kept = (kept + 1).min(self.memory);
                    }
                    x.copy_from_slice(&self.x_new);
                    std::mem::swap(&mut self.g, &mut self.g_new);
                    value = v;
                    accepted = true;
                    break;
                }
                t *= 0.5;
            }
            if !accepted {
                break;
            }
        }
        LbfgsbResult { value, iterations: it, evaluations }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quadratic_with_its_optimum_outside_the_box_ends_on_the_box() {
        // min sum (x - c)^2 in [-1, 1]^4: the optimum is c clipped to the box.
        let c = [0.5, 2.0, -3.0, 0.0];
        let mut x = vec![0.9, -0.9, 0.9, -0.9];
        let mut opt = Lbfgsb::default();
        let r = opt.minimize(&mut x, &[-1.0; 4], &[1.0; 4], 20, |x, g| {
            let mut v = 0.0;
            for i in 0..4 {
                g[i] = 2.0 * (x[i] - c[i]);
                v += (x[i] - c[i]).powi(2);
            }
            v
        });
        for (a, b) in x.iter().zip([0.5, 1.0, -1.0, 0.0]) {
            assert!((a - b).abs() < 1e-6, "{x:?} after {r:?}");
        }
    }

    #[test]
    fn rosenbrock_inside_a_wide_box() {
        let mut x = vec![-1.2, 1.0];
        let mut opt = Lbfgsb::default();
        let r = opt.minimize(&mut x, &[-5.0; 2], &[5.0; 2], 200, |x, g| {
            let (a, b) = (x[0], x[1]);
            g[0] = -2.0 * (1.0 - a) - 400.0 * a * (b - a * a);
            g[1] = 200.0 * (b - a * a);
            (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2)
        });
        assert!((x[0] - 1.0).abs() < 1e-4 && (x[1] - 1.0).abs() < 1e-4, "{x:?} after {r:?}");
    }

    #[test]
    fn rosenbrock_with_its_minimum_cut_off_by_a_bound() {
        // With x1 <= 0.5 the minimum is on that face: x1 = 0.5, x2 = 0.25.
        let mut x = vec![-1.2, 1.0];
        let mut opt = Lbfgsb::default();
        opt.minimize(&mut x, &[-5.0, -5.0], &[0.5, 5.0], 200, |x, g| {
            let (a, b) = (x[0], x[1]);
            g[0] = -2.0 * (1.0 - a) - 400.0 * a * (b - a * a);
            g[1] = 200.0 * (b - a * a);
            (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2)
        });
        assert!((x[0] - 0.5).abs() < 1e-6 && (x[1] - 0.25).abs() < 1e-4, "{x:?}");
    }
}
