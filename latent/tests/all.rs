//! The integration tests of `coadapt-latent`, one binary: each file of `tests/` was its own binary,
//! linking the crate and its dependencies again, and `cargo test` ran them one after
//! another; one binary links once and its test threads share every test.
//!
//! # Layout
//! One module per file of `tests/`, named as the file.

mod agent;
mod embedding;
mod embedding_io;
mod fleet;
mod objectives;
mod planning;
mod train_embedding;
mod value;
