//! The integration tests of `coadapt-tests`, one binary: each file of `tests/` was its own binary,
//! linking the crate and its dependencies again, and `cargo test` ran them one after
//! another; one binary links once and its test threads share every test.
//!
//! # Layout
//! One module per file of `tests/`, named as the file.
//! Shared helpers: `campaign_tree/`.

mod campaign_tree;

mod architecture;
mod campaign_bridge;
mod campaign_script;
mod campaign_stop;
mod doc_tables;
mod lanes;
mod learning;
mod tb_scalars;
