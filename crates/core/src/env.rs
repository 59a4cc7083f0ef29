//! The environment trait: gymnasium's reset/step, with a design vector chosen at every reset.

use crate::space::{BoxSpace, SpaceError};

/// What an environment declares about itself.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvSpec {
    /// Registry name, e.g. `pendulum`.
    pub name: String,
    /// Dimensions of the robot state; the observation is the state with the design appended.
    pub state_dim: usize,
    pub action: BoxSpace,
    pub design: BoxSpace,
    /// What each entry of the design vector is, in order (`back thigh`, `pole length`, ...):
    /// the names an operator building a prototype reads the dimensions by.
    pub design_names: Vec<String>,
    /// The original (reference) design.
    pub default_design: Vec<f32>,
    /// Episode length after which [`TimeLimit`] truncates.
    pub max_episode_steps: usize,
}

impl EnvSpec {
    /// Observation width: state then design.
    pub fn obs_dim(&self) -> usize {
        self.state_dim + self.design.dim()
    }

    pub fn act_dim(&self) -> usize {
        self.action.dim()
    }

    pub fn design_dim(&self) -> usize {
        self.design.dim()
    }
}

/// One environment transition. `observation` borrows the environment's own buffer.
#[derive(Debug)]
pub struct Step<'a> {
    pub observation: &'a [f32],
    pub reward: f32,
    /// A terminal state: the critic must not bootstrap past it.
    pub terminated: bool,
    /// Cut by a time limit: the critic still bootstraps.
    pub truncated: bool,
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EnvError {
    #[error("invalid design: {0}")]
    Design(SpaceError),
    #[error("invalid action: {0}")]
    Action(SpaceError),
    #[error("step called before reset, or after the episode ended")]
    NotRunning,
    #[error("environment failure: {0}")]
    Backend(String),
}

/// A primitive of a robot's body in the world frame (metres; x forward, z up; planar robots live
/// in the y = 0 plane), for pictures of episodes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    Capsule { a: [f32; 3], b: [f32; 3], radius: f32 },
    Sphere { centre: [f32; 3], radius: f32 },
}

/// A (possibly real) robot whose body is set by a design vector at each reset.
pub trait Env: Send {
    fn spec(&self) -> &EnvSpec;

    /// Starts an episode with body `design` and randomness from `seed`; returns the first
    /// observation. The same seed and design give the same episode.
    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError>;

    /// Applies `action` (in the action box; values outside are clipped, non-finite rejected).
    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError>;

    /// Appends the body's current shapes to `out` (nothing for environments that cannot be
    /// drawn, such as a remote robot).
    fn draw(&self, _out: &mut Vec<Shape>) {}
}

impl<E: Env + ?Sized> Env for Box<E> {
    fn spec(&self) -> &EnvSpec {
        (**self).spec()
    }
    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        (**self).reset(seed, design)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        (**self).step(action)
    }
    fn draw(&self, out: &mut Vec<Shape>) {
        (**self).draw(out)
    }
}

/// Truncates episodes after `spec().max_episode_steps` steps and refuses steps after the end,
/// as gymnasium's `TimeLimit` and its order enforcing do.
#[derive(Debug)]
pub struct TimeLimit<E> {
    inner: E,
    t: usize,
    running: bool,
}

impl<E: Env> TimeLimit<E> {
    pub fn new(inner: E) -> Self {
        Self { inner, t: 0, running: false }
    }

    /// Steps taken in the current episode.
    pub fn elapsed(&self) -> usize {
        self.t
    }

    pub fn into_inner(self) -> E {
        self.inner
    }
}

impl<E: Env> Env for TimeLimit<E> {
    fn spec(&self) -> &EnvSpec {
        self.inner.spec()
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.t = 0;
        self.running = false;
        let obs = self.inner.reset(seed, design)?;
        self.running = true;
        Ok(obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        if !self.running {
            return Err(EnvError::NotRunning);
        }
        let limit = self.inner.spec().max_episode_steps;
        self.t += 1;
        let t = self.t;
        let mut step = self.inner.step(action)?;
        step.truncated |= t >= limit;
        self.running = !(step.terminated || step.truncated);
        Ok(step)
    }

    fn draw(&self, out: &mut Vec<Shape>) {
        self.inner.draw(out)
    }
}
