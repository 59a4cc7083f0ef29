//! `coadapt render`: its flags, over the learner's renderer ([`coadapt_learner::render`]).

use std::path::PathBuf;

use clap::Args;
use coadapt_learner::render::{RenderOptions, render};

/// Render an episode of a robot as an animated GIF.
///
/// With `--weights` (a checkpoint.safetensors written by `coadapt train`, or a co-adaptation's
/// `checkpoints/design-<k>/individual.safetensors` or `population.safetensors`) the robot acts
/// with the trained policy's deterministic action; without, it takes zero actions (or random
/// ones with `--random`). `--friction`, `--actuator-scale` and `--torso-mass-scale` put the robot
/// in the world a run was trained in (its config.toml's `[world]`).
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Environment to render (see `coadapt train --help` for the names).
    #[arg(long)]
    pub env: String,
    /// Design vector, comma-separated (default: the environment's original design).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub design: Option<Vec<f32>>,
    /// The world the robot meets (its run's config.toml `[world]`).
    #[command(flatten)]
    pub world: crate::world_args::WorldArgs,
    /// Checkpoint with a SAC `policy` or a DDPG `actor` network.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Uniform random actions instead of zeros when no weights are given.
    #[arg(long)]
    pub random: bool,
    /// Control steps to render.
    #[arg(long, default_value_t = 300)]
    pub steps: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Draw a frame every this many control steps.
    #[arg(long, default_value_t = 2)]
    pub every: usize,
    /// Picture width and height in pixels.
    #[arg(long, default_value_t = 480)]
    pub width: u16,
    #[arg(long, default_value_t = 270)]
    pub height: u16,
    /// Output file (.gif).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let opts = RenderOptions {
        env: args.env,
        design: args.design,
        world: {
            let mut w = coadapt_robots::World::default();
            args.world.apply(&mut w);
            w
        },
        weights: args.weights,
        random: args.random,
        steps: args.steps,
        seed: args.seed,
        every: args.every,
        width: args.width,
        height: args.height,
        out: args.out,
    };
    let (frames, ret) = render(&opts)?;
    coadapt_log::logln!("wrote {} ({frames} frames, return {ret:.2})", opts.out.display());
    Ok(())
}
