//! `coadapt render`: one episode of a robot as an animated GIF.
//!
//! The picture is a cabinet projection of the world (x forward, z up): planar robots, which live
//! in the y = 0 plane, appear exactly side-on; the hexapod's depth axis y is drawn receding up and
//! to the right. The camera follows the body horizontally at a fixed scale; the ground carries a
//! tick every 0.5 m so forward motion is visible.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use coadapt_core::Env;
use coadapt_core::render::{Camera, PALETTE, draw_frame, extent};
use coadapt_nn::{Activations, Mlp, NamedNetwork, squashed};
use rand::Rng;

/// Render an episode of a robot as an animated GIF.
///
/// With `--weights` (a checkpoint.safetensors written by `coadapt train`) the robot acts with the
/// trained policy's deterministic action; without, it takes zero actions (or random ones with
/// `--random`).
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Environment to render (see `coadapt train --help` for the names).
    #[arg(long)]
    pub env: String,
    /// Design vector, comma-separated (default: the environment's original design).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub design: Option<Vec<f32>>,
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

/// The acting policy of a checkpoint: the SAC head's mean, or the DDPG actor, squashed by tanh.
#[derive(Debug)]
pub struct Policy {
    mlp: Mlp,
    params: Vec<f32>,
    gaussian: bool,
    act: Activations,
}

impl Policy {
    /// Loads the acting network of the checkpoint at `path`, checked against the environment's
    /// observation and action widths.
    pub fn load(path: &Path, obs_dim: usize, act_dim: usize) -> anyhow::Result<Self> {
        let nets = coadapt_nn::load_networks(path)?;
        let (net, gaussian) = match (nets.iter().find(|n| n.name == "policy"), nets.iter().find(|n| n.name == "actor")) {
            (Some(p), _) => (p, true),
            (None, Some(a)) => (a, false),
            _ => bail!("{} has neither a SAC `policy` nor a DDPG `actor` network", path.display()),
        };
        let out = if gaussian { 2 * act_dim } else { act_dim };
        // An Mlp has at least an input and an output width: check both against the environment.
        let mut expected = net.mlp.sizes().to_vec();
        let last = expected.len() - 1;
        expected[0] = obs_dim;
        expected[last] = out;
        let net: &NamedNetwork = NamedNetwork::find(&nets, path, &net.name, &expected)?;
        Ok(Self { mlp: net.mlp.clone(), params: net.params.clone(), gaussian, act: Activations::default() })
    }

    /// A SAC policy's stochastic action for the standard normal draws `eps` (one per action
    /// dimension), as the learner's actors act; a DDPG actor's action plus nothing (it has no
    /// distribution).
    pub fn sample(&mut self, obs: &[f32], eps: &[f32], action: &mut [f32]) {
        if !self.gaussian {
            return self.act(obs, action);
        }
        let out = self.mlp.forward(&self.params, obs, 1, &mut self.act);
        let mut log_prob = [0.0];
        squashed::sample(out, eps, action.len(), action, &mut log_prob);
    }

    /// The deterministic action (the SAC head's mean, or the DDPG actor's output).
    pub fn act(&mut self, obs: &[f32], action: &mut [f32]) {
        let out = self.mlp.forward(&self.params, obs, 1, &mut self.act);
        if self.gaussian {
            squashed::mean_action(out, action.len(), action);
        } else {
            for (a, o) in action.iter_mut().zip(out) {
                *a = o.tanh();
            }
        }
    }
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    if args.every == 0 || args.steps == 0 || args.width < 16 || args.height < 16 {
        bail!("--steps and --every must be positive and the picture at least 16 x 16 pixels");
    }
    let mut env = coadapt_robots::make(&args.env)?;
    let spec = env.spec().clone();
    let design = args.design.clone().unwrap_or_else(|| spec.default_design.clone());
    let mut policy = match &args.weights {
        Some(p) => Some(Policy::load(p, spec.obs_dim(), spec.act_dim()).with_context(|| format!("loading policy from {}", p.display()))?),
        None => None,
    };
    let mut obs = env.reset(args.seed, &design).with_context(|| format!("resetting {}", args.env))?.to_vec();
    let mut shapes = Vec::new();
    env.draw(&mut shapes);
    if shapes.is_empty() {
        bail!("environment `{}` cannot be drawn", args.env);
    }
    let (u_lo, u_hi, v_lo, v_hi) = extent(&shapes);
    let (w, h) = (args.width as usize, args.height as usize);
    // Fit the starting body in about two thirds of the picture, ground included.
    let span = (u_hi - u_lo).max(v_hi.max(0.0) - v_lo.min(0.0)).max(0.5);
    let scale = 0.7 * (w.min(h) as f32) / span;
    let mut cam = Camera { scale, u0: 0.5 * (u_lo + u_hi), v0: 0.0, w, h };

    let file = File::create(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let palette: Vec<u8> = PALETTE.iter().flatten().copied().collect();
    let mut enc = gif::Encoder::new(BufWriter::new(file), args.width, args.height, &palette).context("starting the GIF")?;
    enc.set_repeat(gif::Repeat::Infinite).context("writing the GIF header")?;
    let mut frame = vec![0u8; w * h];
    let mut action = vec![0.0; spec.act_dim()];
    let mut rng = coadapt_core::rng(args.seed, 7);
    let (mut ret, mut frames) = (0.0f32, 0usize);
    for t in 0..args.steps {
        if t % args.every == 0 {
            shapes.clear();
            env.draw(&mut shapes);
            let (lo, hi, _, _) = extent(&shapes);
            cam.u0 = 0.5 * (lo + hi);
            draw_frame(&mut frame, &cam, &shapes);
            let mut f = gif::Frame::from_indexed_pixels(args.width, args.height, frame.clone(), None);
            f.delay = (args.every as f32 * 1.65).round().max(2.0) as u16;
            enc.write_frame(&f).context("writing a GIF frame")?;
            frames += 1;
        }
        match (&mut policy, args.random) {
            (Some(p), _) => p.act(&obs, &mut action),
            (None, true) => action.iter_mut().for_each(|a| *a = rng.random_range(-1.0..1.0)),
            (None, false) => action.fill(0.0),
        }
        let s = env.step(&action).with_context(|| format!("stepping {}", args.env))?;
        ret += s.reward;
        obs.copy_from_slice(s.observation);
        if s.terminated || s.truncated {
            break;
        }
    }
    coadapt_log::logln!("wrote {} ({frames} frames, return {ret:.2})", args.out.display());
    Ok(())
}
