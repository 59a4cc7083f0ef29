//! What the planar robots (HalfCheetah, Walker, Hopper) share: the rapier2d body built from a
//! [`BodyPlan`] of capsules, the physics setting, and the environment around it, [`PlanarEnv`].
//!
//! A robot is a [`Robot`]: its name, design space, joint limits and powers, the body for a design,
//! where the torso starts, and its state layout and reward. [`PlanarEnv<R>`] does the rest the same
//! way for every robot:
//! - `reset` checks the design, draws joint angles uniform in +-0.5 rad (clamped to the limits)
//!   from the seed, rebuilds the world for the design, puts the torso level at the robot's start
//!   height, and runs [`SimConfig::settle_steps`] zero-torque control steps before the first
//!   observation (with [`SimConfig::hold_while_settling`] stiff, damped joint springs hold the
//!   start angles meanwhile, so a standing robot lands on its feet);
//! - `step` clips the action to [-1, 1] (non-finite or wrong-length actions are errors), applies
//!   torque `0.9 x power x a` per joint for one control step of [`CONTROL_DT`] (the user torques
//!   are set afresh every step), and never terminates (the thesis keeps no terminal states; 1000-
//!   step episodes are cut by [`coadapt_core::TimeLimit`]);
//! - the observation is the state, then the design: joint angles scaled to [-1, 1] by their
//!   limits, joint velocities x 0.1, then five torso values in the robot's order
//!   ([`Robot::torso_state`]); a non-finite state is an [`EnvError::Backend`] that ends the
//!   episode.
//!
//! Same seed and design give bit-identical episodes: every world is built afresh and rapier is
//! deterministic on one machine.

mod body;

pub use body::{BodyPlan, Capsule, Limb, Torso, capsule_mass, wrap};

use crate::world::{World, WorldError};
use body::Body;
use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step, rng};
use rand::Rng;
use std::marker::PhantomData;

/// Seconds per control step (the reference: 4 PyBullet steps of 0.0165 / 4).
pub const CONTROL_DT: f32 = 0.0165;
/// Gravity during episodes, m/s^2.
pub const GRAVITY: f32 = 9.81;
/// The reference scales every joint power by 0.9.
pub const POWER_FACTOR: f32 = 0.9;
/// Torso values after the joint angles and velocities in every state.
const TORSO_VALUES: usize = 5;

/// How the joints are simulated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    /// Reduced coordinates: the segments cannot drift apart, and limits hold far better.
    Multibody,
    /// One rigid body per segment held together by constraints: cheaper, but light segments
    /// swing through their limits.
    Impulse,
}

/// The physics knobs. [`SimConfig::default`] is the setting measured on HalfCheetah (see
/// [`crate::half_cheetah`]); each robot's [`Robot::default_config`] starts from it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    pub joints: JointKind,
    /// Physics steps per control step.
    pub substeps: usize,
    /// rapier's solver iterations per physics step (each one a TGS substep).
    pub solver_iterations: usize,
    /// Impulse joints only: start each step from the last step's joint impulses.
    pub warmstart_joints: bool,
    /// Multibody joints only: rotor inertia added to each joint, kg m^2 (MuJoCo's armature; the
    /// default is HalfCheetah's 0.1).
    pub armature: f32,
    /// Multibody joints only: the model's MuJoCo joint damping ([`Limb::damping`]); `false` leaves
    /// the joints undamped.
    pub joint_damping: bool,
    /// Zero-torque control steps after a reset, before the first observation.
    pub settle_steps: usize,
    /// Multibody joints only: hold the joints at their start angles while settling (stiff, damped
    /// springs; they give about 0.01 rad under the body's weight), then free them.
    pub hold_while_settling: bool,
    /// Gravity while settling, m/s^2 (full gravity, 9.81, comes back for the episode): the
    /// reference lowers HalfCheetah for 0.8 s at 0.5 with its joints held, so the episode starts
    /// with the body on or just above the ground, its joints at the drawn angles.
    pub settle_gravity: f32,
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
            hold_while_settling: false,
            settle_gravity: GRAVITY,
        }
    }
}

