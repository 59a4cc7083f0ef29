//! Daisy in rapier3d: the thesis's HEBI hexapod (six legs of three motors), with the design
//! setting each leg pair's segment lengths and base-motor range.
//!
//! # The body
//! A box torso 0.3 m wide, 0.5 m long and 0.1 m thick, 5 kg (chassis and the six base motors), and
//! six legs on its sides: front, middle and back pairs at y = 0.2, 0, -0.2 m, the corner legs
//! splayed 30 degrees forwards and backwards. A leg is a base motor turning about the vertical
//! (yaw), a 0.1 m coxa of 0.5 kg carrying the shoulder motor (pitch), the femur carrying the knee
//! motor (pitch; 0.5 kg plus 0.5 kg/m) and the tibia ending in the foot (0.1 kg plus 0.5 kg/m);
//! capsules of radius 0.04, 0.035 and 0.025 m; the original robot weighs 13.4 kg. The robot faces
//! +y, z is up. The whole robot is one rapier multibody, the torso its free root (reduced
//! coordinates: joints cannot come apart, and limits hold far better than with impulse joints).
//! Torque `0.9 x 20 N m x clip(a, -1, 1)` for every joint: a HEBI X8-9 peaks at about 20 N m.
//! Every joint has armature 0.1 kg m^2 (a geared motor's rotor inertia; MuJoCo's HalfCheetah uses
//! the same) and damping 5 N m s/rad: a DC motor's speed-torque line, since HEBI gives the X8-9 a
//! no-load speed of 30 rpm (3.1 rad/s) at 24 V, so full torque balances at 3.6 rad/s. Parts touch
//! the ground only, not each other (friction 0.8, the floor's too). See `body.rs` for the frames
//! and signs.
//!
//! # The design (9 values)
//! `[front femur, front tibia, middle femur, middle tibia, back femur, back tibia]` in metres,
//! bounds [0.12, 0.5], then each pair's base-motor range offset `[front, middle, back]` in
//! radians, bounds [-0.2, 0.2]: the base motor's range is `offset +- 0.6` rad (positive turns the
//! leg forwards on both sides), so a positive offset lets the leg reach further forwards and less
//! far back, and the standing pose turns the leg by the offset. The original design,
//! [`ORIGINAL_DESIGN`], is a HEBI Daisy leg's roughly equal segments: 0.3 m each (the real leg's
//! about 0.325 m, kept a little inside the bounds' middle) and no offsets. Shoulder range
//! [-1, 1] rad, knee [-1, 1.5] rad.
//!
//! # Episodes
//! `reset` rebuilds the world for the design, draws joint angles uniform within +-0.1 rad of the
//! standing pose (base at its range's centre, femur level, tibia hanging vertically), puts the
//! torso level at the [`start_height`] where no part can touch the ground, and lets the body settle
//! for [`SimConfig::settle_steps`] control steps (1 s) with every joint held at its start angle by
//! a PD controller (updated every physics step, within the motors' torque): the original design
//! starts standing, torso about 0.30 m high; a design too weak to hold itself sinks. With zero
//! actions afterwards the legs go limp and the torso comes to rest on the ground. Episodes last
//! 1000 control steps of 0.05 s (20 Hz, the real robot's tens of Hz); nothing terminates them.
//!
//! Observation (43 state values, then the 9 design values):
//!
//! | index | what |
//! |---|---|
//! | 0..18 | joint angles scaled to [-1, 1] by their limits, joint `3 * leg + k` (legs front right, front left, middle right, middle left, back right, back left; k = base, shoulder, knee) |
//! | 18..36 | joint velocities (rad/s) x 0.1, same order |
//! | 36..39 | the torso's rotation since the episode's start as a rotation vector (axis x angle, radians), in the start torso frame (x right, y forward, z up) |
//! | 39..42 | torso linear velocity, world frame (x, y forward, z up), m/s |
//! | 42 | torso height change since the episode's start, m |
//! | 43..52 | the design |
//!
//! Reward per step `max(dy, 0) / 0.066 - 0.25 angle`, where dy is the torso centre's progress
//! along +y during this step (m) and angle is the rotation angle (radians, in [0, pi]) between the
//! torso's orientation at the episode's start (after settling) and now, i.e. the norm of
//! observation 36..39: turning, rolling or pitching away from the start all cost alike.
//!
//! # Simulation setting, from measurements
//! `cargo test --release -p coadapt-robots --test all daisy::measure -- --ignored --nocapture` measures
//! each setting: env steps/s under uniform random actions (original design, resets included;
//! wall clock, on a machine shared with a training run, so +-20 %) and, over 10,000 steps of
//! random full-torque actions (each held for 1-20 steps, new episode every 1000), the worst
//! joint-limit violation for every length at 0.12 (offsets +0.2) / the original design / every
//! length at 0.5 (offsets +0.2), and the deepest any part went into the ground over the three.
//! "Steps" are physics steps per control step, "iters" rapier's solver iterations (TGS substeps)
//! per physics step, "sweeps" its Gauss-Seidel sweeps per iteration, "prediction" the distance
//! (m) at which contacts with the ground are made (rapier's default is 0.02). All with armature
//! 0.1 and damping 5.
//!
//! | control step (s) | steps | iters | sweeps | prediction | env steps/s | worst violation (rad) | in ground (m) |
//! |---|---|---|---|---|---|---|---|
//! | 0.05 | 1 | 4 | 1 | 0.2 | 2,000 | 0.066 / 0.077 / 0.075 | 0.106 |
//! | 0.05 | 2 | 1 | 1 | 0.2 | 2,690 | 0.119 / 0.116 / 0.154 | 0.035 |
//! | 0.05 | 2 | 2 | 1 | 0.02 | 1,960 | 0.059 / 0.083 / 0.096 | 0.154 |
//! | 0.05 | 2 | 2 | 1 | 0.1 | 1,770 | 0.061 / 0.076 / 0.068 | 0.032 |
//! | **0.05** | **2** | **2** | **1** | **0.2** | **1,870** | **0.059 / 0.076 / 0.065** | **0.020** |
//! | 0.05 | 2 | 2 | 4 | 0.2 | 1,850 | 0.075 / 0.059 / 0.080 | 0.020 |
//! | 0.05 | 2 | 3 | 1 | 0.2 | 1,210 | 0.036 / 0.037 / 0.055 | 0.020 |
//! | 0.05 | 2 | 4 | 1 | 0.2 | 1,010 | 0.029 / 0.036 / 0.030 | 0.013 |
//! | 0.05 | 3 | 1 | 1 | 0.2 | 1,740 | 0.069 / 0.083 / 0.078 | 0.030 |
//! | 0.05 | 3 | 2 | 1 | 0.2 | 1,140 | 0.039 / 0.044 / 0.037 | 0.011 |
//! | 0.05 | 4 | 1 | 1 | 0.2 | 1,460 | 0.051 / 0.069 / 0.061 | 0.017 |
//! | 0.05 | 4 | 2 | 1 | 0.2 | 820 | 0.027 / 0.032 / 0.026 | 0.008 |
//! | 0.0165 | 1 | 2 | 1 | 0.2 | 3,320 | 0.038 / 0.040 / 0.054 | 0.012 |
//! | 0.0165 | 1 | 4 | 1 | 0.2 | 1,870 | 0.017 / 0.032 / 0.017 | 0.010 |
//!
//! What the numbers say. The cost is rapier's multibody dynamics: every solver iteration rebuilds
//! the 24 x 24 mass matrix from 19 links' Jacobians and factorises it (about 80 % of the time in
//! `perf`), so the price of a setting is its physics steps x iterations, and Gauss-Seidel sweeps
//! (which do not rebuild it) come free but do not help. As for HalfCheetah, a limit engages only
//! once its joint is past it, so the overshoot is the joint's speed times a solver substep: the
//! motors' damping and armature keep joint speeds low, which is what lets 4 substeps of 12.5 ms
//! hold the limits to 0.08 rad (with armature 0.05 the same setting overshot by 0.11-0.14 rad, and
//! with damping 2 as well, 9 rad/s joints, by 0.12-0.17 rad over 2,000 steps). Feet landing at speed sink through the ground within one
//! physics step unless contacts are made early: a prediction distance of 0.2 m (rapier's
//! speculative contacts then stop the part at the surface) cuts the deepest sinking from 15 cm to
//! 2 cm at no measurable cost. Per simulated second, a 0.0165 s control step costs the same as
//! 0.05 s with the same substep length.
//!
//! Tried and dropped: each leg its own multibody (8 degrees of freedom) hung on the torso by an
//! impulse joint at the base motor, to shrink the mass matrices. At equal substeps it ran
//! 1.5-2.5x faster, but the impulse base joints overshot their limits by 0.6-1.3 rad at 8 or
//! fewer solver substeps per control step, and the simulation diverged (infinite coordinates) at
//! 2 x 2, both with damping 2 and 5 (2,000-step runs, armature 0.05).
//!
//! Chosen ([`SimConfig::default`]): a 0.05 s control step (the real robot's rate; each step, and
//! so each learner update, covers three times the robot time of a 0.0165 s step), 2 physics steps
//! of 25 ms with 2 solver iterations each, prediction distance 0.2 m: limits hold to 0.08 rad
//! under this abuse, parts sink at most 2 cm. Timed against HalfCheetah in one run
//! (`speed_against_half_cheetah`), Daisy ran about 1,650 env steps/s to HalfCheetah's 11,700:
//! 7x fewer steps, but only 2.3x fewer simulated seconds (a Daisy step is 0.05 s, a HalfCheetah step
//! 0.0165 s), and far more than the learner's updates per second. 2 x 3 holds limits to 0.055 rad
//! at two thirds of the speed.

