//! A ReLU multilayer perceptron over row-major batches.
//!
//! A batch is `rows x n_in` row-major (each sample contiguous), so replay buffers and
//! observations feed the network without transposition. Matrix products go through faer with
//! `Par::Seq`: the products here are small, and the learner gets its parallelism from running
//! independent networks on separate cores instead.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rand::Rng;

use crate::NnError;
use crate::bf16::{self, Precision, View};
use crate::simd;

/// rlkit's `b_init_value`: every hidden bias starts at this constant.
pub const RLKIT_HIDDEN_BIAS: f32 = 0.1;

/// How the hidden layers of a network start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HiddenInit {
    /// rlkit's `Mlp` (the reference FEAR's networks): weights uniform in
    /// `+-1/sqrt(weight.size(0))`, which for PyTorch's `[n_out, n_in]` weights is the layer's
    /// output width, and biases 0.1.
    #[default]
    Rlkit,
    /// PyTorch's `nn.Linear` default: weights and biases uniform in `+-1/sqrt(n_in)`.
    Pytorch,
}

/// One affine layer: offsets of its weight `[n_out, n_in]` and bias `[n_out]` in the flat buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layer {
    pub n_in: usize,
    pub n_out: usize,
    pub w: usize,
    pub b: usize,
}

/// The shape of an MLP `sizes[0] -> sizes[1] -> ... -> sizes[k]` with ReLU between layers and no
/// activation after the last. Holds no parameters: those live in a flat `&[f32]` of
/// [`Mlp::n_params`] values, so one shape serves online, target and copied networks alike.
#[derive(Clone, Debug)]
pub struct Mlp {
    sizes: Vec<usize>,
    layers: Vec<Layer>,
    n_params: usize,
    /// The products' arithmetic ([`Mlp::with_precision`]); not part of the shape.
    precision: Precision,
}

/// Two networks are equal when their shapes are: the precision of their products is how they
/// are computed, not what they are.
impl PartialEq for Mlp {
    fn eq(&self, other: &Self) -> bool {
        self.sizes == other.sizes
    }
}

impl Eq for Mlp {}

/// Per-layer outputs kept by [`Mlp::forward`] for [`Mlp::backward`], plus backward scratch.
/// Grows to the largest batch seen and is reused, so warm passes do not allocate.
#[derive(Clone, Debug, Default)]
pub struct Activations {
    outs: Vec<Vec<f32>>,
    /// dL/d(output) of every layer from the last [`Mlp::backward_deltas`] (for a hidden layer,
    /// through its ReLU), `deltas_rows` rows each.
    deltas: Vec<Vec<f32>>,
    deltas_rows: std::ops::Range<usize>,
    rows: usize,
    /// Packing buffers of the bf16 products.
    packed: bf16::Scratch,
}

impl Activations {
    /// The output of the last forward pass (`rows x n_out`, row-major).
    pub fn output(&self) -> &[f32] {
        self.outs.last().map(|o| o.as_slice()).unwrap_or(&[])
    }

    /// The output of layer `i` (after its ReLU for hidden layers) in the last forward pass.
    pub fn layer_output(&self, i: usize) -> &[f32] {
        &self.outs[i]
    }

    /// Rows of the last forward pass.
    pub fn rows(&self) -> usize {
        self.rows
    }
}

impl Mlp {
    /// A network with layer widths `sizes` (input first, output last).
    pub fn new(sizes: &[usize]) -> Result<Self, NnError> {
        if sizes.len() < 2 {
            return Err(NnError::Shape { sizes: sizes.to_vec(), why: "needs at least an input and an output size" });
        }
        if sizes.contains(&0) {
            return Err(NnError::Shape { sizes: sizes.to_vec(), why: "layer sizes must be positive" });
        }
        let mut layers = Vec::with_capacity(sizes.len() - 1);
        let mut off = 0;
        for pair in sizes.windows(2) {
            let (n_in, n_out) = (pair[0], pair[1]);
            layers.push(Layer { n_in, n_out, w: off, b: off + n_in * n_out });
            off += n_in * n_out + n_out;
        }
        Ok(Self { sizes: sizes.to_vec(), layers, n_params: off, precision: Precision::F32 })
    }

