//! A planar robot's rapier body: capsule limbs hinged in a tree below a free torso, rebuilt in its
//! own world for every design.
//!
//! A robot describes its body as a [`BodyPlan`]: capsules in the torso's frame, and limbs, each a
//! capsule in its own frame whose origin is the joint to its parent. Every angle, limit and torque
//! the plan takes and [`Body`] returns is in the robot's own convention, MuJoCo's for its model:
//! MuJoCo's planar models live in the x-z plane and turn about `+y` (clockwise seen with x to the
//! right and z up; [`BodyPlan::clockwise`]) or about `-y` (counter-clockwise, rapier's sense). The
//! torso pitch is always MuJoCo's `rooty` (about `+y`): positive is nose-down.

use super::{JointKind, SimConfig};
use rapier2d::prelude::*;

/// A capsule in the frame of the body that carries it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Capsule {
    /// The ends of the capsule's core segment.
    pub a: Vector,
    pub b: Vector,
    pub radius: f32,
    /// Mass in kg (see [`capsule_mass`]).
    pub mass: f32,
}

/// One hinged segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limb {
    /// The limb it hangs from (an index into [`BodyPlan::limbs`], smaller than its own), or `None`
    /// for the torso.
    pub parent: Option<usize>,
    /// Where its joint sits in the parent's frame (for the torso: relative to the torso's origin).
    pub anchor: Vector,
    /// Its capsule, in its own frame: the origin is the joint, and at zero joint angles the frame is
    /// the torso's.
    pub capsule: Capsule,
    /// Joint range `[lo, hi]` in radians, in the robot's sign convention.
    pub limits: [f32; 2],
    /// Joint damping in N m s/rad (multibody joints only, MuJoCo's value for the model).
    pub damping: f32,
}

/// A whole robot: its torso's capsules and its limbs.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyPlan {
    pub torso: Vec<Capsule>,
    /// Limbs in joint order (the order of actions and observed joints); parents come first.
    pub limbs: Vec<Limb>,
    /// Friction of every part and of the floor.
    pub friction: f32,
    /// Joint angles turn about MuJoCo's `+y` (clockwise in the x-z plane); otherwise about `-y`.
    pub clockwise: bool,
}

/// Mass of a capsule with core length `len` as a 3D solid of `density` (kg/m^3), so that masses
/// follow MuJoCo's.
pub fn capsule_mass(density: f32, radius: f32, len: f32) -> f32 {
    use std::f32::consts::PI;
    density * (PI * radius * radius * len + 4.0 / 3.0 * PI * radius.powi(3))
}

fn rotate(v: Vector, angle: f32) -> Vector {
    let (s, c) = angle.sin_cos();
    Vector::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

/// `x` wrapped into `[-pi, pi)`.
pub fn wrap(x: f32) -> f32 {
    use std::f32::consts::PI;
    (x + PI).rem_euclid(2.0 * PI) - PI
}

impl BodyPlan {
    /// +1 if the robot's angles are rapier's (counter-clockwise), -1 if clockwise.
    fn sign(&self) -> f32 {
        if self.clockwise { -1.0 } else { 1.0 }
    }

    /// Joint position and rapier angle of every limb with the torso level at `torso` and the joints
    /// at `angles`.
    fn poses(&self, torso: Vector, angles: &[f32]) -> Vec<(Vector, f32)> {
        let sign = self.sign();
        let mut pose: Vec<(Vector, f32)> = Vec::with_capacity(self.limbs.len());
        for (limb, &q) in self.limbs.iter().zip(angles) {
            let (parent_pos, parent_angle) = limb.parent.map_or((torso, 0.0), |p| pose[p]);
            pose.push((parent_pos + rotate(limb.anchor, parent_angle), parent_angle + sign * q));
        }
        pose
    }

    /// Height of the lowest point of the surface with the torso level at `torso` and the joints at
    /// `angles`: a robot's start height is where this lands just above the ground.
    pub fn lowest_point(&self, torso: Vector, angles: &[f32]) -> f32 {
        let low = |pos: Vector, angle: f32, c: &Capsule| (pos + rotate(c.a, angle)).y.min((pos + rotate(c.b, angle)).y) - c.radius;
        let mut lowest = self.torso.iter().map(|c| low(torso, 0.0, c)).fold(f32::INFINITY, f32::min);
        for (limb, (pos, angle)) in self.limbs.iter().zip(self.poses(torso, angles)) {
            lowest = lowest.min(low(pos, angle, &limb.capsule));
        }
        lowest
    }

    /// The torso height that puts the body, level torso and joints at `angles`, 1 cm above the
    /// ground: a standing robot then lands on whatever reaches lowest.
    pub fn touching_start_height(&self, angles: &[f32]) -> f32 {
        0.01 - self.lowest_point(Vector::ZERO, angles)
    }
}

/// Torso centre (the torso body's origin) `[x, z]`, the velocity of that point `[vx, vz]`, pitch
/// and pitch rate (positive is nose-down).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Torso {
    pub pos: [f32; 2],
    pub vel: [f32; 2],
    pub pitch: f32,
    pub pitch_rate: f32,
}