mod body;

pub use body::{
    BASE_HALF_RANGE, COXA_LENGTH, FRICTION, JOINTS, KNEE_LIMITS, LEGS, POWERS, SHOULDER_LIMITS, TORSO_HALF_EXTENTS, TORSO_MASS,
    joint_limits, start_height,
};

use crate::world::{World, WorldError};
use body::{Body, Ground};
use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step, rng};
use rand::Rng;
use rapier3d::math::{Rotation, Vector};

/// The motors' torque at full action is 0.9 x power.
const POWER_FACTOR: f32 = 0.9;
const STATE_DIM: usize = 43;
const DESIGN_DIM: usize = 9;
const OBS_DIM: usize = STATE_DIM + DESIGN_DIM;
/// Start joint angles are uniform within this many radians of the standing pose.
pub const START_NOISE: f32 = 0.1;
/// Progress along +y that earns a reward of 1, m.
pub const PROGRESS_SCALE: f32 = 0.066;
/// Reward lost per radian of torso rotation since the start.
pub const ROTATION_PENALTY: f32 = 0.25;
/// Segment-length bounds (m) and base-offset bounds (rad).
pub const LENGTH_BOUNDS: [f32; 2] = [0.12, 0.5];
pub const OFFSET_BOUNDS: [f32; 2] = [-0.2, 0.2];
/// The original design: 0.3 m femur and tibia on every pair, no base offsets.
pub const ORIGINAL_DESIGN: [f32; DESIGN_DIM] = [0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.0, 0.0, 0.0];
/// What each design entry is: segment lengths in metres, then base-motor range offsets in radians.
pub const DESIGN_NAMES: [&str; DESIGN_DIM] = [
    "front femur",
    "front tibia",
    "middle femur",
    "middle tibia",
    "back femur",
    "back tibia",
    "front base offset",
    "middle base offset",
    "back base offset",
];
/// PD gains (N m/rad, N m s/rad) holding the start pose while the body settles.
const HOLD_KP: f32 = 60.0;
const HOLD_KD: f32 = 2.0;

