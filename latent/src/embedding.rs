//! The time-contrastive image embedding (thesis Eq. 4.1, 4.2): an autoencoder whose code is
//! pulled together for consecutive frames and pushed at least a margin apart for random ones.
//!
//! - Encoder E: three 3x3 convolutions of stride 2 with ReLU (64 -> 32 -> 16 -> 8), a linear
//!   layer to `latent` (20) and L2 normalisation, so codes lie on the unit sphere.
//! - Decoder D: the mirror: a linear layer with ReLU back to the last feature map, then three
//!   3x3 transposed convolutions of stride 2 (ReLU between, none after).
//! - Per triple (frame t, frame t+1, a random frame r), averaged over the batch:
//!   `L = mean_pixels (x_t - D(E(x_t)))^2 + |E(x_t) - E(x_t+1)|^2 + max(margin - |E(x_t) - E(x_r)|, 0)`.
//!   The contrastive terms reach only the encoder (the decoder never sees them).
//!
//! The thesis leaves open what is chosen here (and stated in the config): 32 channels per
//! convolution, the margin 1.0 (codes on the unit sphere are at most 2 apart; orthogonal ones
//! sqrt(2)), the squared distance for the pull and the plain distance for the push, and the mean
//! squared pixel error for the reconstruction.
//!
//! Parameters: the encoder's in one flat buffer (conv1, conv2, conv3, linear; each in PyTorch's
//! layout), the decoder's in another (linear, deconv1, deconv2, deconv3).

use coadapt_nn::{Activations, Conv2d, ConvScratch, ConvTranspose2d, Mlp, NnError, Precision};

/// The embedding's shape and loss settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct EmbeddingConfig {
    /// Side of the square input images.
    pub image: usize,
    /// Channels of one input image (3: RGB).
    pub in_channels: usize,
    /// Channels of the three convolutions.
    pub channels: [usize; 3],
    pub latent: usize,
    /// Random frames are pushed at least this far from the anchor's code.
    pub margin: f32,
}

impl Default for EmbeddingConfig {
    fn default() -> Self {
        Self { image: 64, in_channels: 3, channels: [32, 32, 32], latent: 20, margin: 1.0 }
    }
}

/// The networks' shapes and where each layer's parameters start.
#[derive(Clone, Debug)]
pub struct Embedding {
    pub cfg: EmbeddingConfig,
    conv: [Conv2d; 3],
    fc: Mlp,
    dfc: Mlp,
    deconv: [ConvTranspose2d; 3],
    /// Offsets in the encoder's buffer: conv1, conv2, conv3, fc, end.
    enc_at: [usize; 5],
    /// Offsets in the decoder's buffer: dfc, deconv1, deconv2, deconv3, end.
    dec_at: [usize; 5],
}

/// The loss's parts, batch means.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossParts {
    pub reconstruction: f32,
    pub pull: f32,
    pub push: f32,
}

impl LossParts {
    pub fn total(&self) -> f32 {
        self.reconstruction + self.pull + self.push
    }
}

/// Buffers of the passes, grown to the largest batch and reused.
#[derive(Debug, Default)]
pub struct EmbeddingWork {
    /// Encoder: the three feature maps after ReLU, the linear output, the codes, their norms.
    a: [Vec<f32>; 3],
    h: Vec<f32>,
    z: Vec<f32>,
    norm: Vec<f32>,
    fc_act: Activations,
    /// Decoder: the linear layer's output after ReLU, two feature maps after ReLU, the images.
    u: Vec<f32>,
    b: [Vec<f32>; 2],
    y: Vec<f32>,
    dfc_act: Activations,
    /// Backward scratch.
    d: [Vec<f32>; 2],
    dz: Vec<f32>,
    dzd: Vec<f32>,
    dh: Vec<f32>,
    grad_tmp: Vec<f32>,
    scratch: ConvScratch,
}

fn grow(v: &mut Vec<f32>, n: usize) -> &mut [f32] {
    if v.len() < n {
        v.resize(n, 0.0);
    }
    &mut v[..n]
}

fn relu(v: &mut [f32]) {
    v.iter_mut().for_each(|x| *x = x.max(0.0));
}

/// dL/d(pre-activation) from dL/d(post-ReLU output), where the output was `out`.
fn relu_back(d: &mut [f32], out: &[f32]) {
    coadapt_nn::simd::relu_backward(d, out);
}