/// A held joint's spring (N m/rad) and damping (N m s/rad), both integrated implicitly by rapier:
/// a 100 N m load bends it by 0.01 rad, and the damping stops it rocking.
const HOLD_STIFFNESS: f32 = 1.0e4;
const HOLD_DAMPING: f32 = 200.0;

/// Robot parts touch only the ground, as the MuJoCo models' contype/conaffinity set them.
const ROBOT: Group = Group::GROUP_1;
const GROUND: Group = Group::GROUP_2;
/// A revolute joint's coordinate in rapier's spatial layout (after x and y).
const ANGULAR_AXIS: usize = 2;

/// One robot in its own world, with the ground.
pub(crate) struct Body {
    world: PhysicsWorld,
    torso: RigidBodyHandle,
    limbs: Vec<RigidBodyHandle>,
    parents: Vec<RigidBodyHandle>,
    /// +1: the robot's angles are rapier's; -1: clockwise.
    sign: f32,
    /// Every capsule with the body that carries it (for [`Body::lowest_point`]).
    capsules: Vec<(RigidBodyHandle, Capsule)>,
    /// Multibody joints only: each joint's handle, its degree of freedom in the multibody, and its
    /// damping.
    multibody: Vec<Option<MultibodyJointHandle>>,
    dofs: Vec<usize>,
    damping: Vec<f32>,
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Body").field("torso", &self.torso).field("limbs", &self.limbs).finish_non_exhaustive()
    }
}

impl Body {
    /// A fresh world holding the body of `plan` at rest, torso level with its origin at height
    /// `height`, joints at `angles` (the robot's signs, within the limits).
    pub fn build(plan: &BodyPlan, height: f32, angles: &[f32], cfg: &SimConfig) -> Self {
        let n = plan.limbs.len();
        let sign = plan.sign();
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, -super::GRAVITY);
        let p = &mut world.integration_parameters;
        p.dt = super::CONTROL_DT / cfg.substeps as f32;
        p.num_solver_iterations = cfg.solver_iterations;
        p.warmstart_joints = cfg.warmstart_joints;

        // A half-space never runs out however far the robot runs.
        let ground = world.insert_body(RigidBodyBuilder::fixed());
        let floor_groups = InteractionGroups::new(GROUND, ROBOT, InteractionTestMode::And);
        let floor = ColliderBuilder::new(SharedShape::halfspace(Vector::Y)).friction(plan.friction).collision_groups(floor_groups);
        world.insert_collider(floor, Some(ground));