/// The physics knobs; [`SimConfig::default`] is the measured choice documented above.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    /// Seconds per control step.
    pub control_dt: f32,
    /// Physics steps per control step.
    pub substeps: usize,
    /// rapier's solver iterations per physics step.
    pub solver_iterations: usize,
    /// Gauss-Seidel sweeps per solver iteration (rapier's default is 1): they refine joint limits
    /// and contacts without recomputing the multibody's mass matrix, which every solver
    /// iteration does.
    pub pgs_iterations: usize,
    /// How near (m) a part must come to the ground for a contact to be made: rapier's speculative
    /// contacts then stop it at the surface within one physics step (rapier's default is 0.02).
    pub prediction_distance: f32,
    /// Rotor inertia added to each joint, kg m^2.
    pub armature: f32,
    /// Viscous damping of each joint, N m s/rad.
    pub joint_damping: f32,
    /// Control steps with the start pose held after a reset, before the first observation.
    pub settle_steps: usize,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            control_dt: 0.05,
            substeps: 2,
            solver_iterations: 2,
            pgs_iterations: 1,
            prediction_distance: 0.2,
            armature: 0.1,
            joint_damping: 5.0,
            settle_steps: 20,
        }
    }
}

/// The Daisy hexapod environment (see the module documentation).
#[derive(Debug)]
pub struct Daisy {
    spec: EnvSpec,
    cfg: SimConfig,
    body: Option<Body>,
    design: [f32; DESIGN_DIM],
    limits: [[f32; 2]; JOINTS],
    start_pos: [f32; 3],
    start_rot: Rotation,
    last_y: f32,
    obs: [f32; OBS_DIM],
    /// Friction, actuator strength and torso mass ([`World`]).
    world: World,
}

