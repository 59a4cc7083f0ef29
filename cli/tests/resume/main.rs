//! Nothing lost: runs killed at random points (the learner, the optimiser mid-request, an actor
//! mid-episode) resume to exactly the rows of a run never stopped; a damaged newest snapshot
//! falls back to the one before; a resume with a config that changes what the run learns is
//! refused naming the key. All through the binary.
//!
//! # Layout
//! - `support.rs`: the tiny protocol, the uninterrupted reference run, process and kill helpers;
//! - `kills.rs`: fleets and their roles killed with SIGKILL at random points, and restarted;
//! - `ctrl_c.rs`: Ctrl-C mid-design and while the learner trains;
//! - `snapshots.rs`: a damaged snapshot, a refused resume, the snapshots' share of the time.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

mod ctrl_c;
mod kills;
mod snapshots;
mod support;
