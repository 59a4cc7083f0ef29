//! Walker in rapier2d: MuJoCo's `walker2d.xml` (the thesis's PyBullet Walker), with the design
//! scaling the thigh, leg and foot of both legs.
//!
//! # The body
//! MuJoCo's `walker2d.xml` in the plane: an upright torso capsule 0.4 m long (radius 0.05) with two
//! legs hinged at its bottom end, each a thigh (radius 0.05), a leg (0.04) and a foot (0.06). The
//! thigh and leg hang straight down from their joints, the foot points forwards from the ankle at
//! its heel end; their lengths are `design[i] x (0.45, 0.5, 0.2)` (right leg, then left). In the
//! plane the two legs overlap; parts touch the ground only, not each other (MuJoCo's
//! contype/conaffinity). Masses are MuJoCo's density 1000 kg/m^3 times the 3D capsule volume, so
//! longer legs weigh more; friction 0.9 everywhere (gymnasium's Walker2d-v5, which also gives the
//! left foot the right's friction). Joint ranges, armature (0.01 kg m^2) and damping
//! (0.1 N m s/rad) are MuJoCo's. Angles use MuJoCo's signs (the joints turn about `-y`: a positive
//! angle is counter-clockwise with x forwards and z up), so the ranges are as in the XML: thigh
//! and knee [-150, 0] deg (the thigh swings backwards only, the knee bends like a human's), ankle
//! [-45, 45] deg. Torque `0.9 x 100 x clip(a, -1, 1)` on every joint: walker2d's gear 100, scaled
//! by the reference's power factor 0.9 as HalfCheetah's powers are.
//!
//! # Episodes
//! Run by [`PlanarEnv`] (see [`crate::planar`]): joint angles uniform in +-0.5 rad clamped to
//! the limits (so each thigh and knee starts in [-0.5, 0]), the torso upright with the body's
//! lowest point 1 cm above the ground, then [`SimConfig::settle_steps`] control steps (5, 0.08 s:
//! the drop takes 0.045 s) with the joints held at those angles while the body lands, as the
//! reference holds its joints while it lowers the body onto the ground. The joints are then free,
//! and the walker falls unless the policy catches it: a limp settle would start every episode
//! from a heap on the ground, and a longer held one lets a pose that does not balance topple as a
//! rigid body (after 5 steps the torso moves at most 0.6 m/s over the corner designs). The
//! observation is the 17-dim state, then the design: the 6 joint angles scaled to [-1, 1] by
//! their limits, the 6 joint velocities x 0.1, then (MuJoCo's order) torso forward velocity,
//! vertical velocity, pitch rate, pitch (positive nose-down) and height change since the episode
//! started (after settling). Reward `((h > 0.8) (max(vx, 0) + 1) - 0.1 |pitch|) / 10` with `h`
//! the torso centre's height above the ground. The 0.8 m threshold is the thesis's for every
//! design, although the standing height scales with the legs: upright on straight legs the torso
//! centre is at `0.06 + 0.5 d_leg + 0.45 d_thigh + 0.2` m (1.21 m for the original design, 0.74 m
//! with both scales at 0.5, which therefore never earns the standing term). Never terminated;
//! 1000-step episodes.
//!
//! # Simulation setting, from measurements
//! HalfCheetah's setting (multibody joints, 2 physics steps of 8.25 ms per control step, 4 solver
//! iterations) with walker2d's own armature lets joints overshoot their limits by 0.2-0.3 rad:
//! every joint gets 90 N m, and a foot of 2-4 kg swings fast. `cargo test --release -p
//! coadapt-robots --test all planar_robots::measure_limit_violations -- --ignored --nocapture` gives,
//! as HalfCheetah's sweep does, the worst violation over 10,000 steps of random full-torque
//! actions (each held for 1-20 steps, new episode every 1000) for the designs `[0.5]*6`, `[1]*6`
//! and `[1.5]*6`, and the deepest any part went into the ground over the three:
//!
//! | physics steps | solver iterations | armature (kg m^2) | worst violation (rad) | in ground (m) |
//! |---|---|---|---|---|
//! | 2 | 4 | 0.01 (walker2d's) | 0.298 / 0.198 / 0.144 | 0.096 |
//! | 2 | 8 | 0.01 | 0.143 / 0.086 / 0.065 | 0.109 |
//! | 4 | 4 | 0.01 | 0.125 / 0.075 / 0.077 | 0.049 |
//! | 2 | 4 | 0.1 | 0.146 / 0.117 / 0.093 | 0.093 |
//! | **2** | **6** | **0.1** | **0.073 / 0.060 / 0.059** | **0.076** |
//! | 2 | 8 | 0.1 | 0.055 / 0.052 / 0.043 | 0.084 |
//! | 4 | 4 | 0.1 | 0.068 / 0.052 / 0.041 | 0.026 |
//! | 2 | 4 | 0.2 | 0.112 / 0.084 / 0.074 | 0.068 |
//!
//! Chosen ([`Robot::default_config`]): HalfCheetah's armature 0.1 and 2 x 6 (two more solver
//! iterations than HalfCheetah): limits hold to 0.073 rad, near HalfCheetah's 0.057, for 15-25 %
//! of the speed of 2 x 4. Env steps/s (`measure_speed`: [`crate::bench`], original design, uniform
//! random actions, resets included; best of 5 one-second runs in turn with HalfCheetah and Hopper,
//! the 2 x 4 rows one two-second run; two runs on 2 cores loaded by a training run and builds, load
//! average about 4):
//!
//! | robot | env steps/s |
//! |---|---|
//! | Walker, 2 x 6 (default) | 7,600 / 7,900 |
//! | Walker, 2 x 4 | 8,800 / 10,700 |
//! | HalfCheetah, 2 x 4 (its default), same runs | 10,100 / 10,200 |
//!
//! HalfCheetah ran 15,000 on an idle machine, so Walker should run about 11,500 there.