    /// The same network with its products in `precision`: with [`Precision::Bf16`] every layer
    /// product that [`bf16::runs_in_bf16`] admits takes bf16 operands with f32 accumulation
    /// (parameters, activations, gradients and the rest stay f32); the others stay f32.
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// `[n_in, hidden..., n_out]`.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    pub fn layers(&self) -> &[Layer] {
        &self.layers
    }

    pub fn n_params(&self) -> usize {
        self.n_params
    }

    pub fn n_in(&self) -> usize {
        self.sizes[0]
    }

    pub fn n_out(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// Multiply-adds per row of a forward pass.
    pub fn macs_per_row(&self) -> usize {
        self.layers.iter().map(|l| l.n_in * l.n_out).sum()
    }

    /// A zeroed parameter buffer of the right length.
    pub fn zeros(&self) -> Vec<f32> {
        vec![0.0; self.n_params]
    }

    /// Initialises `params` as PyTorch's `nn.Linear` does for the hidden layers (weights and
    /// biases uniform in `+-1/sqrt(n_in)`), the last layer's weight and bias uniform in
    /// `+-final_init` so the initial outputs are near zero.
    pub fn init<R: Rng + ?Sized>(&self, params: &mut [f32], final_init: f32, rng: &mut R) {
        self.init_with(HiddenInit::Pytorch, params, final_init, rng);
    }

    /// Initialises `params` with `hidden` for the hidden layers and the last layer's weight and
    /// bias uniform in `+-final_init`.
    pub fn init_with<R: Rng + ?Sized>(&self, hidden: HiddenInit, params: &mut [f32], final_init: f32, rng: &mut R) {
        assert_eq!(params.len(), self.n_params, "parameter buffer length");
        let last = self.layers.len() - 1;
        for (i, l) in self.layers.iter().enumerate() {
            let (weights, bias) = params[l.w..l.b + l.n_out].split_at_mut(l.n_in * l.n_out);
            if i == last {
                weights.iter_mut().chain(bias.iter_mut()).for_each(|p| *p = rng.random_range(-final_init..=final_init));
                continue;
            }
            match hidden {
                HiddenInit::Pytorch => {
                    let bound = 1.0 / (l.n_in as f32).sqrt();
                    weights.iter_mut().chain(bias.iter_mut()).for_each(|p| *p = rng.random_range(-bound..=bound));
                }
                HiddenInit::Rlkit => {
                    // rlkit's `fanin_init` takes `weight.size(0)` as the fan-in, and a PyTorch
                    // weight is `[n_out, n_in]`: the bound comes from the layer's OUTPUT width.
                    let bound = 1.0 / (l.n_out as f32).sqrt();
                    weights.iter_mut().for_each(|p| *p = rng.random_range(-bound..=bound));
                    bias.fill(RLKIT_HIDDEN_BIAS);
                }
            }
        }
    }

    /// A fresh [`Activations`] able to hold `rows` rows without growing.
    pub fn activations(&self, rows: usize) -> Activations {
        let mut a = Activations::default();
        self.reserve(&mut a, rows);
        a
    }

    fn reserve(&self, a: &mut Activations, rows: usize) {
        if a.outs.len() != self.layers.len() {
            a.outs = self.layers.iter().map(|_| Vec::new()).collect();
        }
        for (o, l) in a.outs.iter_mut().zip(&self.layers) {
            if o.len() < rows * l.n_out {
                o.resize(rows * l.n_out, 0.0);
            }
        }
        if a.deltas.len() != self.layers.len() {
            a.deltas = self.layers.iter().map(|_| Vec::new()).collect();
        }
        for (d, l) in a.deltas.iter_mut().zip(&self.layers) {
            if d.len() < rows * l.n_out {
                d.resize(rows * l.n_out, 0.0);
            }
        }
    }

    /// Forward pass of `rows` rows of `x` (`rows x n_in`, row-major); returns the output
    /// (`rows x n_out`) and keeps every layer's output in `act` for [`Mlp::backward`].
    pub fn forward<'a>(&self, params: &[f32], x: &[f32], rows: usize, act: &'a mut Activations) -> &'a [f32] {
        debug_assert_eq!(params.len(), self.n_params);
        assert_eq!(x.len(), rows * self.n_in(), "input is not rows x n_in");
        self.reserve(act, rows);
        act.rows = rows;
        let last = self.layers.len() - 1;
        for (i, l) in self.layers.iter().enumerate() {
            let (done, rest) = act.outs.split_at_mut(i);
            let input: &[f32] = if i == 0 { x } else { &done[i - 1][..rows * l.n_in] };
            let out = &mut rest[0][..rows * l.n_out];
            affine(params, l, input, rows, out, self.precision, &mut act.packed);
            if i != last {
                for v in out.iter_mut() {
                    *v = v.max(0.0);
                }
            }
        }
        &act.outs[last][..rows * self.n_out()]
    }

    /// Backward pass after [`Mlp::forward`] on the same `x` and `params`, for the rows `rows`
    /// of that pass (a sub-range lets one forward over stacked inputs serve two losses).
    ///
    /// `dy` is dL/d(output) for those rows (`rows.len() x n_out`). Writes dL/d(params) into
    /// `grad` (replacing it) when given, and dL/dx (`rows.len() x n_in`) into `dx` when given;
    /// either may be skipped, so a critic differentiated only with respect to its input pays for
    /// no weight gradient. The same as [`Mlp::backward_deltas`] then [`Mlp::weight_gradient`].
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        act: &mut Activations,
        rows: std::ops::Range<usize>,
        dy: &[f32],
        grad: Option<&mut [f32]>,
        dx: Option<&mut [f32]>,
    ) {
        self.backward_deltas(params, act, rows, dy, dx);
        if let Some(g) = grad {
            self.weight_gradient(x, act, g);
        }
    }

    /// The first half of [`Mlp::backward`]: every layer's delta (dL/d(its output)) for the rows
    /// `rows` of the last forward pass, kept in `act`, and dL/dx into `dx` when given (the
    /// input itself is needed only by the weight gradient). The
    /// weight gradient ([`Mlp::weight_gradient`]) can then run on another core beside other
    /// work; the two halves compute exactly what `backward` does.
    pub fn backward_deltas(&self, params: &[f32], act: &mut Activations, rows: std::ops::Range<usize>, dy: &[f32], dx: Option<&mut [f32]>) {
        assert!(rows.end <= act.rows, "backward rows beyond the forward pass");
        let (r0, n) = (rows.start, rows.len());
        assert_eq!(dy.len(), n * self.n_out(), "dy is not rows x n_out");
        let last = self.layers.len() - 1;
        act.deltas[last][..dy.len()].copy_from_slice(dy);
        for i in (1..self.layers.len()).rev() {
            let l = self.layers[i];
            let input = &act.outs[i - 1][r0 * l.n_in..(r0 + n) * l.n_in];
            let (below, here) = act.deltas.split_at_mut(i);
            let din = &mut below[i - 1][..n * l.n_in];
            input_grad(params, &l, &here[0][..n * l.n_out], n, din, self.precision, &mut act.packed);
            // ReLU: the gradient passes where the layer's output was positive.
            simd::relu_backward(din, input);
        }
        if let Some(dx) = dx {
            let l = self.layers[0];
            input_grad(params, &l, &act.deltas[0][..n * l.n_out], n, dx, self.precision, &mut act.packed);
        }
        act.deltas_rows = rows;
    }

    /// The second half of [`Mlp::backward`]: dL/d(params) into `grad` (replacing it) from the
    /// deltas of the last [`Mlp::backward_deltas`] on `act` (with the same `x`).
    pub fn weight_gradient(&self, x: &[f32], act: &mut Activations, grad: &mut [f32]) {
        let (r0, n) = (act.deltas_rows.start, act.deltas_rows.len());
        for (i, l) in self.layers.iter().enumerate() {
            let input: &[f32] = if i == 0 { &x[r0 * l.n_in..(r0 + n) * l.n_in] } else { &act.outs[i - 1][r0 * l.n_in..(r0 + n) * l.n_in] };
            let delta = &act.deltas[i][..n * l.n_out];
            if self.precision == Precision::Bf16 && bf16::runs_in_bf16(l.n_out, n, l.n_in) {
                let (dv, iv) = (View::row_major(delta, n, l.n_out).t(), View::row_major(input, n, l.n_in));
                bf16::matmul(&mut grad[l.w..l.b], false, dv, iv, &mut act.packed);
            } else {
                let gw = MatMut::from_row_major_slice_mut(&mut grad[l.w..l.b], l.n_out, l.n_in);
                let dm = MatRef::from_row_major_slice(delta, n, l.n_out).transpose();
                matmul(gw, Accum::Replace, dm, MatRef::from_row_major_slice(input, n, l.n_in), 1.0f32, Par::Seq);
            }
            let gb = &mut grad[l.b..l.b + l.n_out];
            gb.fill(0.0);
            for r in delta.chunks_exact(l.n_out) {
                for (b, d) in gb.iter_mut().zip(r) {
                    *b += d;
                }
            }
        }
    }
}

