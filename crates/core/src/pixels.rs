//! [`Pixels`]: any drawable robot seen through a camera (thesis ch. 4: 64 x 64 RGB, three frames
//! stacked, action repeat), as an [`Env`] whose observation is the frames.
//!
//! The observation is `frames x 3 x height x width` values in [0, 1] (the frames oldest first,
//! each frame's channels R, G, B: PyTorch's NCHW with the frames stacked along C), then the
//! design, as for every robot. The camera follows the body horizontally at a scale fixed at
//! construction (from the default design's first pose), so distances in the picture mean the
//! same in every episode; the ground's ticks show forward motion. A step repeats the action
//! `action-repeat` times and sums the rewards; the episode ends when the robot's would.

use crate::render::{Camera, PALETTE, draw_frame, extent};
use crate::{BoxSpace, Env, EnvError, EnvSpec, Shape, Step};

/// The camera and the stacking.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelsConfig {
    pub width: usize,
    pub height: usize,
    /// Frames stacked in each observation (the newest last).
    pub frames: usize,
    /// Robot steps per environment step, with the same action; rewards summed.
    pub action_repeat: usize,
}

impl Default for PixelsConfig {
    /// The thesis's: 64 x 64, 3 frames, action repeat 2.
    fn default() -> Self {
        Self { width: 64, height: 64, frames: 3, action_repeat: 2 }
    }
}

/// A robot seen through a camera.
pub struct Pixels<E: Env> {
    env: E,
    cfg: PixelsConfig,
    spec: EnvSpec,
    cam: Camera,
    shapes: Vec<Shape>,
    frame: Vec<u8>,
    obs: Vec<f32>,
    /// The robot's own observation after the last reset or step (state and design).
    state: Vec<f32>,
    running: bool,
}

impl<E: Env> std::fmt::Debug for Pixels<E> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pixels").field("robot", &self.env.spec().name).field("cfg", &self.cfg).finish_non_exhaustive()
    }
}

impl<E: Env> Pixels<E> {
    /// `env` through a camera; fails for a robot that cannot be drawn (a remote one).
    pub fn new(mut env: E, cfg: PixelsConfig) -> Result<Self, EnvError> {
        if cfg.width < 8 || cfg.height < 8 || cfg.frames == 0 || cfg.action_repeat == 0 {
            return Err(EnvError::Backend(format!("pixels: {cfg:?}: at least 8 x 8 pixels, 1 frame and 1 repeat")));
        }
        let inner = env.spec().clone();
        env.reset(0, &inner.default_design)?;
        let mut shapes = Vec::new();
        env.draw(&mut shapes);
        if shapes.is_empty() {
            return Err(EnvError::Backend(format!("pixels: robot `{}` cannot be drawn", inner.name)));
        }
        // Fit the starting body in about two thirds of the picture, ground included.
        let (u_lo, u_hi, v_lo, v_hi) = extent(&shapes);
        let span = (u_hi - u_lo).max(v_hi.max(0.0) - v_lo.min(0.0)).max(0.5);
        let scale = 0.7 * (cfg.width.min(cfg.height) as f32) / span;
        let cam = Camera { scale, u0: 0.5 * (u_lo + u_hi), v0: 0.0, w: cfg.width, h: cfg.height };
        let state_dim = cfg.frames * 3 * cfg.width * cfg.height;
        let spec = EnvSpec {
            name: format!("{}-pixels", inner.name),
            state_dim,
            action: inner.action.clone(),
            design: inner.design.clone(),
            design_names: inner.design_names.clone(),
            default_design: inner.default_design.clone(),
            max_episode_steps: inner.max_episode_steps.div_ceil(cfg.action_repeat),
        };
        let obs = vec![0.0; state_dim + inner.design.dim()];
        Ok(Self { env, cfg, spec, cam, shapes, frame: vec![0; cfg.width * cfg.height], obs, state: Vec::new(), running: false })
    }

    /// The robot inside.
    pub fn inner(&self) -> &E {
        &self.env
    }

    /// The robot's own observation (its state, then the design) behind the latest frame: what
    /// a state-based learner sees, e.g. to collect an embedding's training frames.
    pub fn state(&self) -> &[f32] {
        &self.state
    }

    /// The newest frame as palette indices (`width x height`), e.g. to write a picture.
    pub fn frame(&self) -> &[u8] {
        &self.frame
    }

    fn frame_len(&self) -> usize {
        3 * self.cfg.width * self.cfg.height
    }

    /// Draws the robot's pose into `self.frame` and writes it as the newest frame of `obs`.
    fn capture(&mut self) {
        self.shapes.clear();
        self.env.draw(&mut self.shapes);
        let (lo, hi, _, _) = extent(&self.shapes);
        self.cam.u0 = 0.5 * (lo + hi);
        draw_frame(&mut self.frame, &self.cam, &self.shapes);
        let (n, fl) = (self.cfg.width * self.cfg.height, self.frame_len());
        let newest = (self.cfg.frames - 1) * fl;
        let (r, rest) = self.obs[newest..newest + fl].split_at_mut(n);
        let (g, b) = rest.split_at_mut(n);
        for (i, &p) in self.frame.iter().enumerate() {
            let c = PALETTE[usize::from(p).min(PALETTE.len() - 1)];
            r[i] = f32::from(c[0]) / 255.0;
            g[i] = f32::from(c[1]) / 255.0;
            b[i] = f32::from(c[2]) / 255.0;
        }
    }
}

impl<E: Env> Env for Pixels<E> {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        let o = self.env.reset(seed, design)?;
        self.state.clear();
        self.state.extend_from_slice(o);
        self.capture();
        // Before the first step every frame of the stack is the first picture.
        let fl = self.frame_len();
        let newest = (self.cfg.frames - 1) * fl;
        for f in 0..self.cfg.frames - 1 {
            self.obs.copy_within(newest..newest + fl, f * fl);
        }
        let d = self.spec.state_dim;
        self.obs[d..].copy_from_slice(design);
        self.running = true;
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        if !self.running {
            return Err(EnvError::NotRunning);
        }
        let (mut reward, mut terminated, mut truncated) = (0.0, false, false);
        for _ in 0..self.cfg.action_repeat {
            let s = self.env.step(action)?;
            self.state.clear();
            self.state.extend_from_slice(s.observation);
            reward += s.reward;
            (terminated, truncated) = (s.terminated, s.truncated);
            if terminated || truncated {
                break;
            }
        }
        // The oldest frame leaves the stack.
        let fl = self.frame_len();
        self.obs.copy_within(fl..self.cfg.frames * fl, 0);
        self.capture();
        self.running = !(terminated || truncated);
        Ok(Step { observation: &self.obs, reward, terminated, truncated })
    }

    fn draw(&self, out: &mut Vec<Shape>) {
        self.env.draw(out)
    }
}

/// The observation box of a pixel robot: frames in [0, 1], then its design box.
pub fn observation_box(spec: &EnvSpec) -> BoxSpace {
    let mut low = vec![0.0; spec.state_dim];
    let mut high = vec![1.0; spec.state_dim];
    low.extend_from_slice(&spec.design.low);
    high.extend_from_slice(&spec.design.high);
    BoxSpace { low, high }
}
