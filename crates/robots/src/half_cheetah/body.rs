//! The cheetah's rapier body: geometry from MuJoCo's `half_cheetah.xml`, rebuilt for every design.
//!
//! MuJoCo's model lives in the x-z plane and turns about +y, which is clockwise seen with x to the
//! right and z up; rapier's 2D angles are counter-clockwise. The accessors here convert, so every
//! angle, limit and torque they take or return uses MuJoCo's signs: a positive thigh angle swings
//! the leg backwards, a positive pitch is nose-down.

use super::{JointKind, SimConfig};
use rapier2d::prelude::*;

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
/// Robot parts touch only the ground, as MuJoCo's contype/conaffinity set them.
const ROBOT: Group = Group::GROUP_1;
const GROUND: Group = Group::GROUP_2;

/// Mass of a capsule of segment length `len` as a 3D solid, so masses follow MuJoCo's.
fn capsule_mass(len: f32) -> f32 {
    use std::f32::consts::PI;
    DENSITY * (PI * RADIUS * RADIUS * len + 4.0 / 3.0 * PI * RADIUS.powi(3))
}

fn rotate(v: Vector, angle: f32) -> Vector {
    let (s, c) = angle.sin_cos();
    Vector::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

fn wrap(x: f32) -> f32 {
    use std::f32::consts::PI;
    (x + PI).rem_euclid(2.0 * PI) - PI
}

/// One cheetah in its own world, with the ground.
pub struct Body {
    world: PhysicsWorld,
    torso: RigidBodyHandle,
    limbs: [RigidBodyHandle; 6],
    lengths: [f32; 6],
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Body").field("torso", &self.torso).field("limbs", &self.limbs).finish_non_exhaustive()
    }
}

/// Where the torso's hips sit so that no leg reaches the ground whatever its joint angles: each
/// segment reaches at most its length from its joint.
pub fn start_height(lengths: &[f32; 6]) -> f32 {
    let back: f32 = lengths[..3].iter().sum();
    let front: f32 = lengths[3..].iter().sum();
    back.max(front) + RADIUS + 0.01
}