/// `out = input . W^T + b` for one layer.
fn affine(params: &[f32], l: &Layer, input: &[f32], rows: usize, out: &mut [f32], precision: Precision, packed: &mut bf16::Scratch) {
    if precision == Precision::Bf16 && bf16::runs_in_bf16(rows, l.n_in, l.n_out) {
        let w = View::row_major(&params[l.w..l.b], l.n_out, l.n_in);
        bf16::matmul(out, false, View::row_major(input, rows, l.n_in), w.t(), packed);
    } else {
        let w = MatRef::from_row_major_slice(&params[l.w..l.b], l.n_out, l.n_in);
        let om = MatMut::from_row_major_slice_mut(out, rows, l.n_out);
        matmul(om, Accum::Replace, MatRef::from_row_major_slice(input, rows, l.n_in), w.transpose(), 1.0f32, Par::Seq);
    }
    let bias = &params[l.b..l.b + l.n_out];
    for r in out.chunks_exact_mut(l.n_out) {
        for (v, b) in r.iter_mut().zip(bias) {
            *v += b;
        }
    }
}

/// `dx = delta . W` for one layer.
fn input_grad(params: &[f32], l: &Layer, delta: &[f32], rows: usize, dx: &mut [f32], precision: Precision, packed: &mut bf16::Scratch) {
    if precision == Precision::Bf16 && bf16::runs_in_bf16(rows, l.n_out, l.n_in) {
        let w = View::row_major(&params[l.w..l.b], l.n_out, l.n_in);
        bf16::matmul(&mut dx[..rows * l.n_in], false, View::row_major(delta, rows, l.n_out), w, packed);
    } else {
        let w = MatRef::from_row_major_slice(&params[l.w..l.b], l.n_out, l.n_in);
        let dm = MatMut::from_row_major_slice_mut(&mut dx[..rows * l.n_in], rows, l.n_in);
        matmul(dm, Accum::Replace, MatRef::from_row_major_slice(delta, rows, l.n_out), w, 1.0f32, Par::Seq);
    }
}
