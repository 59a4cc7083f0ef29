//! `coadapt render`: one episode of a robot as an animated GIF, acting with a trained policy
//! ([`Policy`], from a `coadapt train` checkpoint), zeros or random actions.
//!
//! The picture is a cabinet projection of the world (x forward, z up): planar robots, which live
//! in the y = 0 plane, appear exactly side-on; the hexapod's depth axis y is drawn receding up and
//! to the right. The camera follows the body horizontally at a fixed scale; the ground carries a
//! tick every 0.5 m so forward motion is visible.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use coadapt_core::Env;
use coadapt_core::render::{Camera, PALETTE, draw_frame, extent};
use coadapt_nn::{Activations, Mlp, NamedNetwork, squashed};
use rand::Rng;

/// Why an episode could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// A setting is wrong; the message names it.
    #[error("{0}")]
    Config(String),
    /// The output file could not be written.
    #[error("{what}: {error}")]
    Io { what: String, error: std::io::Error },
    /// The robot, the checkpoint or the GIF encoder failed; the message says which.
    #[error("{0}")]
    Failed(String),
}

/// What to render.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    pub env: String,
    /// `None`: the robot's original design.
    pub design: Option<Vec<f32>>,
    /// The world the robot meets (friction, actuator strength, torso mass; thesis 6.1): a
    /// policy trained in another world is seen in its own.
    pub world: coadapt_robots::World,
    /// A checkpoint with a SAC `policy` or a DDPG `actor` network.
    pub weights: Option<PathBuf>,
    /// Uniform random actions instead of zeros when no weights are given.
    pub random: bool,
    pub steps: usize,
    pub seed: u64,
    /// A frame every this many control steps.
    pub every: usize,
    pub width: u16,
    pub height: u16,
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
    pub fn load(path: &Path, obs_dim: usize, act_dim: usize) -> Result<Self, RenderError> {
        let nn = |e: coadapt_nn::NnError| RenderError::Failed(e.to_string());
        let nets = coadapt_nn::load_networks(path).map_err(nn)?;
        let (net, gaussian) = match (nets.iter().find(|n| n.name == "policy"), nets.iter().find(|n| n.name == "actor")) {
            (Some(p), _) => (p, true),
            (None, Some(a)) => (a, false),
            _ => return Err(RenderError::Failed(format!("{} has neither a SAC `policy` nor a DDPG `actor` network", path.display()))),
        };
        let out = if gaussian { 2 * act_dim } else { act_dim };
        // An Mlp has at least an input and an output width: check both against the environment.
        let mut expected = net.mlp.sizes().to_vec();
        let last = expected.len() - 1;
        expected[0] = obs_dim;
        expected[last] = out;
        let net: &NamedNetwork = NamedNetwork::find(&nets, path, &net.name, &expected).map_err(nn)?;
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

/// Renders the episode of `args` into its GIF file; returns the frames written and the return.
pub fn render(args: &RenderOptions) -> Result<(usize, f32), RenderError> {
    let failed = |what: String| move |e: &dyn std::fmt::Display| RenderError::Failed(format!("{what}: {e}"));
    if args.every == 0 || args.steps == 0 || args.width < 16 || args.height < 16 {
        return Err(RenderError::Config("--steps and --every must be positive and the picture at least 16 x 16 pixels".into()));
    }
    let mut env = coadapt_robots::make_in(&args.env, &args.world).map_err(|e| RenderError::Config(e.to_string()))?;
    let spec = env.spec().clone();
    let design = args.design.clone().unwrap_or_else(|| spec.default_design.clone());
    let mut policy = match &args.weights {
        Some(p) => {
            Some(Policy::load(p, spec.obs_dim(), spec.act_dim()).map_err(|e| failed(format!("loading policy from {}", p.display()))(&e))?)
        }
        None => None,
    };
    let mut obs = env.reset(args.seed, &design).map_err(|e| failed(format!("resetting {}", args.env))(&e))?.to_vec();
    let mut shapes = Vec::new();
    env.draw(&mut shapes);
    if shapes.is_empty() {
        return Err(RenderError::Config(format!("environment `{}` cannot be drawn", args.env)));
    }
    let (u_lo, u_hi, v_lo, v_hi) = extent(&shapes);
    let (w, h) = (args.width as usize, args.height as usize);
    // Fit the starting body in about two thirds of the picture, ground included.
    let span = (u_hi - u_lo).max(v_hi.max(0.0) - v_lo.min(0.0)).max(0.5);
    let scale = 0.7 * (w.min(h) as f32) / span;
    let mut cam = Camera { scale, u0: 0.5 * (u_lo + u_hi), v0: 0.0, w, h };

    let file = File::create(&args.out).map_err(|error| RenderError::Io { what: format!("creating {}", args.out.display()), error })?;
    let palette: Vec<u8> = PALETTE.iter().flatten().copied().collect();
    let gif_failed = |what: &str| {
        let what = format!("{what} {}", args.out.display());
        move |e: gif::EncodingError| match e {
            gif::EncodingError::Io(error) => RenderError::Io { what, error },
            e => RenderError::Failed(format!("{what}: {e}")),
        }
    };
    let mut enc = gif::Encoder::new(BufWriter::new(file), args.width, args.height, &palette).map_err(gif_failed("starting the GIF"))?;
    enc.set_repeat(gif::Repeat::Infinite).map_err(gif_failed("writing the GIF header of"))?;
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
            enc.write_frame(&f).map_err(gif_failed("writing a GIF frame of"))?;
            frames += 1;
        }
        match (&mut policy, args.random) {
            (Some(p), _) => p.act(&obs, &mut action),
            (None, true) => action.iter_mut().for_each(|a| *a = rng.random_range(-1.0..1.0)),
            (None, false) => action.fill(0.0),
        }
        let s = env.step(&action).map_err(|e| failed(format!("stepping {}", args.env))(&e))?;
        ret += s.reward;
        obs.copy_from_slice(s.observation);
        if s.terminated || s.truncated {
            break;
        }
    }
    Ok((frames, ret))
}
