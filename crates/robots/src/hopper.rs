//! Hopper in rapier2d: the thesis's four-joint Hopper, DeepMind Control's `hopper.xml` (torso with
//! a nose, pelvis, thigh, calf, foot), with the design scaling the nose and the four leg segments.
//!
//! # The body
//! dm_control's `hopper.xml` in the plane. An upright torso capsule from 0.05 below the torso's
//! origin to 0.2 above it (radius 0.0653) carries a nose: a capsule of radius 0.03 from (0.08, 0.13)
//! pointing forwards and slightly up, towards dm_control's (0.15, 0.14), `design[0] x 0.07` m long.
//! Below the torso hangs a chain of four hinged segments, in joint (action) order: the pelvis at
//! the waist, 0.05 below the torso's origin (`design[1] x 0.15`, radius 0.065); the thigh at the
//! hip, 0.05 below the pelvis's end (`design[2] x 0.33`, radius 0.04); the calf at the knee
//! (`design[3] x 0.32`, radius 0.03); the foot at the ankle, a capsule `design[4] x 0.25` long
//! across the ankle, 32 % of it behind (dm_control's -0.08 to 0.17, scaled as the reference
//! scales it; radius 0.04). Masses are MuJoCo's density 1000 kg/m^3 times the 3D capsule volumes;
//! friction 1 (MuJoCo's default); parts touch the ground only. Joint ranges, armature (0.2 kg m^2)
//! and damping (0.05 N m s/rad) are dm_control's. Angles use MuJoCo's signs (the joints turn about
//! `+y`: a positive angle is clockwise with x forwards and z up): waist [-30, 30] deg, hip
//! [-170, 10] (the thigh swings forwards), knee [5, 150] (the calf bends backwards; a straight leg
//! is just outside the range), ankle [-45, 45]. Torque `0.9 x 100 x clip(a, -1, 1)` on every joint:
//! the gear of MuJoCo's walker2d/hopper family scaled like HalfCheetah's powers (dm_control's own
//! gears are 30/40/30/10, and the reference's PyBullet port keeps those).
//!
//! The nose's base length is dm_control's 0.07 m: the design table in `DESIGN.md` lists it as 0.7,
//! which reads as a slip (a 0.7 m nose, 2.8 m at the upper bound, would outweigh the torso and
//! reach further than the leg); the reference's port scales dm_control's 0.07 m nose too.
//! [`BASE_LENGTHS`] holds it.
//!
//! # Episodes
//! As Walker's ([`crate::walker`]): joint angles uniform in +-0.5 rad clamped to the limits (so the
//! hip starts in [-0.5, 0.17] and the knee in [0.09, 0.5]), the torso upright with the lowest point
//! 1 cm above the ground, 5 control steps with the joints held while it lands, then free. State
//! (13): the 4 joint angles scaled to [-1, 1] by their limits, the 4 joint velocities x 0.1,
//! torso forward velocity, vertical velocity, pitch rate, pitch (positive nose-down) and height
//! change since the episode started; then the 5 design values. Reward as Walker's,
//! `((h > 0.8) (max(vx, 0) + 1) - 0.1 |pitch|) / 10` with `h` the height of the torso's origin
//! (the waist is 0.05 below it): upright on a straight leg it is at 0.94 m for the original
//! design, and at most 0.54 m with every leg segment at 0.5, so the smallest hoppers never earn
//! the standing term, while long-legged ones earn it crouching. Never terminated; 1000-step
//! episodes.
//!
//! # Simulation setting, from measurements
//! Worst joint-limit violation over 10,000 held random full-torque steps for the designs
//! `[0.5]*5`, `[1]*5` and `[4, 2, 2, 2, 2]`, and the deepest any part went into the ground (as
//! Walker's table, `measure_limit_violations`):
//!
//! | physics steps | solver iterations | armature (kg m^2) | worst violation (rad) | in ground (m) |
//! |---|---|---|---|---|
//! | 2 | 4 | 0.2 (dm_control's) | 0.095 / 0.090 / 0.080 | 0.089 |
//! | **2** | **6** | **0.2** | **0.064 / 0.058 / 0.045** | **0.088** |
//! | 2 | 8 | 0.2 | 0.043 / 0.049 / 0.032 | 0.076 |
//! | 4 | 4 | 0.2 | 0.049 / 0.041 / 0.032 | 0.088 |
//! | 2 | 6 | 0.1 | 0.093 / 0.088 / 0.058 | 0.088 |
//!
//! Chosen ([`Robot::default_config`]): dm_control's armature and Walker's 2 x 6, which holds the
//! limits to 0.064 rad. Env steps/s (`measure_speed`, as Walker's, the same loaded runs):
//!
//! | robot | env steps/s |
//! |---|---|
//! | Hopper, 2 x 6 (default) | 10,800 / 12,100 |
//! | Hopper, 2 x 4 | 12,800 / 15,900 |
//! | HalfCheetah, 2 x 4 (its default), same runs | 10,100 / 10,200 |
//!
//! With five bodies to HalfCheetah's seven, Hopper should run about 17,000 on an idle machine.