/// One planar robot: everything [`PlanarEnv`] needs to know about it.
pub trait Robot: std::fmt::Debug + Send + 'static {
    /// Registry name (also in error messages).
    const NAME: &'static str;
    /// Joint ranges `[lo, hi]` in radians in the robot's sign convention, in joint (action) order;
    /// they also scale the observed angles.
    const JOINT_LIMITS: &'static [[f32; 2]];
    /// Joint torque at full action, before the 0.9 power factor, in N m.
    const POWERS: &'static [f32];
    /// Design bounds and the original design.
    const DESIGN_LOW: &'static [f32];
    const DESIGN_HIGH: &'static [f32];
    const DEFAULT_DESIGN: &'static [f32];
    /// What each design entry scales, in order (for an operator building a prototype).
    const DESIGN_NAMES: &'static [&'static str];

    /// The measured physics setting for this robot.
    fn default_config() -> SimConfig;
    /// The body for `design` (already checked against the bounds).
    fn plan(design: &[f32]) -> BodyPlan;
    /// Height of the torso's origin at reset, torso level and joints at `angles`.
    fn start_height(design: &[f32], plan: &BodyPlan, angles: &[f32]) -> f32;
    /// The five torso values of the state; `height_change` is the torso height minus its height
    /// when the episode started (after settling).
    fn torso_state(torso: &Torso, height_change: f32) -> [f32; TORSO_VALUES];
    /// Reward of the step that ended in `torso`.
    fn reward(torso: &Torso) -> f32;
}

/// `x` degrees in radians (the MuJoCo models give their joint ranges in degrees).
pub const fn deg(x: f32) -> f32 {
    x * std::f32::consts::PI / 180.0
}

/// Walker's and Hopper's five torso values, in MuJoCo's `walker2d`/`hopper` order (the root's
/// velocities `x`, `z`, pitch): forward velocity, vertical velocity, pitch rate, then pitch and
/// height change.
pub fn walker_torso_state(t: &Torso, height_change: f32) -> [f32; TORSO_VALUES] {
    [t.vel[0], t.vel[1], t.pitch_rate, t.pitch, height_change]
}

/// Torso height above which Walker and Hopper count as standing.
pub const STANDING_HEIGHT: f32 = 0.8;

/// Walker's and Hopper's reward (the thesis's): `((h > 0.8) (max(vx, 0) + 1) - 0.1 |pitch|) / 10`
/// with `h` the torso's height above the ground (not its change).
pub fn walker_reward(t: &Torso) -> f32 {
    let standing = if t.pos[1] > STANDING_HEIGHT { 1.0 } else { 0.0 };
    (standing * (t.vel[0].max(0.0) + 1.0) - 0.1 * t.pitch.abs()) / 10.0
}

/// The environment of a planar robot `R` (see the module documentation).
#[derive(Debug)]
pub struct PlanarEnv<R: Robot> {
    spec: EnvSpec,
    cfg: SimConfig,
    body: Option<Body>,
    design: Vec<f32>,
    initial_height: f32,
    obs: Vec<f32>,
    torques: Vec<f32>,
    /// Friction, actuator strength and torso mass ([`World`]).
    world: World,
    robot: PhantomData<fn() -> R>,
}

impl<R: Robot> Default for PlanarEnv<R> {
    fn default() -> Self {
        Self::new()
    }
}

impl<R: Robot> PlanarEnv<R> {
    /// The robot with its measured physics setting.
    pub fn new() -> Self {
        Self::with_config(R::default_config())
    }

    /// The environment with other physics settings (for measurements).
    pub fn with_config(cfg: SimConfig) -> Self {
        let n = R::JOINT_LIMITS.len();
        let state_dim = 2 * n + TORSO_VALUES;
        let spec = EnvSpec {
            name: R::NAME.into(),
            state_dim,
            action: BoxSpace::uniform(n, -1.0, 1.0),
            design: BoxSpace { low: R::DESIGN_LOW.to_vec(), high: R::DESIGN_HIGH.to_vec() },
            design_names: R::DESIGN_NAMES.iter().map(|n| n.to_string()).collect(),
            default_design: R::DEFAULT_DESIGN.to_vec(),
            max_episode_steps: 1000,
        };
        let obs = vec![0.0; state_dim + R::DESIGN_LOW.len()];
        Self {
            spec,
            cfg,
            body: None,
            design: R::DEFAULT_DESIGN.to_vec(),
            initial_height: 0.0,
            obs,
            torques: vec![0.0; n],
            world: World::default(),
            robot: PhantomData,
        }
    }

    /// The robot in `world` (its friction, actuator strength and torso mass), refusing values
    /// no robot can have.
    pub fn in_world(world: World) -> Result<Self, WorldError> {
        world.check()?;
        Ok(Self { world, ..Self::new() })
    }

