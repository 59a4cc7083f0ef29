//! A sparse-reward reaching task seen through the camera: the stand-in for the thesis's Baxter
//! peg insertion (ch. 4, §3.3 of the notes), where a position-controlled arm moves by small
//! joint deltas for 20 steps and is rewarded only on success.
//!
//! A planar three-joint arm in the x-z plane, its base 1 m above the ground, moved kinematically
//! (position control): the action in `[-1, 1]^3` is a joint delta of `0.05 a` rad per step (the
//! thesis's +-0.05 rad). Episodes start at `MU + N(0, 0.05^2)` per joint and last 20 steps. The
//! reward is sparse: **+1** when the end effector comes within `SUCCESS_RADIUS` of the fixed
//! target (the episode ends: success), **-1** when it leaves the workspace box around the base
//! (the episode ends), **0** otherwise. The design scales the three links (`[0.5, 1.5]` each,
//! `[1, 1, 1]` the default, for which the target is reached exactly at joint angles
//! [`TARGET_Q`]). The observation: the joint angles (rad), the end effector's offset from the
//! target (m), then the design. The target is drawn as a ball, so the camera sees the task.
//! [`demonstration_action`] is the scripted demonstrator (straight to `TARGET_Q` in joint space).

use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Shape, Step, rng};
use rand::Rng;
use rand_distr::StandardNormal;

/// Link lengths (m) at design `[1, 1, 1]`.
pub const LINKS: [f32; 3] = [0.5, 0.4, 0.3];
/// The mean start pose (rad; joint 1 from the horizontal, the others relative).
pub const MU: [f32; 3] = [1.2, -0.9, -0.8];
/// Standard deviation of the start pose per joint (rad).
pub const START_SD: f32 = 0.05;
/// The pose that puts the default arm's end effector on the target.
pub const TARGET_Q: [f32; 3] = [0.8, -1.2, -0.3];
/// Joint delta (rad) of a full action.
pub const MAX_DELTA: f32 = 0.05;
/// Success: the end effector within this distance (m) of the target.
pub const SUCCESS_RADIUS: f32 = 0.06;
/// Steps per episode.
pub const STEPS: usize = 20;
const BASE: [f32; 2] = [0.0, 1.0];
/// The workspace around the base (x from, x to, z from, z to), relative to it.
const WORKSPACE: [f32; 4] = [0.2, 1.3, -0.3, 1.0];

fn forward(q: &[f32; 3], lens: &[f32; 3]) -> [[f32; 2]; 4] {
    let mut pts = [BASE; 4];
    let mut angle = 0.0;
    for i in 0..3 {
        angle += q[i];
        pts[i + 1] = [pts[i][0] + lens[i] * angle.cos(), pts[i][1] + lens[i] * angle.sin()];
    }
    pts
}

/// The target: where the default arm's end effector is at [`TARGET_Q`].
pub fn target() -> [f32; 2] {
    forward(&TARGET_Q, &LINKS)[3]
}

/// The scripted demonstrator: from an observation of this robot, the action that moves every
/// joint straight towards [`TARGET_Q`] (as fast as allowed).
pub fn demonstration_action(obs: &[f32], action: &mut [f32]) {
    for i in 0..3 {
        action[i] = ((TARGET_Q[i] - obs[i]) / MAX_DELTA).clamp(-1.0, 1.0);
    }
}

#[derive(Debug)]
pub struct Reach {
    spec: EnvSpec,
    q: [f32; 3],
    lens: [f32; 3],
    obs: Vec<f32>,
    ready: bool,
}

impl Default for Reach {
    fn default() -> Self {
        Self::new()
    }
}

impl Reach {
    pub fn new() -> Self {
        let spec = EnvSpec {
            name: "reach".into(),
            state_dim: 5,
            action: BoxSpace::uniform(3, -1.0, 1.0),
            design: BoxSpace::uniform(3, 0.5, 1.5),
            design_names: vec!["upper arm".into(), "forearm".into(), "hand".into()],
            default_design: vec![1.0, 1.0, 1.0],
            max_episode_steps: STEPS,
        };
        Self { spec, q: MU, lens: LINKS, obs: vec![0.0; 8], ready: false }
    }

    fn tip(&self) -> [f32; 2] {
        forward(&self.q, &self.lens)[3]
    }

    fn observe(&mut self) {
        let (tip, t) = (self.tip(), target());
        self.obs[..3].copy_from_slice(&self.q);
        self.obs[3] = tip[0] - t[0];
        self.obs[4] = tip[1] - t[1];
    }
}

impl Env for Reach {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        let mut r = rng(seed, 0);
        for i in 0..3 {
            let n: f32 = r.sample(StandardNormal);
            self.q[i] = MU[i] + START_SD * n;
            self.lens[i] = LINKS[i] * design[i];
        }
        self.obs[5..].copy_from_slice(design);
        self.ready = true;
        self.observe();
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        if !self.ready {
            return Err(EnvError::NotRunning);
        }
        self.spec.action.check_finite("action", action).map_err(EnvError::Action)?;
        for (q, a) in self.q.iter_mut().zip(action) {
            *q += MAX_DELTA * a.clamp(-1.0, 1.0);
        }
        self.observe();
        let tip = self.tip();
        let (dx, dz) = (tip[0] - BASE[0], tip[1] - BASE[1]);
        let (reward, terminated) = if self.obs[3].hypot(self.obs[4]) < SUCCESS_RADIUS {
            (1.0, true)
        } else if !(WORKSPACE[0]..=WORKSPACE[1]).contains(&dx) || !(WORKSPACE[2]..=WORKSPACE[3]).contains(&dz) {
            (-1.0, true)
        } else {
            (0.0, false)
        };
        self.ready = !terminated;
        Ok(Step { observation: &self.obs, reward, terminated, truncated: false })
    }

    /// The arm (three capsules from the base), the base, and the target as a ball of the
    /// success radius.
    fn draw(&self, out: &mut Vec<Shape>) {
        let p = forward(&self.q, &self.lens);
        for i in 0..3 {
            out.push(Shape::Capsule { a: [p[i][0], 0.0, p[i][1]], b: [p[i + 1][0], 0.0, p[i + 1][1]], radius: 0.035 });
        }
        out.push(Shape::Sphere { centre: [BASE[0], 0.0, BASE[1]], radius: 0.06 });
        let t = target();
        out.push(Shape::Sphere { centre: [t[0], 0.0, t[1]], radius: SUCCESS_RADIUS });
    }
}