use crate::planar::{BodyPlan, Capsule, JointKind, Limb, PlanarEnv, Robot, SimConfig, Torso, capsule_mass};
use crate::planar::{deg, walker_reward, walker_torso_state};
use rapier2d::prelude::Vector;

/// Lengths at design 1: nose, pelvis, thigh, calf, foot.
pub const BASE_LENGTHS: [f32; 5] = [0.07, 0.15, 0.33, 0.32, 0.25];
/// Capsule radius of pelvis, thigh, calf and foot.
pub const RADII: [f32; 4] = [0.065, 0.04, 0.03, 0.04];
/// Joint ranges `[lo, hi]` in radians, dm_control's `hopper.xml`: waist, hip, knee, ankle.
pub const JOINT_LIMITS: [[f32; 2]; 4] =
    [[deg(-30.0), deg(30.0)], [deg(-170.0), deg(10.0)], [deg(5.0), deg(150.0)], [deg(-45.0), deg(45.0)]];
/// Joint torque at full action (before the 0.9 power factor), in N m.
pub const POWERS: [f32; 4] = [100.0; 4];
/// The torso capsule, from its bottom to its top, relative to the torso's origin.
const TORSO: [[f32; 2]; 2] = [[0.0, -0.05], [0.0, 0.2]];
const TORSO_RADIUS: f32 = 0.0653;
/// The nose starts at (0.08, 0.13) and points towards (0.15, 0.14).
const NOSE_START: [f32; 2] = [0.08, 0.13];
const NOSE_AXIS: [f32; 2] = [0.07, 0.01];
const NOSE_RADIUS: f32 = 0.03;
/// The waist sits 0.05 below the torso's origin, the hip 0.05 below the pelvis capsule's end.
const WAIST: [f32; 2] = [0.0, -0.05];
const HIP_GAP: f32 = 0.05;
/// Share of the foot behind the ankle (dm_control: 0.08 of 0.25).
const HEEL: f32 = 0.32;
const DENSITY: f32 = 1000.0;
const FRICTION: f32 = 1.0;
/// dm_control's joint damping (N m s/rad) and armature (kg m^2).
const DAMPING: f32 = 0.05;
const ARMATURE: f32 = 0.2;

/// The Hopper environment (see the module documentation).
pub type Hopper = PlanarEnv<HopperModel>;

/// Hopper's [`Robot`] description.
#[derive(Debug)]
pub struct HopperModel;

impl Robot for HopperModel {
    const NAME: &'static str = "hopper";
    const JOINT_LIMITS: &'static [[f32; 2]] = &JOINT_LIMITS;
    const POWERS: &'static [f32] = &POWERS;
    const DESIGN_LOW: &'static [f32] = &[0.5; 5];
    const DESIGN_HIGH: &'static [f32] = &[4.0, 2.0, 2.0, 2.0, 2.0];
    const DEFAULT_DESIGN: &'static [f32] = &[1.0; 5];
    const DESIGN_NAMES: &'static [&'static str] = &["nose", "pelvis", "thigh", "calf", "foot"];

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
        let l: [f32; 5] = std::array::from_fn(|i| design[i] * BASE_LENGTHS[i]);
        let capsule = |a: Vector, b: Vector, radius: f32, len: f32| Capsule { a, b, radius, mass: capsule_mass(DENSITY, radius, len) };
        let nose_start = Vector::from(NOSE_START);
        let nose_end = nose_start + Vector::from(NOSE_AXIS).normalize() * l[0];
        let torso = vec![
            capsule(Vector::from(TORSO[0]), Vector::from(TORSO[1]), TORSO_RADIUS, TORSO[1][1] - TORSO[0][1]),
            capsule(nose_start, nose_end, NOSE_RADIUS, l[0]),
        ];
        let down = |len: f32| Vector::new(0.0, -len);
        let anchors = [Vector::from(WAIST), down(l[1] + HIP_GAP), down(l[2]), down(l[3])];
        let limbs = (0..4)
            .map(|k| {
                let len = l[k + 1];
                let (a, b) =
                    if k == 3 { (Vector::new(-HEEL * len, 0.0), Vector::new((1.0 - HEEL) * len, 0.0)) } else { (Vector::ZERO, down(len)) };
                Limb {
                    parent: k.checked_sub(1),
                    anchor: anchors[k],
                    capsule: capsule(a, b, RADII[k], len),
                    limits: JOINT_LIMITS[k],
                    damping: DAMPING,
                }
            })
            .collect();
        BodyPlan { torso, limbs, friction: FRICTION, clockwise: true }
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