    /// The world this robot steps in.
    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Joint angles in radians (the robot's signs), or `None` before the first reset.
    pub fn joint_angles(&self) -> Option<Vec<f32>> {
        self.body.as_ref().map(|b| (0..R::JOINT_LIMITS.len()).map(|i| b.joint(i).0).collect())
    }

    /// How far the joint furthest outside its range is outside it, in radians (0 when all hold).
    pub fn limit_violation(&self) -> f32 {
        let Some(b) = self.body.as_ref() else { return 0.0 };
        let outside = |(i, &[lo, hi]): (usize, &[f32; 2])| {
            let q = b.joint(i).0;
            (lo - q).max(q - hi).max(0.0)
        };
        R::JOINT_LIMITS.iter().enumerate().map(outside).fold(0.0, f32::max)
    }

    /// Torso height in metres, or `None` before the first reset.
    pub fn torso_height(&self) -> Option<f32> {
        self.body.as_ref().map(|b| b.torso().pos[1])
    }

    /// Height of the lowest point of the body's surface (negative: a part is in the ground), or
    /// `None` before the first reset.
    pub fn lowest_point(&self) -> Option<f32> {
        self.body.as_ref().map(Body::lowest_point)
    }

    /// The torso's state (position, velocity, pitch), or `None` before the first reset.
    pub fn torso(&self) -> Option<Torso> {
        self.body.as_ref().map(Body::torso)
    }

    /// Height of each capsule's lowest surface point (the torso's capsules first, then one per
    /// limb in joint order), for diagnosing where a body rests on the ground; empty before the
    /// first reset.
    pub fn part_heights(&self, out: &mut Vec<f32>) {
        match self.body.as_ref() {
            Some(b) => b.part_heights(out),
            None => out.clear(),
        }
    }

    /// One control step with `self.torques`.
    fn advance(&mut self) {
        if let Some(body) = self.body.as_mut() {
            body.set_torques(&self.torques);
            for _ in 0..self.cfg.substeps {
                body.step();
            }
        }
    }

    /// Fills the observation and returns the torso state; errs if the simulation produced a
    /// non-finite state.
    fn observe(&mut self) -> Result<Torso, EnvError> {
        let Some(body) = self.body.as_ref() else { return Err(EnvError::NotRunning) };
        let n = R::JOINT_LIMITS.len();
        for (i, &[lo, hi]) in R::JOINT_LIMITS.iter().enumerate() {
            let (q, qd) = body.joint(i);
            self.obs[i] = 2.0 * (q - lo) / (hi - lo) - 1.0;
            self.obs[n + i] = 0.1 * qd;
        }
        let torso = body.torso();
        let state_dim = self.spec.state_dim;
        self.obs[2 * n..state_dim].copy_from_slice(&R::torso_state(&torso, torso.pos[1] - self.initial_height));
        self.obs[state_dim..].copy_from_slice(&self.design);
        match self.obs.iter().position(|x| !x.is_finite()) {
            Some(i) => Err(EnvError::Backend(format!("{} simulation diverged: observation[{i}] = {}", R::NAME, self.obs[i]))),
            None => Ok(torso),
        }
    }
}

impl<R: Robot> Env for PlanarEnv<R> {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        self.body = None;
        self.design.copy_from_slice(design);
        let mut r = rng(seed, 0);
        let angles: Vec<f32> = R::JOINT_LIMITS.iter().map(|&[lo, hi]| r.random_range(-0.5f32..0.5).clamp(lo, hi)).collect();
        let mut plan = R::plan(design);
        plan.friction = self.world.friction_or(plan.friction);
        for c in &mut plan.torso {
            c.mass *= self.world.torso_mass_scale;
        }
        let height = R::start_height(design, &plan, &angles);
        let mut body = Body::build(&plan, height, &angles, &self.cfg);
        let hold = self.cfg.hold_while_settling && self.cfg.settle_steps > 0;
        if hold {
            body.hold_joints(true);
        }
        body.set_gravity(self.cfg.settle_gravity);
        self.body = Some(body);
        self.torques.fill(0.0);
        for _ in 0..self.cfg.settle_steps {
            self.advance();
        }
        if let Some(body) = self.body.as_mut() {
            body.set_gravity(GRAVITY);
            if hold {
                body.hold_joints(false);
            }
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
        for ((t, &a), &power) in self.torques.iter_mut().zip(action).zip(R::POWERS) {
            *t = POWER_FACTOR * power * self.world.actuator_scale * a.clamp(-1.0, 1.0);
        }
        self.advance();
        let torso = match self.observe() {
            Ok(torso) => torso,
            Err(e) => {
                self.body = None;
                return Err(e);
            }
        };
        Ok(Step { observation: &self.obs, reward: R::reward(&torso), terminated: false, truncated: false })
    }

    fn draw(&self, out: &mut Vec<coadapt_core::Shape>) {
        if let Some(b) = &self.body {
            b.draw(out);
        }
    }
}
