//! Latent design-dependent action spaces (thesis section 6.2, Eq. 6.1).
//!
//! An encoder `e(a, s, xi) = z` and a decoder `d(z, s, xi) = a~`, trained on experience from many
//! designs with the Q-weighted reconstruction loss
//!
//! ```text
//!     L = (1/N) sum_i || a_i - d(e(a_i, s_i, xi_i), s_i, xi_i) ||_2 * w_i,    w_i = max(Q(s_i, a_i, xi_i), 0)
//! ```
//!
//! Eq. 6.1 sums over the data; the mean keeps the step size independent of the batch. The norm
//! is the Euclidean norm itself, not its square, as the thesis writes it. The weights are
//! numbers per transition (the critic is evaluated once; no gradient flows into it): actions the
//! critic finds worthless are not worth reconstructing. The decoder ends in `tanh`, so a decoded
//! action lies in the action box `[-1, 1]`; the latent code is unbounded (the encoder ends
//! linear) and 2-D by default, so it can be drawn (thesis Fig. 6.1, 6.2).
//!
//! Both networks read the learner's observation, which is the state with the design appended,
//! so `(s, xi)` is one input `o` here: `e([a, o])`, `d([z, o])`.
//!
//! Correlated exploration, the proposed use: [`ActionAutoencoder::explore`] gives
//! `a~ = pi(s) + beta (d(z, s, xi) - d(0, s, xi))`, `z ~ N(0, I)`, clipped to the box. Taken
//! literally the thesis's `a~ = pi(s) + d(z, s, xi)` adds a whole decoded action to the policy's
//! (about twice an action); the difference from the decoded action at `z = 0` is a perturbation
//! that is zero on average around `z = 0` and moves along the directions the decoder spans.

use coadapt_nn::{Activations, Adam, AdamConfig, Mlp, NnError};
use serde::{Deserialize, Serialize};

/// The last layers' initial scale (uniform in +-3e-3, as SAC's): z and a~ start near 0.
const FINAL_INIT: f32 = 3e-3;

/// The autoencoder's settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct ActionSpaceConfig {
    /// Dimensions of the latent code z (the thesis draws 2).
    pub latent_dim: usize,
    /// Hidden layers of the encoder and of the decoder (ReLU).
    pub hidden: Vec<usize>,
    /// Adam's step size for both networks.
    pub learning_rate: f32,
    /// Transitions per update.
    pub batch_size: usize,
}

impl Default for ActionSpaceConfig {
    fn default() -> Self {
        Self { latent_dim: 2, hidden: vec![64, 64], learning_rate: 1e-3, batch_size: 256 }
    }
}

/// The weights of Eq. 6.1 from critic values: `max(Q, 0)`.
pub fn weights(q: &[f32]) -> Vec<f32> {
    q.iter().map(|v| v.max(0.0)).collect()
}

/// The encoder and decoder of Eq. 6.1 with their optimisers and workspaces.
#[derive(Debug)]
pub struct ActionAutoencoder {
    pub cfg: ActionSpaceConfig,
    obs_dim: usize,
    act_dim: usize,
    enc: Mlp,
    dec: Mlp,
    theta_e: Vec<f32>,
    theta_d: Vec<f32>,
    adam_e: Adam,
    adam_d: Adam,
    grad_e: Vec<f32>,
    grad_d: Vec<f32>,
    // Workspaces, grown to the largest batch seen: the update allocates nothing after that.
    enc_in: Vec<f32>,
    dec_in: Vec<f32>,
    act_e: Activations,
    act_d: Activations,
    decoded: Vec<f32>,
    dy: Vec<f32>,
    dx_dec: Vec<f32>,
    dz: Vec<f32>,
}

fn sizes(n_in: usize, hidden: &[usize], n_out: usize) -> Vec<usize> {
    let mut s = vec![n_in];
    s.extend_from_slice(hidden);
    s.push(n_out);
    s
}

