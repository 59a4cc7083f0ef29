//! The integration tests of `coadapt-env-rpc`, one binary: each file of `tests/` was its own binary,
//! linking the crate and its dependencies again, and `cargo test` ran them one after
//! another; one binary links once and its test threads share every test.
//!
//! # Layout
//! One module per file of `tests/`, named as the file.

mod auth;
mod limits;
mod profile;
mod remote;
