//! coadapt's benchmarks, behind `coadapt bench ...`: each prints one JSON line per figure on
//! stdout (`{"bench": ..., "config": ..., "value": ..., "unit": ...}`, some with more keys),
//! the lines BENCHMARKS.md, `bench/compare_*.sh` and `bench/ratios.py` read. Each benchmark
//! takes its options struct (a clap `Args` with the `clap` feature, for the binary) and returns
//! the fleet's [`AppError`](coadapt_fleet::app::AppError): a bad option exits 78, a full disk 73.
//!
//! # Layout
//! - [`nn`]: SAC updates/s and the design objective's forward throughput.
//! - [`pso`]: one full PSO over Q, seconds and GFLOP/s.
//! - [`sim`]: env steps/s of each robot on one core.
//! - [`transport`]: weight broadcast latency and experience throughput between processes,
//!   over shared memory and gRPC (the peers are child processes: [`transport::PeerCommand`]).
//! - [`snapshot`]: writing and reading a learner's snapshot with millions of transitions.
//! - [`env`]: environments over dm_env_rpc on loopback against the same in process.
//! - [`design`]: design queries (Score) over gRPC against in process, and what serving them
//!   costs the learner.
//! - [`groups`]: one GrouPS update; [`conv`]: the image embedding's convolutions; [`plan`]: one
//!   planning step of Alg. 3 (each with percentiles and, for the first two, a `--dump` for the
//!   Python peer's check).
//! - [`page`]: the operator page of a reference-sized run, fetched over HTTP.
//! - [`figure`]: the one-line figure, rates and percentiles they share.

pub mod conv;
pub mod design;
pub mod env;
pub mod figure;
pub mod groups;
pub mod nn;
pub mod page;
pub mod plan;
pub mod pso;
pub mod sim;
pub mod snapshot;
pub mod transport;
