//! The integration tests of `coadapt-learner`, one binary: each file of `tests/` was its own binary,
//! linking the crate and its dependencies again, and `cargo test` ran them one after
//! another; one binary links once and its test threads share every test.
//!
//! # Layout
//! One module per file of `tests/`, named as the file.

mod action_space;
mod conservative;
mod ensemble;
mod fear;
mod gradcheck;
mod hardware;
mod hostile_optimizer;
mod prototype;
mod reference;
mod two_cores;
mod update_schedule;