impl Body {
    /// A fresh world holding the body with segment `lengths`, at rest, torso level at
    /// [`start_height`], joints at `angles` (MuJoCo signs, within the limits).
    pub fn build(lengths: &[f32; 6], angles: &[f32; 6], cfg: &SimConfig) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, -9.81);
        let p = &mut world.integration_parameters;
        p.dt = super::CONTROL_DT / cfg.substeps as f32;
        p.num_solver_iterations = cfg.solver_iterations;
        p.warmstart_joints = cfg.warmstart_joints;

        // A half-space never runs out however far the cheetah runs.
        let ground = world.insert_body(RigidBodyBuilder::fixed());
        let floor_groups = InteractionGroups::new(GROUND, ROBOT, InteractionTestMode::And);
        let floor = ColliderBuilder::new(SharedShape::halfspace(Vector::Y)).friction(FRICTION).collision_groups(floor_groups);
        world.insert_collider(floor, Some(ground));

        let groups = InteractionGroups::new(ROBOT, GROUND, InteractionTestMode::And);
        let h = start_height(lengths);
        let torso = world.insert_body(RigidBodyBuilder::dynamic().translation(Vector::new(0.0, h)).can_sleep(false));
        let torso_len = 2.0 * TORSO_HALF_LENGTH;
        let torso_col = ColliderBuilder::capsule_x(TORSO_HALF_LENGTH, RADIUS).mass(capsule_mass(torso_len));
        world.insert_collider(torso_col.friction(FRICTION).collision_groups(groups), Some(torso));
        let head_dir = Vector::new(HEAD_TILT.sin(), HEAD_TILT.cos()) * HEAD_HALF_LENGTH;
        let head_c = Vector::from(HEAD_CENTRE);
        let head = ColliderBuilder::capsule_from_endpoints(head_c - head_dir, head_c + head_dir, RADIUS)
            .mass(capsule_mass(2.0 * HEAD_HALF_LENGTH))
            .friction(FRICTION)
            .collision_groups(groups);
        world.insert_collider(head, Some(torso));

        // Place every limb where the joint angles put it, so impulse joints start satisfied.
        let mut limbs = [torso; 6];
        let mut pose = [(Vector::ZERO, 0.0f32); 6];
        let mut anchors = [Vector::ZERO; 6];
        for i in 0..6 {
            let (parent_pos, parent_angle, anchor) = match PARENT[i] {
                None => (Vector::new(0.0, h), 0.0, Vector::from(HIPS[i / 3])),
                Some(p) => (pose[p].0, pose[p].1, Vector::from(DIRECTIONS[p]) * lengths[p]),
            };
            // rapier turns counter-clockwise: a positive MuJoCo angle is a negative rapier one.
            let angle = parent_angle - angles[i];
            let pos = parent_pos + rotate(anchor, parent_angle);
            pose[i] = (pos, angle);
            anchors[i] = anchor;
            limbs[i] = world.insert_body(RigidBodyBuilder::dynamic().translation(pos).rotation(angle).can_sleep(false));
            let end = Vector::from(DIRECTIONS[i]) * lengths[i];
            let col = ColliderBuilder::capsule_from_endpoints(Vector::ZERO, end, RADIUS).mass(capsule_mass(lengths[i]));
            world.insert_collider(col.friction(FRICTION).collision_groups(groups), Some(limbs[i]));
        }

        let mut handles = [None; 6];
        for i in 0..6 {
            let parent = PARENT[i].map_or(torso, |p| limbs[p]);
            let [lo, hi] = JOINT_LIMITS[i];
            let joint = RevoluteJointBuilder::new().local_anchor1(anchors[i]).local_anchor2(Vector::ZERO).limits([-hi, -lo]);
            match cfg.joints {
                JointKind::Impulse => {
                    world.insert_impulse_joint(parent, limbs[i], joint);
                }
                JointKind::Multibody => handles[i] = world.insert_multibody_joint(parent, limbs[i], joint),
            }
        }
        if cfg.joints == JointKind::Multibody {
            set_multibody_coordinates(&mut world, &handles, limbs, angles, cfg);
        }
        Self { world, torso, limbs, lengths: *lengths }
    }

    /// Advances the world by one physics step.
    pub fn step(&mut self) {
        self.world.step();
    }

    /// Sets the joint torques (MuJoCo signs) that act until the next call: rapier keeps user
    /// torques across steps, so the old ones are cleared first.
    pub fn set_torques(&mut self, torques: &[f32; 6]) {
        for body in [self.torso].iter().chain(&self.limbs) {
            if let Some(rb) = self.world.bodies.get_mut(*body) {
                rb.reset_torques(true);
            }
        }
        for i in 0..6 {
            let parent = PARENT[i].map_or(self.torso, |p| self.limbs[p]);
            // A positive MuJoCo torque turns the child clockwise against its parent.
            if let Some(rb) = self.world.bodies.get_mut(self.limbs[i]) {
                rb.add_torque(-torques[i], true);
            }
            if let Some(rb) = self.world.bodies.get_mut(parent) {
                rb.add_torque(torques[i], true);
            }
        }
    }

    fn angle_and_rate(&self, h: RigidBodyHandle) -> (f32, f32) {
        self.world.bodies.get(h).map_or((f32::NAN, f32::NAN), |rb| (rb.rotation().angle(), rb.angvel()))
    }

    /// Joint angles and velocities, MuJoCo signs.
    pub fn joints(&self) -> ([f32; 6], [f32; 6]) {
        let mut q = [0.0; 6];
        let mut qd = [0.0; 6];
        for i in 0..6 {
            let parent = PARENT[i].map_or(self.torso, |p| self.limbs[p]);
            let (a_p, w_p) = self.angle_and_rate(parent);
            let (a_c, w_c) = self.angle_and_rate(self.limbs[i]);
            q[i] = -wrap(a_c - a_p);
            qd[i] = -(w_c - w_p);
        }
        (q, qd)
    }

    /// The body's capsules, for pictures.
    pub fn draw(&self, out: &mut Vec<coadapt_core::Shape>) {
        crate::draw::planar(&self.world.colliders, out)
    }

    /// Height of the lowest point of any capsule surface: below zero, that part is in the ground.
    pub fn lowest_point(&self) -> f32 {
        let lowest = |h: RigidBodyHandle, a: Vector, b: Vector| {
            self.world.bodies.get(h).map_or(f32::NAN, |rb| {
                let p = rb.position();
                (*p * a).y.min((*p * b).y) - RADIUS
            })
        };
        let head_dir = Vector::new(HEAD_TILT.sin(), HEAD_TILT.cos()) * HEAD_HALF_LENGTH;
        let head_c = Vector::from(HEAD_CENTRE);
        let mut low = lowest(self.torso, Vector::new(-TORSO_HALF_LENGTH, 0.0), Vector::new(TORSO_HALF_LENGTH, 0.0)).min(lowest(
            self.torso,
            head_c - head_dir,
            head_c + head_dir,
        ));
        for i in 0..6 {
            low = low.min(lowest(self.limbs[i], Vector::ZERO, Vector::from(DIRECTIONS[i]) * self.lengths[i]));
        }
        low
    }

    /// Torso centre `[x, z]`, the velocity of that point `[vx, vz]`, pitch and pitch rate
    /// (MuJoCo signs: positive is nose-down).
    pub fn torso(&self) -> ([f32; 2], [f32; 2], f32, f32) {
        match self.world.bodies.get(self.torso) {
            Some(rb) => {
                let p = rb.translation();
                let v = rb.velocity_at_point(p);
                ([p.x, p.y], [v.x, v.y], -wrap(rb.rotation().angle()), -rb.angvel())
            }
            None => ([f32::NAN; 2], [f32::NAN; 2], f32::NAN, f32::NAN),
        }
    }
}

/// Multibody joints start at zero coordinates whatever the bodies' poses: set them to `angles`
/// (rapier's coordinate is the child's counter-clockwise turn, minus the MuJoCo angle) and move the
/// bodies to match.
fn set_multibody_coordinates(
    world: &mut PhysicsWorld,
    handles: &[Option<MultibodyJointHandle>; 6],
    limbs: [RigidBodyHandle; 6],
    angles: &[f32; 6],
    cfg: &SimConfig,
) {
    let Some(Some(first)) = handles.first() else { return };
    let Some((mb, _)) = world.multibody_joints.get_mut(*first) else { return };
    mb.forward_kinematics(&world.bodies, true);
    // The free root's rotation gets rapier's default damping of 0.1: the torso flies freely.
    for d in mb.damping_mut().iter_mut().take(3) {
        *d = 0.0;
    }
    let mut disp = vec![0.0; mb.ndofs()];
    let mut dofs = [0; 6];
    for link in mb.links() {
        if let Some(i) = limbs.iter().position(|&h| h == link.rigid_body_handle()) {
            dofs[i] = link.assembly_id();
            disp[dofs[i]] = -angles[i];
        }
    }
    for i in 0..6 {
        mb.armature_mut()[dofs[i]] = cfg.armature;
        mb.damping_mut()[dofs[i]] = if cfg.joint_damping { DAMPING[i] } else { 0.0 };
    }
    mb.apply_displacements(&disp);
    mb.forward_kinematics(&world.bodies, true);
    mb.update_rigid_bodies(&mut world.bodies, true);
}
