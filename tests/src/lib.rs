//! End-to-end tests of coadapt live in `tests/`; this crate has no library code.
//!
//! # Layout
//! - `tests/learning.rs`: SAC and DDPG learn Pendulum (release mode in CI).
