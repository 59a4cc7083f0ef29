//! The coadapt design optimiser: chooses the next body from the learned critic.
//!
//! # Layout
//! - [`objective`]: the design objective of FEAR (thesis Eq. 5.6),
//!   `f(xi) = mean_s Q(s_xi, tanh(mu(s_xi)), s_xi)` over a batch of start states whose design
//!   columns are replaced by `xi`, evaluated for a whole swarm of designs in one batched,
//!   two-core pass.

pub mod objective;

pub use objective::{DesignObjective, ObjectiveError, ObjectiveWorkspace, QMode};