impl Default for Daisy {
    fn default() -> Self {
        Self::new()
    }
}

/// Femur and tibia lengths per pair, and base offsets per pair, from a design vector.
fn split_design(design: &[f32]) -> ([[f32; 2]; 3], [f32; 3]) {
    (std::array::from_fn(|p| [design[2 * p], design[2 * p + 1]]), std::array::from_fn(|p| design[6 + p]))
}

/// The rotation taking `from` to `to`, with a non-negative scalar part (angle in [0, pi]).
fn relative_rotation(from: Rotation, to: Rotation) -> Rotation {
    let r = from.inverse() * to;
    if r.w < 0.0 { -r } else { r }
}

impl Daisy {
    pub fn new() -> Self {
        Self::with_config(SimConfig::default())
    }

    /// The environment with other physics settings (for measurements).
    pub fn with_config(cfg: SimConfig) -> Self {
        let mut low = vec![LENGTH_BOUNDS[0]; 6];
        low.extend([OFFSET_BOUNDS[0]; 3]);
        let mut high = vec![LENGTH_BOUNDS[1]; 6];
        high.extend([OFFSET_BOUNDS[1]; 3]);
        let design = BoxSpace::new(low, high).unwrap_or_else(|e| unreachable!("constant bounds: {e}"));
        let spec = EnvSpec {
            name: "daisy".into(),
            state_dim: STATE_DIM,
            action: BoxSpace::uniform(JOINTS, -1.0, 1.0),
            design,
            design_names: DESIGN_NAMES.iter().map(|n| n.to_string()).collect(),
            default_design: ORIGINAL_DESIGN.to_vec(),
            max_episode_steps: 1000,
        };
        Self {
            spec,
            cfg,
            body: None,
            design: ORIGINAL_DESIGN,
            limits: joint_limits(&[0.0; 3]),
            start_pos: [0.0; 3],
            start_rot: Rotation::IDENTITY,
            last_y: 0.0,
            obs: [0.0; OBS_DIM],
            world: World::default(),
        }
    }

    /// Daisy in `world` (its friction, actuator strength and torso mass), refusing values no
    /// robot can have.
    pub fn in_world(world: World) -> Result<Self, WorldError> {
        world.check()?;
        Ok(Self { world, ..Self::new() })
    }