/// Rows of `[a, b]`, `a` being `rows x na` and `b` `rows x nb`, into `out`.
fn concat_rows(a: &[f32], na: usize, b: &[f32], nb: usize, rows: usize, out: &mut Vec<f32>) {
    out.clear();
    for r in 0..rows {
        out.extend_from_slice(&a[r * na..(r + 1) * na]);
        out.extend_from_slice(&b[r * nb..(r + 1) * nb]);
    }
}

impl ActionAutoencoder {
    /// An autoencoder for observations (state and design) of `obs_dim` and actions of `act_dim`.
    pub fn new(obs_dim: usize, act_dim: usize, cfg: ActionSpaceConfig, seed: u64) -> Result<Self, NnError> {
        if cfg.latent_dim == 0 {
            return Err(NnError::Shape { sizes: vec![0], why: "latent-dim must be at least 1" });
        }
        let enc = Mlp::new(&sizes(act_dim + obs_dim, &cfg.hidden, cfg.latent_dim))?;
        let dec = Mlp::new(&sizes(cfg.latent_dim + obs_dim, &cfg.hidden, act_dim))?;
        let mut rng = coadapt_core::rng(seed, 0x4145);
        let (mut theta_e, mut theta_d) = (enc.zeros(), dec.zeros());
        enc.init(&mut theta_e, FINAL_INIT, &mut rng);
        dec.init(&mut theta_d, FINAL_INIT, &mut rng);
        let adam = AdamConfig { lr: cfg.learning_rate, ..AdamConfig::default() };
        Ok(Self {
            obs_dim,
            act_dim,
            adam_e: Adam::new(enc.n_params(), adam),
            adam_d: Adam::new(dec.n_params(), adam),
            grad_e: enc.zeros(),
            grad_d: dec.zeros(),
            act_e: enc.activations(1),
            act_d: dec.activations(1),
            enc,
            dec,
            theta_e,
            theta_d,
            enc_in: Vec::new(),
            dec_in: Vec::new(),
            decoded: Vec::new(),
            dy: Vec::new(),
            dx_dec: Vec::new(),
            dz: Vec::new(),
            cfg,
        })
    }

    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    pub fn latent_dim(&self) -> usize {
        self.cfg.latent_dim
    }

    pub fn encoder(&self) -> (&Mlp, &[f32]) {
        (&self.enc, &self.theta_e)
    }

    pub fn decoder(&self) -> (&Mlp, &[f32]) {
        (&self.dec, &self.theta_d)
    }

    /// Replaces both networks' parameters (a loaded file, a test's fixed values).
    pub fn set_params(&mut self, theta_e: &[f32], theta_d: &[f32]) {
        assert_eq!((theta_e.len(), theta_d.len()), (self.enc.n_params(), self.dec.n_params()), "parameter counts");
        self.theta_e.copy_from_slice(theta_e);
        self.theta_d.copy_from_slice(theta_d);
    }

    /// The gradients of the last [`Self::loss_and_gradients`]: (encoder, decoder).
    pub fn gradients(&self) -> (&[f32], &[f32]) {
        (&self.grad_e, &self.grad_d)
    }

    fn grow(&mut self, rows: usize) {
        if self.act_e.rows() < rows {
            self.act_e = self.enc.activations(rows);
            self.act_d = self.dec.activations(rows);
        }
    }

    /// z = e(a, o) for `rows` rows (`obs`: rows x obs_dim, `act`: rows x act_dim).
    pub fn encode(&mut self, obs: &[f32], act: &[f32], rows: usize) -> Vec<f32> {
        self.grow(rows);
        concat_rows(act, self.act_dim, obs, self.obs_dim, rows, &mut self.enc_in);
        self.enc.forward(&self.theta_e, &self.enc_in, rows, &mut self.act_e).to_vec()
    }

    /// a~ = d(z, o) for `rows` rows (`z`: rows x latent_dim), in the action box.
    pub fn decode(&mut self, obs: &[f32], z: &[f32], rows: usize) -> Vec<f32> {
        self.grow(rows);
        concat_rows(z, self.cfg.latent_dim, obs, self.obs_dim, rows, &mut self.dec_in);
        self.dec.forward(&self.theta_d, &self.dec_in, rows, &mut self.act_d).iter().map(|v| v.tanh()).collect()
    }

