//! The `coadapt` command's integration tests, one binary.
//!
//! Each file of `tests/` was its own test binary; every one linked the whole stack again (about
//! 10 s of CPU each in release), and `cargo test` ran the binaries one after another, so a
//! binary whose single test waits (on Slurm's time limit, a pod, a network delay) kept the
//! second core idle. One binary links once, and its 2 test threads share every test.
//!
//! libtest runs tests in name order. The tests of `long.rs` take minutes each, much of it waiting,
//! so their module is `_long`, whose name sorts first: they start while the other thread works
//! through the short ones, rather than last with nothing beside them.
//!
//! # Layout
//! One module per concept, each the file of its name; `resume/` holds the kill-and-resume tests
//! (its own `# Layout`).

#[path = "long.rs"]
mod _long;

mod action_space;
mod campaign;
mod cli;
mod confirm;
mod deploy;
mod disk;
mod ensemble;
mod fleet;
mod health;
mod latent;
mod latent_fleet;
mod metrics;
mod operator_page;
mod plot;
mod precision;
mod proptest_config;
mod robots;
mod run;
mod search;
mod serve;
mod tensorboard;
mod transfer;
