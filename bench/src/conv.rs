//! `coadapt bench conv`: the convolutions of the thesis's image embedding (issue 15, DDPG from
//! pixels) on 64x64 RGB frames, timed per layer and as the whole encoder and decoder stacks,
//! forward alone and forward + backward (the weights' and the input's gradients), at batch 32
//! and 1. The peer is PyTorch on the same shapes (bench/peers/conv_bench.py).
//!
//! The shapes are those `Embedding::new(EmbeddingConfig::default())` builds (latent/src/
//! embedding.rs): 3x3 kernels, stride 2, padding 1; convolutions 3->32 (64->32), 32->32
//! (32->16), 32->32 (16->8) and the mirrored transposed convolutions 32->32 (8->16), 32->32
//! (16->32), 32->3 (32->64), each with output padding 1. The "encoder" and "decoder" figures
//! chain the three layers of each side alone (no ReLU, no linear layer), on both sides.
//!
//! Parameters, inputs and output gradients are drawn once per figure, before anything is timed;
//! the buffers are allocated and the scratch warmed by the untimed repetitions. Each repetition
//! times one call (forward, or forward then backward) on its own; median, p10, p90. Single
//! thread: the layers' GEMMs run with faer's `Par::Seq`. `--dump FILE` writes every layer's
//! shape, parameters, input, output gradient and our output, parameter gradient and input
//! gradient at batch 2, for the peer's `--check` (the peer also reads the shapes from it).

use std::path::PathBuf;
use std::time::Instant;

use coadapt_latent::EmbeddingConfig;
use coadapt_nn::{Conv2d, ConvScratch, ConvTranspose2d, NnError, Precision};
use rand::Rng;
use serde_json::json;

use crate::figure::percentile;
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ConvOptions {
    /// Timed repetitions per figure (each one call on its own).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 100))]
    pub repetitions: usize,
    /// Untimed calls before the timed ones, per figure.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 10))]
    pub warmup: usize,
    /// Batch sizes, comma-separated.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![32usize, 1]))]
    pub batch: Vec<usize>,
    /// Time only the figures whose config contains this (e.g. `conv2`, `encoder`).
    #[cfg_attr(feature = "clap", arg(long))]
    pub only: Option<String>,
    /// Seed of the random parameters and inputs.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Write every layer's shape, inputs and our outputs (batch 2) to this JSON file first.
    #[cfg_attr(feature = "clap", arg(long))]
    pub dump: Option<PathBuf>,
    /// With --dump: write the file and time nothing.
    #[cfg_attr(feature = "clap", arg(long))]
    pub dump_only: bool,
    /// The products' arithmetic: f32, or bf16 operands with f32 accumulation (on a CPU with
    /// AVX-512 BF16 or AMX; f32 elsewhere). The figures' config names end in `-bf16`, and the
    /// dump holds the bf16 outputs.
    #[cfg_attr(feature = "clap", arg(long, default_value = "f32"))]
    pub precision: Precision,
}

/// One layer's shape, as PyTorch's constructor takes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Spec {
    pub name: &'static str,
    pub transposed: bool,
    pub c_in: usize,
    pub c_out: usize,
    pub k: usize,
    pub stride: usize,
    pub pad: usize,
    pub output_padding: usize,
    /// The input's sides.
    pub h: usize,
    pub w: usize,
}

/// A built layer of either kind.
#[derive(Clone, Debug)]
pub struct Layer {
    pub spec: Spec,
    conv: Result<Conv2d, ConvTranspose2d>,
}

impl Layer {
    pub fn new(spec: Spec) -> Result<Self, NnError> {
        let Spec { c_in, c_out, k, stride, pad, output_padding, h, w, .. } = spec;
        let conv = if spec.transposed {
            Err(ConvTranspose2d::new(c_in, c_out, k, stride, pad, output_padding, h, w)?)
        } else {
            Ok(Conv2d::new(c_in, c_out, k, stride, pad, h, w)?)
        };
        Ok(Self { spec, conv })
    }

    /// The same layer with its products in `precision`.
    pub fn with_precision(self, precision: Precision) -> Self {
        let conv = match self.conv {
            Ok(c) => Ok(c.with_precision(precision)),
            Err(t) => Err(t.with_precision(precision)),
        };
        Self { conv, ..self }
    }

    pub fn precision(&self) -> Precision {
        self.conv.as_ref().map_or_else(|t| t.precision(), |c| c.precision())
    }

    pub fn n_params(&self) -> usize {
        self.conv.as_ref().map_or_else(|t| t.n_params(), |c| c.n_params())
    }