    /// The world Daisy steps in.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// Joint `j`'s torque at full action, in N m.
    fn max_torque(&self, j: usize) -> f32 {
        POWER_FACTOR * POWERS[j % 3] * self.world.actuator_scale
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The current design's joint limits `[lo, hi]` (radians), joint `3 * leg + k`.
    pub fn limits(&self) -> &[[f32; 2]; JOINTS] {
        &self.limits
    }

    /// Joint angles in radians, or `None` before the first reset.
    pub fn joint_angles(&self) -> Option<[f32; JOINTS]> {
        self.body.as_ref().map(|b| b.joints().0)
    }

    /// How far the joint furthest outside its range is outside it, in radians (0 when all hold).
    pub fn limit_violation(&self) -> f32 {
        let Some(q) = self.joint_angles() else { return 0.0 };
        q.iter().zip(&self.limits).map(|(&q, &[lo, hi])| (lo - q).max(q - hi).max(0.0)).fold(0.0, f32::max)
    }

    /// Torso centre `[x, y, z]` in metres, or `None` before the first reset.
    pub fn torso_position(&self) -> Option<[f32; 3]> {
        self.body.as_ref().map(|b| b.torso().0.to_array())
    }

    /// Torso height in metres, or `None` before the first reset.
    pub fn torso_height(&self) -> Option<f32> {
        self.torso_position().map(|p| p[2])
    }

    /// Height of the lowest point of the body's surface (negative: a part is in the ground), or
    /// `None` before the first reset.
    pub fn lowest_point(&self) -> Option<f32> {
        self.body.as_ref().map(Body::lowest_point)
    }

    /// One control step with constant `torques`.
    fn advance(&mut self, torques: &[f32; JOINTS]) {
        if let Some(body) = self.body.as_mut() {
            for _ in 0..self.cfg.substeps {
                body.step(torques);
            }
        }
    }

    /// One control step holding the joints at `target` with a PD controller updated every
    /// physics step, its torque within the motors' limits.
    fn hold(&mut self, target: &[f32; JOINTS]) {
        let max: [f32; JOINTS] = std::array::from_fn(|j| self.max_torque(j));
        let Some(body) = self.body.as_mut() else { return };
        for _ in 0..self.cfg.substeps {
            let (q, qd) = body.joints();
            let torques: [f32; JOINTS] = std::array::from_fn(|j| (HOLD_KP * (target[j] - q[j]) - HOLD_KD * qd[j]).clamp(-max[j], max[j]));
            body.step(&torques);
        }
    }

    /// Fills the observation; errs if the simulation produced a non-finite state.
    fn observe(&mut self) -> Result<(), EnvError> {
        let Some(body) = self.body.as_ref() else { return Err(EnvError::NotRunning) };
        let (q, qd) = body.joints();
        let (pos, rot, vel) = body.torso();
        for j in 0..JOINTS {
            let [lo, hi] = self.limits[j];
            self.obs[j] = 2.0 * (q[j] - lo) / (hi - lo) - 1.0;
            self.obs[JOINTS + j] = 0.1 * qd[j];
        }
        let rotation = relative_rotation(self.start_rot, rot).to_scaled_axis();
        self.obs[36..39].copy_from_slice(&rotation.to_array());
        self.obs[39..42].copy_from_slice(&vel.to_array());
        self.obs[42] = pos.z - self.start_pos[2];
        self.obs[STATE_DIM..].copy_from_slice(&self.design);
        match self.obs.iter().position(|x| !x.is_finite()) {
            Some(i) => Err(EnvError::Backend(format!("daisy simulation diverged: observation[{i}] = {}", self.obs[i]))),
            None => Ok(()),
        }
    }
}

impl Env for Daisy {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        self.body = None;
        self.design.copy_from_slice(design);
        let (lengths, offsets) = split_design(design);
        self.limits = joint_limits(&offsets);
        let mut r = rng(seed, 0);
        let angles: [f32; JOINTS] = std::array::from_fn(|j| {
            let [lo, hi] = self.limits[j];
            let stand = if j % 3 == 0 { offsets[j / 6] } else { 0.0 };
            (stand + r.random_range(-START_NOISE..START_NOISE)).clamp(lo, hi)
        });
        let height = start_height(&lengths, START_NOISE);
        let ground = Ground { friction: self.world.friction_or(FRICTION), torso_mass: TORSO_MASS * self.world.torso_mass_scale };
        self.body = Some(Body::build(&lengths, &offsets, &angles, height, ground, &self.cfg));
        for _ in 0..self.cfg.settle_steps {
            self.hold(&angles);
        }
        if let Some(body) = self.body.as_ref() {
            let (pos, rot, _) = body.torso();
            self.start_pos = pos.to_array();
            self.start_rot = rot;
            self.last_y = pos.y;
        }
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
        let torques: [f32; JOINTS] = std::array::from_fn(|j| self.max_torque(j) * action[j].clamp(-1.0, 1.0));
        self.advance(&torques);
        if let Err(e) = self.observe() {
            self.body = None;
            return Err(e);
        }
        let y = self.body.as_ref().map_or(f32::NAN, |b| b.torso().0.y);
        let dy = y - self.last_y;
        self.last_y = y;
        let angle = Vector::from_slice(&self.obs[36..39]).length();
        let reward = dy.max(0.0) / PROGRESS_SCALE - ROTATION_PENALTY * angle;
        Ok(Step { observation: &self.obs, reward, terminated: false, truncated: false })
    }

    fn draw(&self, out: &mut Vec<coadapt_core::Shape>) {
        if let Some(b) = self.body.as_ref() {
            b.draw(out);
        }
    }
}
