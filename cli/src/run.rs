//! `coadapt run`: its flags, over the co-adaptation's library ([`coadapt_coadaptation::run`]).

use std::path::PathBuf;

use clap::Args;
use coadapt_coadaptation::config::{Overrides, resolve};
use coadapt_fleet::TransportKind;

use crate::progress::shutdown_on_ctrl_c;

/// Run a whole co-adaptation: design after design, train the controller and choose the next body.
///
/// The run directory gets the resolved `config.toml`, `designs.csv` (one row per design: kind,
/// design vector, episodes, best and last evaluation return, the design objective predicted for
/// it, design rollouts spent, prototype), `episodes.csv`, `checkpoints/` (population and
/// individual networks after each design), `landscape.csv` and `plots/*.svg` (learning curves,
/// best return over designs, design landscape). Rows are flushed as they are written: Ctrl-C
/// stops after the current episode and keeps everything.
///
/// Real hardware: `schedule.confirm-designs = true` stops at each design until its prototype is
/// built (answer with `coadapt confirm RUN_DIR [--as-built V1,V2,...|--reject]`), and
/// `schedule.reset-needs-confirmation = true` before each episode until the robot is reset
/// (`coadapt confirm RUN_DIR --reset`).
///
/// Settings: the embedded default (`configs/half-cheetah.toml`: HalfCheetah, 15 designs and 260
/// episodes, about 18 minutes on 2 cores, designs chosen by PSO over an ensemble of 5 critics'
/// lower confidence bound, the choice that beat the thesis's FEAR on 3 of 4 robots, EXPERIMENTS
/// 5.13), replaced by `--config`, then the flags. Other configs: `configs/<robot>.toml` (the
/// same default on walker, hopper, daisy), `configs/<robot>-reduced.toml` (the thesis's FEAR,
/// same schedule), `configs/<robot>-reference.toml` (the thesis's protocol, 50 designs, hours),
/// a tiny one, and each baseline.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// TOML config (top-level env, seed, ... and [schedule], [learner], [learner.sac],
    /// [optimizer] tables); a run directory's config.toml is a valid one.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run directory (default: runs/<config name>-seed<seed>, with -2, -3, ... appended if
    /// taken); an explicit --out must not hold a run already.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override the seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override the exploitation method: pso-q (FEAR), cmaes-q, sim-pso, sim-cmaes, openai-es,
    /// cmaes-es, random, or screened (PSO over Q proposes a few designs, short rollouts choose;
    /// `[optimizer.screen]`).
    #[arg(long)]
    pub exploit: Option<String>,
    /// Override the exploration method: random or novelty.
    #[arg(long)]
    pub explore: Option<String>,
    /// Override the number of designs.
    #[arg(long)]
    pub designs: Option<usize>,
    /// Override how the roles talk: shm (separate processes over iceoryx2 shared memory, the
    /// default), grpc (separate processes over gRPC on this machine), in-process (threads).
    #[arg(long, value_enum)]
    pub transport: Option<TransportKind>,
    /// Override the number of actors.
    #[arg(long)]
    pub actors: Option<usize>,
    /// Override flow.mode: lock-step (the reference schedule, reproducible) or async
    /// (episodes in flight on every actor while the learner trains).
    #[arg(long)]
    pub flow: Option<String>,
    /// Continue the run in RUN_DIR (after a crash, a kill, a reboot or Ctrl-C) from its newest
    /// sound snapshot, with its config.toml (a --config given must agree with it except in
    /// schedule.designs, actors, fleet, snapshot, remote and deadlines). CSVs are cut back to
    /// the snapshot; the same seed gives the same rows as a run never stopped.
    #[arg(long, value_name = "RUN_DIR", conflicts_with = "out")]
    pub resume: Option<PathBuf>,
    /// Serve design queries during the run on ADDR (sets design-service.listen): the
    /// learner answers DesignService (Info, Score, Optimize, Landscape, History, Watch) and the
    /// Open Inference Protocol model `design-critic` with the networks of its latest design
    /// request. Loopback only unless [security] configures TLS or --insecure is given.
    #[arg(long, value_name = "ADDR")]
    pub serve: Option<String>,
    /// Allow plaintext (no TLS) on addresses other than loopback (sets security.insecure):
    /// only on a network you trust.
    #[arg(long)]
    pub insecure: bool,
    /// Start the population networks (policy, critics, targets) from the run in RUN_DIR, its
    /// newest checkpoint (sets init-population.from): transfer to another world (thesis 6.1).
    /// Its state, action and design dimensions and network sizes must be this run's;
    /// init-population.replay = true in the config also takes its population replay.
    #[arg(long, value_name = "RUN_DIR")]
    pub init_population: Option<PathBuf>,
    /// The world the robot meets (sets world.friction, world.actuator-scale,
    /// world.torso-mass-scale; thesis 6.1).
    #[command(flatten)]
    pub world: crate::world_args::WorldArgs,
    /// The networks' matrix products (sets learner.sac.precision): f32, or bf16 (bfloat16
    /// operands with f32 accumulation where the CPU has AVX-512 BF16 or AMX, f32 elsewhere;
    /// parameters, optimiser states and the rest stay f32). Learns as f32 does (EXPERIMENTS 12)
    /// and trains 1.6-1.9x faster on an AMD EPYC with AVX-512 BF16 (BENCHMARKS.md). The
    /// reference protocols (`configs/*-reference.toml`) ask for bf16; `--precision f32` forces f32.
    #[arg(long, value_name = "f32|bf16")]
    pub precision: Option<coadapt_nn::Precision>,
}

/// `coadapt run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let o = Overrides {
        seed: args.seed,
        exploit: args.exploit,
        explore: args.explore,
        designs: args.designs,
        transport: args.transport,
        actors: args.actors,
        flow: args.flow,
        serve: args.serve,
        insecure: args.insecure,
        init_population: args.init_population,
        friction: args.world.friction,
        actuator_scale: args.world.actuator_scale,
        torso_mass_scale: args.world.torso_mass_scale,
        precision: args.precision,
    };
    let (cfg, name) = resolve(args.config.as_deref(), args.resume.as_deref(), &o)?;
    let shutdown = shutdown_on_ctrl_c();
    Ok(coadapt_coadaptation::run::run(cfg, &name, args.out, args.resume, &shutdown)?)
}
