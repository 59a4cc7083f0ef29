//! gymnasium's Pendulum-v1, with the design scaling pole length and mass.
//!
//! Dynamics and reward are Pendulum-v1's (g = 10, dt = 0.05, max speed 8, max torque 2, 200
//! steps): `thdot' = clip(thdot + (3g/(2l) sin th + 3/(m l^2) u) dt, -8, 8)`,
//! `th' = th + thdot' dt`, reward `-(norm(th)^2 + 0.1 thdot^2 + 0.001 u^2)`. The action in
//! `[-1, 1]` is the torque as a fraction of the maximum, `u = 2a`. The design `[l, m]` multiplies
//! the unit length and mass, in `[0.5, 2]`; `[1, 1]` is Pendulum-v1 exactly. The observation is
//! `[cos th, sin th, thdot, l, m]`.

use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Shape, Step, rng};
use rand::Rng;

const G: f32 = 10.0;
const DT: f32 = 0.05;
const MAX_SPEED: f32 = 8.0;
const MAX_TORQUE: f32 = 2.0;

#[derive(Debug)]
pub struct Pendulum {
    spec: EnvSpec,
    th: f32,
    thdot: f32,
    len: f32,
    mass: f32,
    obs: [f32; 5],
    ready: bool,
}

impl Default for Pendulum {
    fn default() -> Self {
        Self::new()
    }
}

impl Pendulum {
    pub fn new() -> Self {
        let spec = EnvSpec {
            name: "pendulum".into(),
            state_dim: 3,
            action: BoxSpace::uniform(1, -1.0, 1.0),
            design: BoxSpace::uniform(2, 0.5, 2.0),
            design_names: vec!["pole length".into(), "pole mass".into()],
            default_design: vec![1.0, 1.0],
            max_episode_steps: 200,
        };
        Self { spec, th: 0.0, thdot: 0.0, len: 1.0, mass: 1.0, obs: [0.0; 5], ready: false }
    }

    fn observe(&mut self) {
        self.obs = [self.th.cos(), self.th.sin(), self.thdot, self.len, self.mass];
    }
}

fn angle_normalize(x: f32) -> f32 {
    use std::f32::consts::PI;
    (x + PI).rem_euclid(2.0 * PI) - PI
}

impl Env for Pendulum {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        let mut r = rng(seed, 0);
        self.th = r.random_range(-std::f32::consts::PI..std::f32::consts::PI);
        self.thdot = r.random_range(-1.0..1.0);
        self.len = design[0];
        self.mass = design[1];
        self.ready = true;
        self.observe();
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        if !self.ready {
            return Err(EnvError::NotRunning);
        }
        self.spec.action.check_finite("action", action).map_err(EnvError::Action)?;
        let u = action[0].clamp(-1.0, 1.0) * MAX_TORQUE;
        let (l, m) = (self.len, self.mass);
        let cost = angle_normalize(self.th).powi(2) + 0.1 * self.thdot.powi(2) + 0.001 * u * u;
        let thdot = (self.thdot + (3.0 * G / (2.0 * l) * self.th.sin() + 3.0 / (m * l * l) * u) * DT).clamp(-MAX_SPEED, MAX_SPEED);
        self.th += thdot * DT;
        self.thdot = thdot;
        self.observe();
        Ok(Step { observation: &self.obs, reward: -cost, terminated: false, truncated: false })
    }

    /// The pole from a pivot 2.2 m above the ground (so it clears it); theta = 0 is upright.
    fn draw(&self, out: &mut Vec<Shape>) {
        let pivot = [0.0, 0.0, 2.2];
        let tip = [self.len * self.th.sin(), 0.0, pivot[2] + self.len * self.th.cos()];
        out.push(Shape::Capsule { a: pivot, b: tip, radius: 0.04 * self.mass.sqrt() });
        out.push(Shape::Sphere { centre: pivot, radius: 0.05 });
    }
}
