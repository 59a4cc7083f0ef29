//! HalfCheetah in rapier2d: the reference's PyBullet HalfCheetahBulletEnv, with the design scaling
//! the six leg segments.
//!
//! # The body
//! MuJoCo's `half_cheetah.xml` in the plane: a torso capsule 1 m long with a head, and two legs
//! (thigh, shin, foot) hinged at its ends, every capsule of radius 0.046. Each segment is a capsule
//! from its joint to the next one, of length `design[i] x (0.29, 0.3, 0.188)` (back thigh, shin,
//! foot, then the front leg with the same base lengths, as the product brief says; the reference's
//! code keeps MuJoCo's shorter front leg, 0.266, 0.212, 0.14), pointing along MuJoCo's geom axis.
//! Masses are MuJoCo's density (14 kg over the original geoms) times the 3D capsule volume, so
//! longer legs weigh more. Joint ranges, armature and damping are MuJoCo's (the reference's XML
//! narrows a few ranges); MuJoCo's joint springs are left out, so a zero action leaves the legs
//! limp. Parts touch the ground only, not each other; friction 0.4. Torque
//! `0.9 x power x clip(a, -1, 1)` with powers 120/90/60/90/60/30 N m (the reference's front thigh
//! has 90, not MuJoCo's 120). See `body.rs` for the geometry and the sign conventions.
//!
//! # Episodes
//! `reset` rebuilds the world for the design (about 15 us), puts the torso level above the longest
//! leg with joint angles uniform in +-0.5 rad (clamped to the limits), then lets the body fall and
//! settle for [`SimConfig::settle_steps`] zero-torque control steps (60, about 1 s: a fall of up to
//! 1.6 m and the rocking after it; the reference settles for 0.8 s). A control step is 0.0165 s.
//! The observation is the 17-dim state, then the design: joint angles scaled to [-1, 1] by their
//! limits, joint velocities x 0.1, torso forward velocity, pitch rate, vertical velocity, pitch and
//! height change since the episode started (after settling). Reward `max(vx / 10, 0)`; no terminal
//! state (1000-step episodes are cut by [`coadapt_core::TimeLimit`]).
//!
//! # Simulation setting, from measurements
//! The bar is MuJoCo HalfCheetah-v5 through gymnasium: about 10,300 env steps/s on one core of
//! this machine in `peers.md`, 13,200-13,600 when timed beside ours on an idle machine (gymnasium
//! 1.4, mujoco 4.0), where the default setting below ran 15,000 (`cheetah_speed`, uniform random
//! actions, resets with their settling included).
//!
//! `cargo run --release -p coadapt-robots --example cheetah_speed -- --sweep` measures each
//! setting over 10,000 steps of random full-torque actions (each held for 1-20 steps, new episode
//! every 1000) per design: env steps/s (design `[1]*6`; timings on this shared machine vary by
//! +-20 %), the worst joint-limit violation in radians for designs `[0.8]*6` / `[1]*6` / `[2]*6`, and
//! the deepest any part went into the ground over the three designs. "Steps" are physics steps
//! per 0.0165 s control step, "iters" rapier's solver iterations (TGS substeps) per physics step,
//! "MuJoCo joints" MuJoCo's joint armature 0.1 kg m^2 and damping (6, 4.5, 3, 4.5, 3, 1.5 N m s).
//!
//! | joints | steps | iters | MuJoCo joints | env steps/s | worst violation (rad) | in ground (m) |
//! |---|---|---|---|---|---|---|
//! | multibody | 1 | 4 | no | 32,900 | 1.43 / 1.03 / 0.33 | 0.24 |
//! | multibody | 2 | 2 | no | 28,000 | 2.74 / 0.84 / 0.29 | blew up |
//! | multibody | 4 | 1 | no | 20,500 | 1.01 / 0.87 / 0.29 | 0.071 |
//! | multibody | 1 | 2 | yes | 49,800 | 0.24 / 0.22 / 0.16 | 0.126 |
//! | multibody | 1 | 4 | yes | 26,800 | 0.11 / 0.12 / 0.08 | 0.130 |
//! | multibody | 1 | 8 | yes | 17,000 | 0.046 / 0.054 / 0.043 | 0.148 |
//! | multibody | 1 | 12 | yes | 12,900 | 0.026 / 0.031 / 0.021 | 0.138 |
//! | multibody | 2 | 1 | yes | 42,100 | 0.21 / 0.24 / 0.18 | 0.074 |
//! | multibody | 2 | 2 | yes | 27,300 | 0.098 / 0.105 / 0.085 | 0.056 |
//! | **multibody** | **2** | **4** | **yes** | **14,700** | **0.049 / 0.057 / 0.038** | **0.058** |
//! | multibody | 2 | 6 | yes | 11,400 | 0.027 / 0.036 / 0.024 | 0.065 |
//! | multibody | 4 | 1 | yes | 20,200 | 0.11 / 0.11 / 0.08 | 0.054 |
//! | multibody | 4 | 2 | yes | 14,200 | 0.052 / 0.050 / 0.041 | 0.055 |
//! | impulse | 1 | 4 | - | 84,400 | 2.74 / 2.74 / 1.04 | 0.205 |
//! | impulse | 1 | 8 | - | 57,500 | 2.74 / 2.73 / 0.53 | 0.220 |
//! | impulse | 2 | 4 | - | 48,000 | 2.74 / 2.74 / 0.50 | 0.131 |
//! | impulse | 4 | 2 | - | 36,300 | 2.74 / 2.72 / 0.48 | 0.059 |
//! | impulse | 4 | 4 | - | 28,600 | 2.55 / 1.36 / 0.21 | 0.041 |
//! | impulse, warm-started | 4 | 4 | - | 26,700 | 2.62 / 1.31 / 0.20 | 0.056 |
//! | impulse | 8 | 2 | - | 20,900 | 2.57 / 1.24 / 0.22 | 0.013 |
//!
//! What the numbers say. rapier's limit constraints engage only once a joint is past its limit, so
//! the overshoot is the joint speed times a solver substep, and a foot of under 1 kg driven by
//! 54 N m is fast: impulse joints let light limbs swing right through their limits (2.7 rad is a
//! joint gone round the other side), at any affordable step count. Multibody joints alone do
//! little better, and without armature one configuration flung the body away. MuJoCo's own
//! model carries joint armature and damping for exactly this; with them, the overshoot falls with
//! the solver iterations. Two physics steps per control step halve how deep a foot lands in the
//! ground (contacts are found once per physics step) for the same solver work as one step with
//! twice the iterations.
//!
//! Chosen ([`SimConfig::default`]): multibody joints with MuJoCo's armature and damping, 2 physics
//! steps of 8.25 ms with 4 solver iterations each: limits hold to 0.06 rad under this abuse,
//! feet sink at most 6 cm on impact, at about 1.1x MuJoCo's speed measured in the same run
//! (1.45x the figure in `peers.md`). 1 x 8 is as fast with the same limits but lands feet 15 cm
//! deep; 2 x 6 holds limits to 0.036 rad but only matches MuJoCo's speed.

