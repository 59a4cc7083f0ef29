//! DDPG from pixels that explores by planning in a learned latent space (thesis ch. 4).
//!
//! # Layout
//! - `embedding`: the time-contrastive autoencoder (Eq. 4.1, 4.2), [`Embedding`]: convolutional
//!   encoder to a 20-D code on the unit sphere, mirrored decoder, the loss and its gradients.
//!
//! Next (issue 15): latent dynamics (Eq. 4.3-4.5), DDPG with the Q and V critics, exploration by
//! trajectory optimisation (Alg. 3).

mod embedding;

pub use embedding::{Embedding, EmbeddingConfig, EmbeddingWork, LossParts};