    /// The loss of Eq. 6.1 over `rows` transitions (`weight`: max(Q, 0) of each), and its
    /// gradients with respect to both networks (read them with [`Self::gradients`]).
    pub fn loss_and_gradients(&mut self, obs: &[f32], act: &[f32], weight: &[f32], rows: usize) -> f64 {
        let (na, nz, no) = (self.act_dim, self.cfg.latent_dim, self.obs_dim);
        assert_eq!((obs.len(), act.len(), weight.len()), (rows * no, rows * na, rows), "batch shapes");
        self.grow(rows);
        // Forward: z = e([a, o]); a~ = tanh(d([z, o])).
        concat_rows(act, na, obs, no, rows, &mut self.enc_in);
        let z = self.enc.forward(&self.theta_e, &self.enc_in, rows, &mut self.act_e);
        concat_rows(z, nz, obs, no, rows, &mut self.dec_in);
        let pre = self.dec.forward(&self.theta_d, &self.dec_in, rows, &mut self.act_d);
        self.decoded.clear();
        self.decoded.extend(pre.iter().map(|v| v.tanh()));
        // L = (1/N) sum_i w_i ||a_i - a~_i||; dL/da~_i = -(w_i / N) (a_i - a~_i) / ||a_i - a~_i||,
        // through tanh: times (1 - a~^2). A row reconstructed exactly has no gradient (the norm's
        // subgradient at 0 is taken as 0).
        let inv_n = 1.0 / rows as f64;
        let mut loss = 0.0f64;
        self.dy.clear();
        self.dy.resize(rows * na, 0.0);
        for i in 0..rows {
            let (a, d) = (&act[i * na..(i + 1) * na], &self.decoded[i * na..(i + 1) * na]);
            let norm = a.iter().zip(d).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>().sqrt();
            let w = f64::from(weight[i]);
            loss += w * norm * inv_n;
            if norm > 0.0 {
                for k in 0..na {
                    let r = f64::from(a[k] - d[k]);
                    self.dy[i * na + k] = (-(w * inv_n) * r / norm * (1.0 - f64::from(d[k]).powi(2))) as f32;
                }
            }
        }
        // Backward: the decoder's parameters and its input ([z, o]); the z part goes on into the
        // encoder.
        self.dx_dec.clear();
        self.dx_dec.resize(rows * (nz + no), 0.0);
        self.dec.backward(&self.theta_d, &self.dec_in, &mut self.act_d, 0..rows, &self.dy, Some(&mut self.grad_d), Some(&mut self.dx_dec));
        self.dz.clear();
        for i in 0..rows {
            self.dz.extend_from_slice(&self.dx_dec[i * (nz + no)..i * (nz + no) + nz]);
        }
        self.enc.backward(&self.theta_e, &self.enc_in, &mut self.act_e, 0..rows, &self.dz, Some(&mut self.grad_e), None);
        loss
    }

    /// One Adam step on both networks from a batch; returns the batch's loss before the step.
    pub fn update(&mut self, obs: &[f32], act: &[f32], weight: &[f32], rows: usize) -> f64 {
        let loss = self.loss_and_gradients(obs, act, weight, rows);
        self.adam_e.step(&mut self.theta_e, &self.grad_e);
        self.adam_d.step(&mut self.theta_d, &self.grad_d);
        loss
    }

    /// Correlated exploration around the policy's action `pi` at observation `obs`:
    /// `pi + beta (d(z, o) - d(0, o))`, clipped to `[-1, 1]`, for one latent draw `z`.
    pub fn explore(&mut self, obs: &[f32], pi: &[f32], z: &[f32], beta: f32) -> Vec<f32> {
        let mut out = vec![0.0; self.act_dim];
        self.explore_into(obs, pi, z, beta, &mut out);
        out
    }

