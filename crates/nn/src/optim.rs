//! Optimisation on flat parameter buffers: Adam, gradient clamping, Polyak averaging.

/// Adam's hyper-parameters (PyTorch's defaults but the learning rate).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { lr: 3e-4, beta1: 0.9, beta2: 0.999, eps: 1e-8 }
    }
}

/// Moments saved from an optimiser of another size (a snapshot of another network).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("Adam moments of {m} and {v} values for {params} parameters")]
pub struct MomentsMismatch {
    /// Values of the first and second moment estimates given.
    pub m: usize,
    pub v: usize,
    /// The optimiser's parameters.
    pub params: usize,
}

/// Adam (Kingma & Ba) with bias correction, as `torch.optim.Adam` computes it.
#[derive(Clone, Debug)]
pub struct Adam {
    pub cfg: AdamConfig,
    m: Vec<f32>,
    v: Vec<f32>,
    t: u32,
}

impl Adam {
    pub fn new(n_params: usize, cfg: AdamConfig) -> Self {
        Self { cfg, m: vec![0.0; n_params], v: vec![0.0; n_params], t: 0 }
    }

    /// Forgets the moment estimates, as a freshly constructed optimiser would.
    pub fn reset(&mut self) {
        self.m.fill(0.0);
        self.v.fill(0.0);
        self.t = 0;
    }

    /// Steps taken since construction or the last reset.
    pub fn steps(&self) -> u32 {
        self.t
    }

    /// The first and second moment estimates (for a snapshot of the whole run).
    pub fn moments(&self) -> (&[f32], &[f32]) {
        (&self.m, &self.v)
    }

    /// Restores moments and step count saved from an optimiser of the same size.
    pub fn restore(&mut self, m: &[f32], v: &[f32], t: u32) -> Result<(), MomentsMismatch> {
        if m.len() != self.m.len() || v.len() != self.v.len() {
            return Err(MomentsMismatch { m: m.len(), v: v.len(), params: self.m.len() });
        }
        self.m.copy_from_slice(m);
        self.v.copy_from_slice(v);
        self.t = t;
        Ok(())
    }

    /// One descent step of `params` along `grad`.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) {
        assert_eq!(params.len(), self.m.len(), "Adam built for another network");
        assert_eq!(grad.len(), self.m.len(), "gradient length");
        self.t += 1;
        let AdamConfig { lr, beta1, beta2, eps } = self.cfg;
        let bc1 = 1.0 - beta1.powi(self.t as i32);
        let bc2_sqrt = (1.0 - beta2.powi(self.t as i32)).sqrt();
        let step = lr / bc1;
        for (((p, g), m), v) in params.iter_mut().zip(grad).zip(&mut self.m).zip(&mut self.v) {
            *m = beta1 * *m + (1.0 - beta1) * g;
            *v = beta2 * *v + (1.0 - beta2) * g * g;
            *p -= step * *m / (v.sqrt() / bc2_sqrt + eps);
        }
    }
}

/// Clamps every element of `grad` to `[-c, c]` (the reference's `grad.clamp_(-1, 1)`).
pub fn clamp_elementwise(grad: &mut [f32], c: f32) {
    for g in grad {
        *g = g.clamp(-c, c);
    }
}

/// `target <- tau * online + (1 - tau) * target`.
pub fn polyak(target: &mut [f32], online: &[f32], tau: f32) {
    assert_eq!(target.len(), online.len(), "polyak between networks of different sizes");
    for (t, o) in target.iter_mut().zip(online) {
        *t += tau * (o - *t);
    }
}