        let groups = InteractionGroups::new(ROBOT, GROUND, InteractionTestMode::And);
        let collider = |c: &Capsule| {
            ColliderBuilder::capsule_from_endpoints(c.a, c.b, c.radius).mass(c.mass).friction(plan.friction).collision_groups(groups)
        };
        let torso_pos = Vector::new(0.0, height);
        let torso = world.insert_body(RigidBodyBuilder::dynamic().translation(torso_pos).can_sleep(false));
        let mut capsules = Vec::with_capacity(plan.torso.len() + n);
        for c in &plan.torso {
            world.insert_collider(collider(c), Some(torso));
            capsules.push((torso, *c));
        }

        // Place every limb where the joint angles put it, so impulse joints start satisfied.
        let mut limbs = Vec::with_capacity(n);
        for (limb, (pos, angle)) in plan.limbs.iter().zip(plan.poses(torso_pos, angles)) {
            let h = world.insert_body(RigidBodyBuilder::dynamic().translation(pos).rotation(angle).can_sleep(false));
            world.insert_collider(collider(&limb.capsule), Some(h));
            capsules.push((h, limb.capsule));
            limbs.push(h);
        }

        let parents: Vec<_> = plan.limbs.iter().map(|l| l.parent.map_or(torso, |p| limbs[p])).collect();
        let mut multibody = vec![None; n];
        for (i, limb) in plan.limbs.iter().enumerate() {
            let [lo, hi] = limb.limits;
            let limits = if plan.clockwise { [-hi, -lo] } else { [lo, hi] };
            let joint = RevoluteJointBuilder::new().local_anchor1(limb.anchor).local_anchor2(Vector::ZERO).limits(limits);
            match cfg.joints {
                JointKind::Impulse => {
                    world.insert_impulse_joint(parents[i], limbs[i], joint);
                }
                JointKind::Multibody => multibody[i] = world.insert_multibody_joint(parents[i], limbs[i], joint),
            }
        }
        let mut body = Self { world, torso, limbs, parents, sign, capsules, multibody, dofs: vec![0; n], damping: vec![0.0; n] };
        if cfg.joints == JointKind::Multibody {
            body.set_multibody_coordinates(plan, angles, cfg);
        }
        body
    }

    /// Multibody joints start at zero coordinates whatever the bodies' poses: set them to `angles`
    /// (rapier's coordinate is the child's counter-clockwise turn) and move the bodies to match;
    /// give the joints their armature and damping.
    fn set_multibody_coordinates(&mut self, plan: &BodyPlan, angles: &[f32], cfg: &SimConfig) {
        let Some(Some(first)) = self.multibody.first() else { return };
        let Some((mb, _)) = self.world.multibody_joints.get_mut(*first) else { return };
        mb.forward_kinematics(&self.world.bodies, true);
        // The free root's rotation gets rapier's default damping of 0.1: the torso flies freely.
        for d in mb.damping_mut().iter_mut().take(3) {
            *d = 0.0;
        }
        let mut disp = vec![0.0; mb.ndofs()];
        let dofs = &mut self.dofs;
        for link in mb.links() {
            if let Some(i) = self.limbs.iter().position(|&h| h == link.rigid_body_handle()) {
                dofs[i] = link.assembly_id();
                disp[dofs[i]] = self.sign * angles[i];
            }
        }
        for (i, limb) in plan.limbs.iter().enumerate() {
            self.damping[i] = if cfg.joint_damping { limb.damping } else { 0.0 };
            mb.armature_mut()[dofs[i]] = cfg.armature;
            mb.damping_mut()[dofs[i]] = self.damping[i];
        }
        mb.apply_displacements(&disp);
        mb.forward_kinematics(&self.world.bodies, true);
        mb.update_rigid_bodies(&mut self.world.bodies, true);
    }

    /// Multibody joints only: `true` holds every joint at its current angle with a stiff, heavily
    /// damped spring, `false` frees them again with their own damping. (rapier's kinematic joints
    /// would hold exactly, but their limit constraints fail.)
    pub fn hold_joints(&mut self, hold: bool) {
        for (i, h) in self.multibody.iter().enumerate() {
            let Some((mb, link)) = h.and_then(|h| self.world.multibody_joints.get_mut(h)) else { continue };
            mb.damping_mut()[self.dofs[i]] = if hold { HOLD_DAMPING } else { self.damping[i] };
            if let Some(link) = mb.link_mut(link) {
                let rest = link.joint.coords()[ANGULAR_AXIS];
                link.joint.set_spring(ANGULAR_AXIS, if hold { HOLD_STIFFNESS } else { 0.0 }, rest);
            }
        }
    }

    /// Sets gravity to `g` m/s^2, downwards.
    pub fn set_gravity(&mut self, g: f32) {
        self.world.gravity = Vector::new(0.0, -g);
    }

    /// Advances the world by one physics step.
    pub fn step(&mut self) {
        self.world.step();
    }

    /// Sets the joint torques (the robot's signs) that act until the next call: rapier keeps user
    /// torques across steps, so the old ones are cleared first.
    pub fn set_torques(&mut self, torques: &[f32]) {
        for body in std::iter::once(&self.torso).chain(&self.limbs) {
            if let Some(rb) = self.world.bodies.get_mut(*body) {
                rb.reset_torques(true);
            }
        }
        for (i, &t) in torques.iter().enumerate() {
            // The torque turns the child against its parent.
            if let Some(rb) = self.world.bodies.get_mut(self.limbs[i]) {
                rb.add_torque(self.sign * t, true);
            }
            if let Some(rb) = self.world.bodies.get_mut(self.parents[i]) {
                rb.add_torque(-self.sign * t, true);
            }
        }
    }

    fn angle_and_rate(&self, h: RigidBodyHandle) -> (f32, f32) {
        self.world.bodies.get(h).map_or((f32::NAN, f32::NAN), |rb| (rb.rotation().angle(), rb.angvel()))
    }

    /// Angle and angular velocity of joint `i` (the robot's signs).
    pub fn joint(&self, i: usize) -> (f32, f32) {
        let (a_p, w_p) = self.angle_and_rate(self.parents[i]);
        let (a_c, w_c) = self.angle_and_rate(self.limbs[i]);
        (self.sign * wrap(a_c - a_p), self.sign * (w_c - w_p))
    }

    /// The body's capsules, for pictures.
    pub fn draw(&self, out: &mut Vec<coadapt_core::Shape>) {
        crate::draw::planar(&self.world.colliders, out)
    }

    /// Height of the lowest point of any capsule surface: below zero, that part is in the ground.
    pub fn lowest_point(&self) -> f32 {
        self.capsules.iter().map(|(h, c)| self.surface_low(*h, c)).fold(f32::INFINITY, f32::min)
    }

    fn surface_low(&self, h: RigidBodyHandle, c: &Capsule) -> f32 {
        self.world.bodies.get(h).map_or(f32::NAN, |rb| {
            let p = rb.position();
            (*p * c.a).y.min((*p * c.b).y) - c.radius
        })
    }

    /// For each capsule (the torso's first, then one per limb in joint order), the height of its
    /// lowest surface point: at or below about 0 it touches the ground (contacts are found at
    /// rapier's prediction distance, a few millimetres).
    pub fn part_heights(&self, out: &mut Vec<f32>) {
        out.clear();
        out.extend(self.capsules.iter().map(|(h, c)| self.surface_low(*h, c)));
    }

    pub fn torso(&self) -> Torso {
        match self.world.bodies.get(self.torso) {
            Some(rb) => {
                let p = rb.translation();
                let v = rb.velocity_at_point(p);
                Torso { pos: [p.x, p.y], vel: [v.x, v.y], pitch: -wrap(rb.rotation().angle()), pitch_rate: -rb.angvel() }
            }
            None => Torso { pos: [f32::NAN; 2], vel: [f32::NAN; 2], pitch: f32::NAN, pitch_rate: f32::NAN },
        }
    }
}
