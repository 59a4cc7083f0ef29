//! Multilayer perceptrons on faer for the coadapt learner and design optimiser.
//!
//! # Layout
//! - [`bf16`]: products with bfloat16 operands and f32 accumulation (AVX-512 BF16 or AMX,
//!   detected at run time), the kernel of the mixed-precision path.
//! - [`simd`]: hand-written SIMD for the convolutions' stride phases and copies and ReLU's
//!   backward pass (where the compiler's code used masked stores, slow on AMD's Zen 4).
//! - [`mlp`]: the network shape ([`Mlp`]), allocation-free forward and backward passes over
//!   row-major batches into preallocated [`Activations`].
//! - [`optim`]: [`Adam`] (and [`MomentsMismatch`], restoring it from another size), element-wise
//!   gradient clamping and Polyak averaging on flat buffers.
//! - [`squashed`]: the tanh-squashed Gaussian of the SAC policy (sample, log-probability, backward).
//! - [`io`]: save and load networks as safetensors, in PyTorch's `nn.Sequential` naming.
//! - [`conv`]: [`Conv2d`] and [`ConvTranspose2d`] over NCHW batches (im2col through stride
//!   phases, then faer's f32 or our bf16 products; PyTorch's parameter layouts), for encoders
//!   and decoders of images.
//!
//! Every network's parameters live in one contiguous `f32` buffer laid out exactly as PyTorch's
//! `parameters_to_vector(nn.Sequential(Linear, ReLU, ..., Linear))`: per layer the weight
//! `[out, in]` row-major, then the bias `[out]`. That buffer is what transports broadcast and
//! what a PyTorch user loads.

pub mod bf16;
pub mod conv;
pub mod io;
pub mod mlp;
pub mod optim;
pub mod simd;
pub mod squashed;

pub use bf16::Precision;
pub use conv::{Conv2d, ConvScratch, ConvTranspose2d};
pub use io::{NamedNetwork, load_networks, save_networks};
pub use mlp::{Activations, HiddenInit, Layer, Mlp};
pub use optim::{Adam, AdamConfig, MomentsMismatch, clamp_elementwise, polyak};

/// Errors of network construction and weight files.
#[derive(Debug, thiserror::Error)]
pub enum NnError {
    #[error("invalid network shape {sizes:?}: {why}")]
    Shape { sizes: Vec<usize>, why: &'static str },
    // `cause`, not `source`: the message holds it already, and a `source` would print it twice
    // in an error chain (`{:#}`).
    #[error("cannot read weights file {path}: {cause}")]
    Read { path: String, cause: std::io::Error },
    #[error("cannot write weights file {path}: {cause}")]
    Write { path: String, cause: std::io::Error },
    #[error("weights file {path} is not a valid safetensors file: {why}")]
    Corrupt { path: String, why: String },
    #[error("weights file {path} has no network named `{name}` (it has: {available})")]
    MissingNetwork { path: String, name: String, available: String },
    #[error("network `{name}` in {path} has shape {found:?}, expected {expected:?}")]
    ShapeMismatch { path: String, name: String, found: Vec<usize>, expected: Vec<usize> },
}