    pub fn in_len(&self) -> usize {
        self.conv.as_ref().map_or_else(|t| t.in_len(), |c| c.in_len())
    }

    pub fn out_len(&self) -> usize {
        self.conv.as_ref().map_or_else(|t| t.out_len(), |c| c.out_len())
    }

    pub fn out_shape(&self) -> (usize, usize, usize) {
        self.conv.as_ref().map_or_else(|t| t.out_shape(), |c| c.out_shape())
    }

    /// Multiply-adds per image of a forward pass.
    pub fn macs(&self) -> usize {
        self.conv.as_ref().map_or_else(|t| t.macs(), |c| c.macs())
    }

    pub fn forward(&self, p: &[f32], x: &[f32], n: usize, out: &mut [f32], s: &mut ConvScratch) {
        match &self.conv {
            Ok(c) => c.forward(p, x, n, out, s),
            Err(t) => t.forward(p, x, n, out, s),
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub fn backward(&self, p: &[f32], x: &[f32], n: usize, dy: &[f32], g: Option<&mut [f32]>, dx: Option<&mut [f32]>, s: &mut ConvScratch) {
        match &self.conv {
            Ok(c) => c.backward(p, x, n, dy, g, dx, s),
            Err(t) => t.backward(p, x, n, dy, g, dx, s),
        }
    }

    /// `conv2-32to32-32to16`: name, channels in to out, input side to output side.
    pub fn config(&self) -> String {
        let (c, oh, _) = self.out_shape();
        format!("{}-{}to{}-{}to{}", self.spec.name, self.spec.c_in, c, self.spec.h, oh)
    }
}

/// The embedding's convolutions for `cfg` (as `Embedding::new` builds them): the encoder's
/// three, then the decoder's three.
pub fn embedding_layers(cfg: &EmbeddingConfig) -> Result<Vec<Layer>, NnError> {
    let [c1, c2, c3] = cfg.channels;
    let conv = |name, c_in, c_out, side| Spec {
        name,
        transposed: false,
        c_in,
        c_out,
        k: 3,
        stride: 2,
        pad: 1,
        output_padding: 0,
        h: side,
        w: side,
    };
    let l1 = Layer::new(conv("conv1", cfg.in_channels, c1, cfg.image))?;
    let s1 = l1.out_shape().1;
    let l2 = Layer::new(conv("conv2", c1, c2, s1))?;
    let s2 = l2.out_shape().1;
    let l3 = Layer::new(conv("conv3", c2, c3, s2))?;
    let s3 = l3.out_shape().1;
    // Embedding::new's output padding: where the stride-2 convolution rounded down.
    let op = |big: usize, small: usize| big + 2 - 3 - 2 * (small - 1);
    let deconv = |name, c_in, c_out, small, big| Spec {
        name,
        transposed: true,
        c_in,
        c_out,
        k: 3,
        stride: 2,
        pad: 1,
        output_padding: op(big, small),
        h: small,
        w: small,
    };
    let d1 = Layer::new(deconv("deconv1", c3, c2, s3, s2))?;
    let d2 = Layer::new(deconv("deconv2", c2, c1, s2, s1))?;
    let d3 = Layer::new(deconv("deconv3", c1, cfg.in_channels, s1, cfg.image))?;
    Ok(vec![l1, l2, l3, d1, d2, d3])
}

/// A chain of layers with its parameters, activations, gradients and scratch, for a batch.
#[derive(Debug)]
pub struct Stack<'a> {
    layers: &'a [Layer],
    n: usize,
    params: Vec<Vec<f32>>,
    /// `acts[0]` the input, `acts[i + 1]` layer i's output.
    acts: Vec<Vec<f32>>,
    /// dL/d(acts[i]); the last one is the output gradient, drawn at random.
    d: Vec<Vec<f32>>,
    grads: Vec<Vec<f32>>,
    scratch: ConvScratch,
}

impl<'a> Stack<'a> {
    /// Parameters uniform in +-1/sqrt(fan-in) (PyTorch's default bound), the input uniform in
    /// [0, 1) (pixels) or standard-ish features, the output gradient uniform in +-1.
    pub fn new<R: Rng + ?Sized>(layers: &'a [Layer], n: usize, rng: &mut R) -> Self {
        let params = layers
            .iter()
            .map(|l| {
                let fan_in = (if l.spec.transposed { l.spec.c_out } else { l.spec.c_in }) * l.spec.k * l.spec.k;
                let b = 1.0 / (fan_in as f32).sqrt();
                (0..l.n_params()).map(|_| rng.random_range(-b..b)).collect()
            })
            .collect();
        let mut acts = vec![(0..n * layers[0].in_len()).map(|_| rng.random_range(0.0..1.0f32)).collect::<Vec<f32>>()];
        let mut d = vec![vec![0.0; n * layers[0].in_len()]];
        for l in layers {
            acts.push(vec![0.0; n * l.out_len()]);
            d.push(vec![0.0; n * l.out_len()]);
        }
        if let Some(last) = d.last_mut() {
            last.iter_mut().for_each(|v| *v = rng.random_range(-1.0..1.0f32));
        }
        let grads = layers.iter().map(|l| vec![0.0; l.n_params()]).collect();
        Self { layers, n, params, acts, d, grads, scratch: ConvScratch::default() }
    }

