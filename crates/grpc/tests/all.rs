//! The integration tests of `coadapt-grpc`, one binary: each file of `tests/` was its own binary,
//! linking the crate and its dependencies again, and `cargo test` ran them one after
//! another; one binary links once and its test threads share every test.
//!
//! # Layout
//! One module per file of `tests/`, named as the file.
//! Shared helpers: `common/`.

mod common;

mod auth;
mod conformance;
mod edge;
mod fleet;
#[path = "hostile/main.rs"]
mod hostile;
mod run_id;