impl Embedding {
    pub fn new(cfg: EmbeddingConfig) -> Result<Self, NnError> {
        let [c1, c2, c3] = cfg.channels;
        let s = cfg.image;
        let conv1 = Conv2d::new(cfg.in_channels, c1, 3, 2, 1, s, s)?;
        let (_, h1, w1) = conv1.out_shape();
        let conv2 = Conv2d::new(c1, c2, 3, 2, 1, h1, w1)?;
        let (_, h2, w2) = conv2.out_shape();
        let conv3 = Conv2d::new(c2, c3, 3, 2, 1, h2, w2)?;
        let (_, h3, w3) = conv3.out_shape();
        let flat = c3 * h3 * w3;
        let fc = Mlp::new(&[flat, cfg.latent])?;
        let dfc = Mlp::new(&[cfg.latent, flat])?;
        // Mirror the shapes back: output padding where the stride-2 convolution rounded down.
        let op = |big: usize, small: usize| big + 2 - 3 - 2 * (small - 1);
        let deconv1 = ConvTranspose2d::new(c3, c2, 3, 2, 1, op(h2, h3), h3, w3)?;
        let deconv2 = ConvTranspose2d::new(c2, c1, 3, 2, 1, op(h1, h2), h2, w2)?;
        let deconv3 = ConvTranspose2d::new(c1, cfg.in_channels, 3, 2, 1, op(s, h1), h1, w1)?;
        if deconv3.out_shape() != (cfg.in_channels, s, s) {
            return Err(NnError::Shape { sizes: vec![s], why: "the decoder does not mirror the encoder for this image size" });
        }
        let conv = [conv1, conv2, conv3];
        let mut enc_at = [0; 5];
        for (i, c) in conv.iter().enumerate() {
            enc_at[i + 1] = enc_at[i] + c.n_params();
        }
        enc_at[4] = enc_at[3] + fc.n_params();
        let deconv = [deconv1, deconv2, deconv3];
        let mut dec_at = [0; 5];
        dec_at[1] = dfc.n_params();
        for (i, d) in deconv.iter().enumerate() {
            dec_at[i + 2] = dec_at[i + 1] + d.n_params();
        }
        Ok(Self { cfg, conv, fc, dfc, deconv, enc_at, dec_at })
    }