    /// [`Self::explore`] into `out` (`act_dim`), allocating nothing once the decoder's workspace
    /// holds two rows: what an acting loop calls every step.
    pub fn explore_into(&mut self, obs: &[f32], pi: &[f32], z: &[f32], beta: f32, out: &mut [f32]) {
        let (n, nz) = (self.act_dim, self.cfg.latent_dim);
        assert_eq!((obs.len(), pi.len(), z.len(), out.len()), (self.obs_dim, n, nz, n), "explore shapes");
        self.grow(2);
        // Rows [z, o] and [0, o] of the decoder's input, in its workspace.
        self.dec_in.clear();
        self.dec_in.extend_from_slice(z);
        self.dec_in.extend_from_slice(obs);
        self.dec_in.resize(self.dec_in.len() + nz, 0.0);
        self.dec_in.extend_from_slice(obs);
        let pre = self.dec.forward(&self.theta_d, &self.dec_in, 2, &mut self.act_d);
        for (k, o) in out.iter_mut().enumerate() {
            *o = (pi[k] + beta * (pre[k].tanh() - pre[n + k].tanh())).clamp(-1.0, 1.0);
        }
    }

    #[doc(hidden)]
    /// Test hook: which hidden ReLU units were active in the last forward pass of the encoder
    /// and the decoder (a finite difference that flips one straddles a kink).
    pub fn relu_pattern(&self, rows: usize) -> Vec<bool> {
        let mut out = Vec::new();
        for (mlp, act) in [(&self.enc, &self.act_e), (&self.dec, &self.act_d)] {
            for (i, l) in mlp.layers().iter().enumerate().take(mlp.layers().len() - 1) {
                out.extend(act.layer_output(i)[..rows * l.n_out].iter().map(|v| *v > 0.0));
            }
        }
        out
    }

    /// The autoencoder in `path` (written by [`Self::save`]), its latent and hidden sizes read
    /// from the file; refused unless it reads observations of `obs_dim` and actions of `act_dim`.
    pub fn from_file(path: &std::path::Path, obs_dim: usize, act_dim: usize) -> Result<Self, NnError> {
        let nets = coadapt_nn::load_networks(path)?;
        let enc = nets.iter().find(|n| n.name == "encoder").ok_or_else(|| NnError::MissingNetwork {
            path: path.display().to_string(),
            name: "encoder".into(),
            available: nets.iter().map(|n| n.name.clone()).collect::<Vec<_>>().join(", "),
        })?;
        let sizes = enc.mlp.sizes();
        let (latent_dim, hidden) = (sizes[sizes.len() - 1], sizes[1..sizes.len() - 1].to_vec());
        if sizes[0] != act_dim + obs_dim {
            return Err(NnError::ShapeMismatch {
                path: path.display().to_string(),
                name: "encoder".into(),
                found: sizes.to_vec(),
                expected: [vec![act_dim + obs_dim], hidden, vec![latent_dim]].concat(),
            });
        }
        let mut ae = Self::new(obs_dim, act_dim, ActionSpaceConfig { latent_dim, hidden, ..ActionSpaceConfig::default() }, 0)?;
        ae.load(path)?;
        Ok(ae)
    }

    /// Writes both networks to one safetensors file (`encoder`, `decoder`).
    pub fn save(&self, path: &std::path::Path) -> Result<(), NnError> {
        coadapt_nn::save_networks(path, &[("encoder", &self.enc, &self.theta_e), ("decoder", &self.dec, &self.theta_d)])
    }

    /// Loads what [`Self::save`] wrote; the shapes must be this autoencoder's.
    pub fn load(&mut self, path: &std::path::Path) -> Result<(), NnError> {
        let nets = coadapt_nn::load_networks(path)?;
        let e = coadapt_nn::NamedNetwork::find(&nets, path, "encoder", self.enc.sizes())?.params.clone();
        let d = coadapt_nn::NamedNetwork::find(&nets, path, "decoder", self.dec.sizes())?.params.clone();
        self.set_params(&e, &d);
        Ok(())
    }
}