use crate::planar::{BodyPlan, Capsule, JointKind, Limb, PlanarEnv, Robot, SimConfig, Torso, capsule_mass};
use crate::planar::{deg, walker_reward, walker_torso_state};
use rapier2d::prelude::Vector;

/// Segment lengths at design 1: thigh, leg, foot of the right leg, then of the left.
pub const BASE_LENGTHS: [f32; 6] = [0.45, 0.5, 0.2, 0.45, 0.5, 0.2];
/// Capsule radius of thigh, leg and foot.
pub const RADII: [f32; 3] = [0.05, 0.04, 0.06];
/// Joint ranges `[lo, hi]` in radians, MuJoCo's `walker2d.xml`: thigh, knee, ankle, right then left.
pub const JOINT_LIMITS: [[f32; 2]; 6] =
    [[deg(-150.0), 0.0], [deg(-150.0), 0.0], [deg(-45.0), deg(45.0)], [deg(-150.0), 0.0], [deg(-150.0), 0.0], [deg(-45.0), deg(45.0)]];
/// Joint torque at full action (before the 0.9 power factor), in N m: walker2d's gear.
pub const POWERS: [f32; 6] = [100.0; 6];
/// The torso capsule runs from 0.2 below its centre (the hips) to 0.2 above.
const TORSO_HALF_LENGTH: f32 = 0.2;
const TORSO_RADIUS: f32 = 0.05;
const DENSITY: f32 = 1000.0;
const FRICTION: f32 = 0.9;
/// MuJoCo's joint damping (N m s/rad).
const DAMPING: f32 = 0.1;
/// Joint armature (kg m^2): HalfCheetah's MuJoCo value, not walker2d's 0.01, under which the light
/// feet swing 0.2-0.3 rad through their limits (module docs).
const ARMATURE: f32 = 0.1;

/// The Walker environment (see the module documentation).
pub type Walker = PlanarEnv<WalkerModel>;

/// Walker's [`Robot`] description.
#[derive(Debug)]
pub struct WalkerModel;

impl Robot for WalkerModel {
    const NAME: &'static str = "walker";
    const JOINT_LIMITS: &'static [[f32; 2]] = &JOINT_LIMITS;
    const POWERS: &'static [f32] = &POWERS;
    const DESIGN_LOW: &'static [f32] = &[0.5; 6];
    const DESIGN_HIGH: &'static [f32] = &[1.5; 6];
    const DEFAULT_DESIGN: &'static [f32] = &[1.0; 6];
    const DESIGN_NAMES: &'static [&'static str] = &["right thigh", "right leg", "right foot", "left thigh", "left leg", "left foot"];

    fn default_config() -> SimConfig {
        SimConfig {
            joints: JointKind::Multibody,
            substeps: 2,
            solver_iterations: 6,
            armature: ARMATURE,
            settle_steps: 5,
            hold_while_settling: true,
            ..SimConfig::default()
        }
    }

    fn plan(design: &[f32]) -> BodyPlan {
        let capsule = |a: Vector, b: Vector, radius: f32, len: f32| Capsule { a, b, radius, mass: capsule_mass(DENSITY, radius, len) };
        let hips = Vector::new(0.0, -TORSO_HALF_LENGTH);
        let torso = vec![capsule(hips, -hips, TORSO_RADIUS, 2.0 * TORSO_HALF_LENGTH)];
        let mut limbs = Vec::with_capacity(6);
        for leg in 0..2 {
            let l: [f32; 3] = std::array::from_fn(|k| design[3 * leg + k] * BASE_LENGTHS[3 * leg + k]);
            let down = |len: f32| Vector::new(0.0, -len);
            let first = 3 * leg;
            let segments =
                [(None, hips, down(l[0])), (Some(first), down(l[0]), down(l[1])), (Some(first + 1), down(l[1]), Vector::new(l[2], 0.0))];
            for (k, (parent, anchor, end)) in segments.into_iter().enumerate() {
                limbs.push(Limb {
                    parent,
                    anchor,
                    capsule: capsule(Vector::ZERO, end, RADII[k], l[k]),
                    limits: JOINT_LIMITS[first + k],
                    damping: DAMPING,
                });
            }
        }
        BodyPlan { torso, limbs, friction: FRICTION, clockwise: false }
    }

    fn start_height(_design: &[f32], plan: &BodyPlan, angles: &[f32]) -> f32 {
        plan.touching_start_height(angles)
    }

    fn torso_state(t: &Torso, height_change: f32) -> [f32; 5] {
        walker_torso_state(t, height_change)
    }

    fn reward(t: &Torso) -> f32 {
        walker_reward(t)
    }
}