mod body;

pub use body::{BASE_LENGTHS, JOINT_LIMITS, POWERS, RADIUS, start_height};

use body::Body;
use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step, rng};
use rand::Rng;

/// Seconds per control step (the reference: 4 PyBullet steps of 0.0165 / 4).
pub const CONTROL_DT: f32 = 0.0165;
/// The reference scales every joint power by 0.9.
const POWER_FACTOR: f32 = 0.9;
const STATE_DIM: usize = 17;

/// How the joints are simulated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    /// Reduced coordinates: the segments cannot drift apart, and limits hold far better.
    Multibody,
    /// One rigid body per segment held together by constraints: cheaper, but light segments
    /// swing through their limits.
    Impulse,
}

/// The physics knobs; [`SimConfig::default`] is the measured choice documented above.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    pub joints: JointKind,
    /// Physics steps per control step.
    pub substeps: usize,
    /// rapier's solver iterations per physics step (each one a TGS substep).
    pub solver_iterations: usize,
    /// Impulse joints only: start each step from the last step's joint impulses.
    pub warmstart_joints: bool,
    /// Multibody joints only: rotor inertia added to each joint, kg m^2 (MuJoCo's is 0.1).
    pub armature: f32,
    /// Multibody joints only: MuJoCo's joint damping (6, 4.5, 3, 4.5, 3, 1.5 N m s/rad).
    pub joint_damping: bool,
    /// Zero-torque control steps after a reset, before the first observation.
    pub settle_steps: usize,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            joints: JointKind::Multibody,
            substeps: 2,
            solver_iterations: 4,
            warmstart_joints: false,
            armature: 0.1,
            joint_damping: true,
            settle_steps: 60,
        }
    }
}

/// The HalfCheetah environment (see the module documentation).
#[derive(Debug)]
pub struct HalfCheetah {
    spec: EnvSpec,
    cfg: SimConfig,
    body: Option<Body>,
    design: [f32; 6],
    initial_height: f32,
    obs: [f32; STATE_DIM + 6],
}

