//! The integration tests of `coadapt-robots`, one binary: each file of `tests/` was its own binary,
//! linking the crate and its dependencies again, and `cargo test` ran them one after
//! another; one binary links once and its test threads share every test.
//!
//! # Layout
//! One module per file of `tests/`, named as the file.

mod bimanual;
mod daisy;
mod design_names;
mod half_cheetah;
mod pendulum;
mod pixels;
mod planar_robots;
mod reach;
mod world;