    /// The same networks with every product in `precision` (f32 by default; bf16: bf16
    /// operands with f32 accumulation on CPUs with AVX-512 BF16 or AMX, f32 elsewhere).
    /// Parameters and their layout do not change: an embedding trained in one precision loads
    /// in the other.
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.conv = self.conv.map(|c| c.with_precision(precision));
        self.deconv = self.deconv.map(|d| d.with_precision(precision));
        self.fc = self.fc.with_precision(precision);
        self.dfc = self.dfc.with_precision(precision);
        self
    }

    pub fn encoder_params(&self) -> usize {
        self.enc_at[4]
    }

    pub fn decoder_params(&self) -> usize {
        self.dec_at[4]
    }

    /// Values of one input image.
    pub fn image_len(&self) -> usize {
        self.conv[0].in_len()
    }

    /// Initialises both buffers as PyTorch's defaults do (uniform in +-1/sqrt(fan_in)).
    pub fn init<R: rand::Rng + ?Sized>(&self, enc: &mut [f32], dec: &mut [f32], rng: &mut R) {
        let mut fill = |buf: &mut [f32], fan_in: usize| {
            let b = 1.0 / (fan_in as f32).sqrt();
            buf.iter_mut().for_each(|p| *p = rng.random_range(-b..=b));
        };
        for (i, c) in self.conv.iter().enumerate() {
            fill(&mut enc[self.enc_at[i]..self.enc_at[i + 1]], c.c_in * 9);
        }
        fill(&mut enc[self.enc_at[3]..self.enc_at[4]], self.fc.n_in());
        fill(&mut dec[..self.dec_at[1]], self.cfg.latent);
        for (i, d) in self.deconv.iter().enumerate() {
            // PyTorch's ConvTranspose2d takes its fan-in from weight.size(1) * k * k = c_out * 9.
            fill(&mut dec[self.dec_at[i + 1]..self.dec_at[i + 2]], d.c_out * 9);
        }
    }

    /// Codes of `n` images (`n x image_len`), `n x latent`, unit length; keeps what the
    /// backward pass needs in `w`.
    pub fn encode<'a>(&self, enc: &[f32], x: &[f32], n: usize, w: &'a mut EmbeddingWork) -> &'a [f32] {
        let at = &self.enc_at;
        for i in 0..3 {
            let len = n * self.conv[i].out_len();
            let (done, rest) = w.a.split_at_mut(i);
            let input: &[f32] = if i == 0 { x } else { &done[i - 1] };
            let out = grow(&mut rest[0], len);
            self.conv[i].forward(&enc[at[i]..at[i + 1]], input, n, out, &mut w.scratch);
            relu(out);
        }
        let l = self.cfg.latent;
        let flat = self.fc.n_in();
        let h = self.fc.forward(&enc[at[3]..at[4]], &w.a[2][..n * flat], n, &mut w.fc_act);
        grow(&mut w.h, n * l).copy_from_slice(h);
        let z = grow(&mut w.z, n * l);
        let norm = grow(&mut w.norm, n);
        for ((zr, hr), nr) in z.chunks_exact_mut(l).zip(w.h.chunks_exact(l)).zip(norm.iter_mut()) {
            *nr = hr.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
            zr.iter_mut().zip(hr).for_each(|(a, b)| *a = b / *nr);
        }
        &w.z[..n * l]
    }

    /// Backward of [`Embedding::encode`] (same `x`, `n`): `dz` is dL/d(codes); adds dL/d(params)
    /// into `grad` (`encoder_params` long).
    pub fn encode_backward(&self, enc: &[f32], x: &[f32], n: usize, dz: &[f32], grad: &mut [f32], w: &mut EmbeddingWork) {
        let (l, at) = (self.cfg.latent, &self.enc_at);
        // Through the normalisation: dh = (dz - z (z . dz)) / |h|.
        let dh = grow(&mut w.dh, n * l);
        for i in 0..n {
            let (z, d) = (&w.z[i * l..(i + 1) * l], &dz[i * l..(i + 1) * l]);
            let zd: f32 = z.iter().zip(d).map(|(a, b)| a * b).sum();
            for k in 0..l {
                dh[i * l + k] = (d[k] - z[k] * zd) / w.norm[i];
            }
        }
        let flat = self.fc.n_in();
        let mut cur = std::mem::take(&mut w.d[0]);
        let mut next = std::mem::take(&mut w.d[1]);
        let gt = grow(&mut w.grad_tmp, self.fc.n_params());
        self.fc.backward(
            &enc[at[3]..at[4]],
            &w.a[2][..n * flat],
            &mut w.fc_act,
            0..n,
            &w.dh[..n * l],
            Some(gt),
            Some(grow(&mut cur, n * flat)),
        );
        grad[at[3]..at[4]].iter_mut().zip(w.grad_tmp.iter()).for_each(|(g, t)| *g += t);
        // Down the convolutions, `cur` holding dL/d(output of layer i).
        for i in (0..3).rev() {
            let len = n * self.conv[i].out_len();
            relu_back(&mut cur[..len], &w.a[i][..len]);
            let input: &[f32] = if i == 0 { x } else { &w.a[i - 1] };
            let dx = if i == 0 { None } else { Some(grow(&mut next, n * self.conv[i].in_len())) };
            self.conv[i].backward(&enc[at[i]..at[i + 1]], input, n, &cur[..len], Some(&mut grad[at[i]..at[i + 1]]), dx, &mut w.scratch);
            std::mem::swap(&mut cur, &mut next);
        }
        w.d = [cur, next];
    }

    /// Images of `n` codes (`n x latent`), `n x image_len`.
    pub fn decode<'a>(&self, dec: &[f32], z: &[f32], n: usize, w: &'a mut EmbeddingWork) -> &'a [f32] {
        let at = &self.dec_at;
        let flat = self.dfc.n_out();
        let u = self.dfc.forward(&dec[..at[1]], z, n, &mut w.dfc_act);
        let ub = grow(&mut w.u, n * flat);
        ub.copy_from_slice(u);
        relu(ub);
        let len0 = n * self.deconv[0].out_len();
        self.deconv[0].forward(&dec[at[1]..at[2]], &w.u[..n * flat], n, grow(&mut w.b[0], len0), &mut w.scratch);
        relu(&mut w.b[0][..len0]);
        let len1 = n * self.deconv[1].out_len();
        let (b0, b1) = w.b.split_at_mut(1);
        self.deconv[1].forward(&dec[at[2]..at[3]], &b0[0][..len0], n, grow(&mut b1[0], len1), &mut w.scratch);
        relu(&mut w.b[1][..len1]);
        let len2 = n * self.deconv[2].out_len();
        self.deconv[2].forward(&dec[at[3]..at[4]], &w.b[1][..len1], n, grow(&mut w.y, len2), &mut w.scratch);
        &w.y[..len2]
    }

    /// Backward of [`Embedding::decode`] (same `z`, `n`): `dy` is dL/d(images); adds
    /// dL/d(params) into `grad` and writes dL/dz into `dz`.
    #[allow(clippy::too_many_arguments)]
    pub fn decode_backward(&self, dec: &[f32], z: &[f32], n: usize, dy: &[f32], grad: &mut [f32], dz: &mut [f32], w: &mut EmbeddingWork) {
        let at = &self.dec_at;
        let flat = self.dfc.n_out();
        let (len0, len1) = (n * self.deconv[0].out_len(), n * self.deconv[1].out_len());
        let [da, db] = &mut w.d;
        let d1 = grow(da, len1);
        self.deconv[2].backward(&dec[at[3]..at[4]], &w.b[1][..len1], n, dy, Some(&mut grad[at[3]..at[4]]), Some(d1), &mut w.scratch);
        relu_back(d1, &w.b[1][..len1]);
        let d0 = grow(db, len0);
        self.deconv[1].backward(&dec[at[2]..at[3]], &w.b[0][..len0], n, d1, Some(&mut grad[at[2]..at[3]]), Some(d0), &mut w.scratch);
        relu_back(d0, &w.b[0][..len0]);
        let du = grow(da, n * flat);
        self.deconv[0].backward(&dec[at[1]..at[2]], &w.u[..n * flat], n, d0, Some(&mut grad[at[1]..at[2]]), Some(du), &mut w.scratch);
        relu_back(du, &w.u[..n * flat]);
        let gt = grow(&mut w.grad_tmp, self.dfc.n_params());
        self.dfc.backward(&dec[..at[1]], z, &mut w.dfc_act, 0..n, du, Some(gt), Some(dz));
        grad[..at[1]].iter_mut().zip(gt.iter()).for_each(|(g, t)| *g += t);
    }

    /// Eq. 4.1-4.2 on `n` triples: `frames` holds the anchors, then their next frames, then the
    /// random frames (`3n x image_len`). Adds the gradients of the batch-mean loss into
    /// `grad_enc` and `grad_dec` and returns the loss's parts.
    #[allow(clippy::too_many_arguments)]
    pub fn loss_and_grad(
        &self,
        enc: &[f32],
        dec: &[f32],
        frames: &[f32],
        n: usize,
        grad_enc: &mut [f32],
        grad_dec: &mut [f32],
        w: &mut EmbeddingWork,
    ) -> LossParts {
        let (l, px) = (self.cfg.latent, self.image_len());
        assert!(frames.len() >= 3 * n * px, "frames: 3n images expected");
        self.encode(enc, frames, 3 * n, w);
        let mut z = std::mem::take(&mut w.z);
        self.decode(dec, &z[..n * l], n, w);
        let inv_n = 1.0 / n as f32;
        let mut parts = LossParts::default();
        // Reconstruction: mean squared pixel error per image, averaged over the batch.
        let scale = inv_n / px as f32;
        let mut dy = std::mem::take(&mut w.y);
        for (y, x) in dy[..n * px].iter_mut().zip(&frames[..n * px]) {
            let e = *y - x;
            parts.reconstruction += e * e * scale;
            *y = 2.0 * e * scale;
        }
        let mut dz = std::mem::take(&mut w.dz);
        grow(&mut dz, 3 * n * l).fill(0.0);
        let mut dzd = std::mem::take(&mut w.dzd);
        grow(&mut dzd, n * l);
        self.decode_backward(dec, &z[..n * l], n, &dy[..n * px], grad_dec, &mut dzd[..n * l], w);
        dz[..n * l].copy_from_slice(&dzd[..n * l]);
        for i in 0..n {
            let (a, p, r) = (i * l, (n + i) * l, (2 * n + i) * l);
            // Pull: |z_t - z_t+1|^2.
            for k in 0..l {
                let d = z[a + k] - z[p + k];
                parts.pull += d * d * inv_n;
                dz[a + k] += 2.0 * d * inv_n;
                dz[p + k] -= 2.0 * d * inv_n;
            }
            // Push: max(margin - |z_t - z_r|, 0).
            let dist = (0..l).map(|k| (z[a + k] - z[r + k]).powi(2)).sum::<f32>().sqrt();
            if dist < self.cfg.margin {
                parts.push += (self.cfg.margin - dist) * inv_n;
                if dist > 1e-12 {
                    for k in 0..l {
                        let g = -(z[a + k] - z[r + k]) / dist * inv_n;
                        dz[a + k] += g;
                        dz[r + k] -= g;
                    }
                }
            }
        }
        // The encoder's pass over all 3n images is still in `w` (the decoder did not touch it).
        std::mem::swap(&mut z, &mut w.z);
        self.encode_backward(enc, frames, 3 * n, &dz[..3 * n * l], grad_enc, w);
        (w.dz, w.dzd, w.y) = (dz, dzd, dy);
        parts
    }
}
