//! The cheetah's body plan: geometry from MuJoCo's `half_cheetah.xml`, rebuilt for every design.
//!
//! MuJoCo's model lives in the x-z plane and turns about +y, which is clockwise seen with x to the
//! right and z up ([`BodyPlan::clockwise`]); every angle, limit and torque uses MuJoCo's signs: a
//! positive thigh angle swings the leg backwards, a positive pitch is nose-down.

use crate::planar::{BodyPlan, Capsule, Limb, capsule_mass};
use rapier2d::prelude::Vector;

/// Capsule radius of every limb and of the torso.
pub const RADIUS: f32 = 0.046;
/// Capsule lengths (end to end of the segment) at design 1: back thigh, shin, foot; front thigh,
/// shin, foot. The product brief gives both legs the back leg's MuJoCo lengths.
pub const BASE_LENGTHS: [f32; 6] = [0.29, 0.3, 0.188, 0.29, 0.3, 0.188];
/// Joint ranges `[lo, hi]` in radians, MuJoCo's `half_cheetah.xml`.
pub const JOINT_LIMITS: [[f32; 2]; 6] = [[-0.52, 1.05], [-0.785, 0.785], [-0.4, 0.785], [-1.0, 0.7], [-1.2, 0.87], [-0.5, 0.5]];
/// Joint torque at full action (before the reference's 0.9 power factor), in N m.
pub const POWERS: [f32; 6] = [120.0, 90.0, 60.0, 90.0, 60.0, 30.0];

/// Unit direction of each limb from its joint at zero joint angles, in the torso frame: MuJoCo's
/// geom axes (`axisangle` about y) turned to point away from the joint, towards the child body.
const DIRECTIONS: [[f32; 2]; 6] = [
    [0.6119, -0.7910],  // bthigh, axisangle -3.8: down and forwards
    [-0.8962, -0.4436], // bshin, -2.03: down and backwards
    [0.2667, -0.9638],  // bfoot, -0.27
    [-0.4969, -0.8678], // fthigh, 0.52
    [0.5646, -0.8253],  // fshin, -0.6
    [0.5646, -0.8253],  // ffoot, -0.6
];
/// MuJoCo's joint damping in N m s/rad (multibody joints only).
const DAMPING: [f32; 6] = [6.0, 4.5, 3.0, 4.5, 3.0, 1.5];
/// Parent of each limb: `None` is the torso.
const PARENT: [Option<usize>; 6] = [None, Some(0), Some(1), None, Some(3), Some(4)];
/// Hip positions on the torso (its capsule runs from x = -0.5 to 0.5).
const HIPS: [[f32; 2]; 2] = [[-0.5, 0.0], [0.5, 0.0]];
const TORSO_HALF_LENGTH: f32 = 0.5;
/// MuJoCo's head: a capsule of half-length 0.15 centred at (0.6, 0.1), tilted 0.87 rad up.
const HEAD_CENTRE: [f32; 2] = [0.6, 0.1];
const HEAD_HALF_LENGTH: f32 = 0.15;
const HEAD_TILT: f32 = 0.87;
/// MuJoCo sets the total mass to 14 kg over its original geoms (volume 0.02098 m^3 as 3D
/// capsules); the same density for every design makes longer legs heavier, as in PyBullet.
const DENSITY: f32 = 667.2;
/// MuJoCo's friction for every geom (the floor included).
const FRICTION: f32 = 0.4;

/// Where the torso's hips sit so that no leg reaches the ground whatever its joint angles: each
/// segment reaches at most its length from its joint.
pub fn start_height(lengths: &[f32; 6]) -> f32 {
    let back: f32 = lengths[..3].iter().sum();
    let front: f32 = lengths[3..].iter().sum();
    back.max(front) + RADIUS + 0.01
}

/// The cheetah with segment `lengths`: a level torso capsule with the head, and two legs hinged
/// at its ends, each segment a capsule from its joint along MuJoCo's geom axis.
pub fn plan(lengths: &[f32; 6]) -> BodyPlan {
    let capsule = |a: Vector, b: Vector, len: f32| Capsule { a, b, radius: RADIUS, mass: capsule_mass(DENSITY, RADIUS, len) };
    let torso_end = Vector::X * TORSO_HALF_LENGTH;
    let head_dir = Vector::new(HEAD_TILT.sin(), HEAD_TILT.cos()) * HEAD_HALF_LENGTH;
    let head_c = Vector::from(HEAD_CENTRE);
    let torso = vec![
        capsule(-torso_end, torso_end, 2.0 * TORSO_HALF_LENGTH),
        capsule(head_c - head_dir, head_c + head_dir, 2.0 * HEAD_HALF_LENGTH),
    ];
    let limbs = (0..6)
        .map(|i| Limb {
            parent: PARENT[i],
            anchor: match PARENT[i] {
                None => Vector::from(HIPS[i / 3]),
                Some(p) => Vector::from(DIRECTIONS[p]) * lengths[p],
            },
            capsule: capsule(Vector::ZERO, Vector::from(DIRECTIONS[i]) * lengths[i], lengths[i]),
            limits: JOINT_LIMITS[i],
            damping: DAMPING[i],
        })
        .collect();
    BodyPlan { torso, limbs, friction: FRICTION, clockwise: true }
}