impl Default for HalfCheetah {
    fn default() -> Self {
        Self::new()
    }
}

impl HalfCheetah {
    pub fn new() -> Self {
        Self::with_config(SimConfig::default())
    }

    /// The environment with other physics settings (for measurements).
    pub fn with_config(cfg: SimConfig) -> Self {
        let spec = EnvSpec {
            name: "half-cheetah".into(),
            state_dim: STATE_DIM,
            action: BoxSpace::uniform(6, -1.0, 1.0),
            design: BoxSpace::uniform(6, 0.8, 2.0),
            default_design: vec![1.0; 6],
            max_episode_steps: 1000,
        };
        Self { spec, cfg, body: None, design: [1.0; 6], initial_height: 0.0, obs: [0.0; STATE_DIM + 6] }
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Joint angles in radians (MuJoCo's signs), or `None` before the first reset.
    pub fn joint_angles(&self) -> Option<[f32; 6]> {
        self.body.as_ref().map(|b| b.joints().0)
    }

    /// How far the joint furthest outside its range is outside it, in radians (0 when all hold).
    pub fn limit_violation(&self) -> f32 {
        let Some(q) = self.joint_angles() else { return 0.0 };
        q.iter().zip(&JOINT_LIMITS).map(|(&q, &[lo, hi])| (lo - q).max(q - hi).max(0.0)).fold(0.0, f32::max)
    }

    /// Torso height in metres, or `None` before the first reset.
    pub fn torso_height(&self) -> Option<f32> {
        self.body.as_ref().map(|b| b.torso().0[1])
    }

    /// Height of the lowest point of the body's surface (negative: a part is in the ground), or
    /// `None` before the first reset.
    pub fn lowest_point(&self) -> Option<f32> {
        self.body.as_ref().map(Body::lowest_point)
    }

    fn advance(&mut self, torques: &[f32; 6]) {
        if let Some(body) = self.body.as_mut() {
            body.set_torques(torques);
            for _ in 0..self.cfg.substeps {
                body.step();
            }
        }
    }

    /// Fills the observation; errs if the simulation produced a non-finite state.
    fn observe(&mut self) -> Result<(), EnvError> {
        let Some(body) = self.body.as_ref() else { return Err(EnvError::NotRunning) };
        let (q, qd) = body.joints();
        let (pos, vel, pitch, pitch_rate) = body.torso();
        for i in 0..6 {
            let [lo, hi] = JOINT_LIMITS[i];
            self.obs[i] = 2.0 * (q[i] - lo) / (hi - lo) - 1.0;
            self.obs[6 + i] = 0.1 * qd[i];
        }
        self.obs[12..17].copy_from_slice(&[vel[0], pitch_rate, vel[1], pitch, pos[1] - self.initial_height]);
        self.obs[17..].copy_from_slice(&self.design);
        match self.obs.iter().position(|x| !x.is_finite()) {
            Some(i) => Err(EnvError::Backend(format!("half-cheetah simulation diverged: observation[{i}] = {}", self.obs[i]))),
            None => Ok(()),
        }
    }
}

impl Env for HalfCheetah {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        self.body = None;
        self.design.copy_from_slice(design);
        let mut r = rng(seed, 0);
        let mut angles = [0.0; 6];
        for (a, [lo, hi]) in angles.iter_mut().zip(JOINT_LIMITS) {
            *a = r.random_range(-0.5f32..0.5).clamp(lo, hi);
        }
        let lengths: [f32; 6] = std::array::from_fn(|i| design[i] * BASE_LENGTHS[i]);
        self.body = Some(Body::build(&lengths, &angles, &self.cfg));
        for _ in 0..self.cfg.settle_steps {
            self.advance(&[0.0; 6]);
        }
        self.initial_height = self.torso_height().unwrap_or(0.0);
        if let Err(e) = self.observe() {
            self.body = None;
            return Err(e);
        }
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        if self.body.is_none() {
            return Err(EnvError::NotRunning);
        }
        self.spec.action.check_finite("action", action).map_err(EnvError::Action)?;
        let torques: [f32; 6] = std::array::from_fn(|i| POWER_FACTOR * POWERS[i] * action[i].clamp(-1.0, 1.0));
        self.advance(&torques);
        if let Err(e) = self.observe() {
            self.body = None;
            return Err(e);
        }
        let reward = (self.obs[12] / 10.0).max(0.0);
        Ok(Step { observation: &self.obs, reward, terminated: false, truncated: false })
    }

    fn draw(&self, out: &mut Vec<coadapt_core::Shape>) {
        if let Some(b) = &self.body {
            b.draw(out);
        }
    }
}