    pub fn forward(&mut self) {
        for (i, l) in self.layers.iter().enumerate() {
            let (done, rest) = self.acts.split_at_mut(i + 1);
            l.forward(&self.params[i], &done[i], self.n, &mut rest[0], &mut self.scratch);
        }
    }

    /// The parameters' gradients (zeroed first, as one batch's) and every input's gradient,
    /// from the last layer down, after [`Stack::forward`].
    pub fn backward(&mut self) {
        for i in (0..self.layers.len()).rev() {
            let g = &mut self.grads[i];
            g.fill(0.0);
            let (below, above) = self.d.split_at_mut(i + 1);
            self.layers[i].backward(&self.params[i], &self.acts[i], self.n, &above[0], Some(g), Some(&mut below[i]), &mut self.scratch);
        }
    }

    /// Multiply-adds per batch of a forward pass.
    pub fn macs(&self) -> usize {
        self.n * self.layers.iter().map(Layer::macs).sum::<usize>()
    }
}

fn time_ms(reps: usize, warmup: usize, mut f: impl FnMut()) -> Vec<f64> {
    for _ in 0..warmup {
        f();
    }
    let mut ms: Vec<f64> = (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    ms
}

fn round(v: f64) -> f64 {
    (v * 1e4).round() / 1e4
}

/// One figure's JSON line: median ms, p10, p90, and the model GFLOP/s at the median
/// (`2 * MACs / time`; forward + backward counts three times the forward's MACs: the output,
/// the weights' gradient, the input's gradient).
pub fn line(bench: &str, config: &str, batch: usize, ms: &[f64], flops: f64, precision: Precision) -> serde_json::Value {
    let median = percentile(ms, 0.5);
    json!({
        "bench": bench,
        "config": config,
        "value": round(median),
        "unit": "ms",
        "impl": "coadapt",
        "p10": round(percentile(ms, 0.1)),
        "p90": round(percentile(ms, 0.9)),
        "gflop_s": round(flops / (median * 1e-3) / 1e9),
        "batch": batch,
        "repetitions": ms.len(),
        "threads": 1,
        "dtype": precision.name(),
    })
}

/// The figures: each layer alone, then the encoder's and the decoder's three together.
pub fn figures(layers: &[Layer]) -> Vec<(String, std::ops::Range<usize>)> {
    let mut v: Vec<_> = (0..layers.len()).map(|i| (layers[i].config(), i..i + 1)).collect();
    v.push(("encoder-3conv".into(), 0..3));
    v.push(("decoder-3deconv".into(), 3..6));
    v
}

pub fn run(a: &ConvOptions) -> Result<(), AppError> {
    if a.repetitions == 0 {
        return Err(AppError::Config("--repetitions must be at least 1".into()));
    }
    let layers: Vec<Layer> = embedding_layers(&EmbeddingConfig::default())?.into_iter().map(|l| l.with_precision(a.precision)).collect();
    if a.precision == Precision::Bf16 && !coadapt_nn::bf16::bf16_available() {
        coadapt_log::logln!("bench conv: this CPU has neither AVX-512 BF16 nor AMX: the bf16 figures run f32 products");
    }
    let suffix = if a.precision == Precision::Bf16 { "-bf16" } else { "" };
    if let Some(path) = &a.dump {
        std::fs::write(path, dump(&layers, 2, a.seed).to_string()).map_err(AppError::io(format!("writing {}", path.display())))?;
        coadapt_log::logln!("bench conv: shapes, inputs and outputs written to {}", path.display());
        if a.dump_only {
            return Ok(());
        }
    }
    let mut r = coadapt_core::rng(a.seed, 1);
    for &n in &a.batch {
        for (name, range) in figures(&layers) {
            if a.only.as_deref().is_some_and(|o| !name.contains(o)) {
                continue;
            }
            let config = format!("{name}-b{n}{suffix}");
            let mut s = Stack::new(&layers[range], n, &mut r);
            let flops = 2.0 * s.macs() as f64;
            let ms = time_ms(a.repetitions, a.warmup, || {
                s.forward();
                std::hint::black_box(&s.acts);
            });
            coadapt_log::print_stdout_line(&line("conv_forward", &config, n, &ms, flops, a.precision).to_string());
            let ms = time_ms(a.repetitions, a.warmup, || {
                s.forward();
                s.backward();
                std::hint::black_box((&s.grads, &s.d));
            });
            coadapt_log::print_stdout_line(&line("conv_forward_backward", &config, n, &ms, 3.0 * flops, a.precision).to_string());
        }
    }
    Ok(())
}

/// Every layer alone at batch `n`: its shape, parameters (PyTorch's layout), input, output
/// gradient, and our output, parameter gradient (weight then bias) and input gradient.
pub fn dump(layers: &[Layer], n: usize, seed: u64) -> serde_json::Value {
    let mut r = coadapt_core::rng(seed, 2);
    let items: Vec<_> = layers
        .iter()
        .map(|l| {
            let one = std::slice::from_ref(l);
            let mut s = Stack::new(one, n, &mut r);
            s.forward();
            s.backward();
            let sp = &l.spec;
            json!({
                "name": sp.name,
                "config": l.config(),
                "transposed": sp.transposed,
                "c_in": sp.c_in,
                "c_out": sp.c_out,
                "k": sp.k,
                "stride": sp.stride,
                "pad": sp.pad,
                "output_padding": sp.output_padding,
                "h": sp.h,
                "w": sp.w,
                "out_shape": l.out_shape(),
                "macs": l.macs(),
                "n": n,
                "precision": l.precision().name(),
                "params": s.params[0],
                "x": s.acts[0],
                "dy": s.d[1],
                "out": s.acts[1],
                "grad": s.grads[0],
                "dx": s.d[0],
            })
        })
        .collect();
    let figures: Vec<_> = figures(layers).into_iter().map(|(name, r)| json!({"name": name, "layers": r.collect::<Vec<_>>()})).collect();
    json!({"layers": items, "figures": figures})
}

#[cfg(test)]
mod tests {
    use super::*;
    use coadapt_latent::Embedding;
    use coadapt_nn::Mlp;

    #[test]
    fn the_layers_are_the_embeddings_and_the_dump_round_trips() {
        let cfg = EmbeddingConfig::default();
        let layers = embedding_layers(&cfg).unwrap_or_else(|e| panic!("{e}"));
        // The same parameter counts as the embedding's own layers.
        let emb = Embedding::new(cfg).unwrap_or_else(|e| panic!("{e}"));
        let (_, h3, w3) = layers[2].out_shape();
        let flat = cfg.channels[2] * h3 * w3;
        let fc = Mlp::new(&[flat, cfg.latent]).unwrap_or_else(|e| panic!("{e}"));
        let dfc = Mlp::new(&[cfg.latent, flat]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(emb.encoder_params(), layers[..3].iter().map(Layer::n_params).sum::<usize>() + fc.n_params());
        assert_eq!(emb.decoder_params(), layers[3..].iter().map(Layer::n_params).sum::<usize>() + dfc.n_params());
        assert_eq!(layers[5].out_shape(), (3, 64, 64));
        assert_eq!(layers.iter().map(Layer::config).collect::<Vec<_>>()[..2], ["conv1-3to32-64to32", "conv2-32to32-32to16"]);
        // f32 round-trips through the JSON exactly; the dump is one layer's forward/backward.
        let v = dump(&layers, 2, 7);
        let floats = |v: &serde_json::Value| -> Vec<f32> {
            v.as_array().map(|a| a.iter().filter_map(|x| x.as_f64()).map(|x| x as f32).collect()).unwrap_or_default()
        };
        let d = &v["layers"][1];
        let (params, x, out) = (floats(&d["params"]), floats(&d["x"]), floats(&d["out"]));
        assert_eq!((params.len(), x.len(), out.len()), (layers[1].n_params(), 2 * layers[1].in_len(), 2 * layers[1].out_len()));
        let mut again = vec![0.0; out.len()];
        layers[1].forward(&params, &x, 2, &mut again, &mut ConvScratch::default());
        assert_eq!(again, out);
        assert!(out.iter().any(|v| *v != 0.0));
        assert_eq!(floats(&d["dx"]).len(), x.len());
        assert_eq!(v["layers"][3]["output_padding"], 1);
    }
}
