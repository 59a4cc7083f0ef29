//! `coadapt bench`: the subcommands and their dispatch into `coadapt_bench`, whose options are
//! the subcommands' flags (its `clap` feature).

use anyhow::Context;
use clap::Subcommand;
use coadapt_bench::{conv, design, env, groups, nn, page, plan, pso, sim, snapshot, transport};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Networks: SAC updates per second and the design-objective forward throughput.
    Nn(nn::NnOptions),
    /// Design optimisation over Q: one full PSO (700 particles x 250 iterations x 32 start
    /// states, 3 x 256 networks) timed, with the GFLOP/s reached.
    Pso(pso::PsoOptions),
    /// Simulation: env steps per second of each robot on one core, random actions, resets
    /// included.
    Sim(sim::SimOptions),
    /// Transports between processes: weight broadcast latency to 1, 4 and 16 actor processes,
    /// experience throughput, over shared memory and gRPC.
    Transport(transport::TransportOptions),
    /// Snapshots: writing and reading a learner with 1 and 10 million transitions in its
    /// population buffer (seconds and MB/s; the disk under --dir).
    Snapshot(snapshot::SnapshotOptions),
    /// Environments over dm_env_rpc: steps/s and step latency (median, p99) of our robots
    /// served on loopback against the same in process, and of any server given by --url.
    Env(env::EnvOptions),
    /// Design queries: Score latency and designs/s for batches of 1, 100 and 10,000 over gRPC
    /// (and TLS) against the same in process; the learner's updates/s with and without a client
    /// scoring in a loop.
    Design(design::DesignOptions),
    /// Policy search: one GrouPS update (30 rollouts, the best 15, 12 actions in 4 groups, 11
    /// features, 6 latent dimensions, 20 inner iterations), median and p10/p90 over
    /// repetitions from the same state.
    Groups(groups::GroupsOptions),
    /// Convolutions: the image embedding's convolutions and transposed convolutions on 64x64
    /// RGB frames, per layer and as the encoder and decoder, forward and forward + backward,
    /// batch 32 and 1, one thread: median and p10/p90 ms, model GFLOP/s.
    Conv(conv::ConvOptions),
    /// Planning latency: one control step of Alg. 3 (L-BFGS, 20 iterations, over f_Q through
    /// the latent dynamics and critic) for horizons 1, 10 and 20, median and p10/p90 ms.
    Plan(plan::PlanOptions),
    /// The operator page of a run of the reference protocol's size (50 designs, 6,000
    /// episodes), fetched over HTTP on loopback as a browser does: ms per resource and for the
    /// whole page, median and p90.
    Page(page::PageOptions),
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Nn(o) => nn::run(&o)?,
        BenchCommand::Pso(o) => pso::run(&o)?,
        BenchCommand::Sim(o) => sim::run(&o)?,
        BenchCommand::Transport(o) => {
            // The peers are this binary again: `coadapt bench transport --peer ...`.
            let program = std::env::current_exe().context("finding the coadapt binary")?;
            let peers = transport::PeerCommand { program, args: vec!["bench".into(), "transport".into()] };
            transport::run(&o, &peers)?
        }
        BenchCommand::Snapshot(o) => snapshot::run(&o)?,
        BenchCommand::Env(o) => env::run(&o)?,
        BenchCommand::Design(o) => design::run(&o)?,
        BenchCommand::Groups(o) => groups::run(&o)?,
        BenchCommand::Conv(o) => conv::run(&o)?,
        BenchCommand::Plan(o) => plan::run(&o)?,
        BenchCommand::Page(o) => page::run(&o)?,
    }
    Ok(())
}
