//! Daisy's rapier3d body: a box torso and six three-motor legs, one multibody, rebuilt for every
//! design.
//!
//! The world is z-up with the robot facing +y: the torso frame has x to the robot's right, y
//! forward, z up. Legs are numbered pair by pair, right then left: front right, front left,
//! middle right, middle left, back right, back left; joints leg by leg: base (yaw), shoulder
//! (pitch), knee (pitch), so joint `3 * leg + k`.
//!
//! Every body's frame has its origin at the joint that carries it and, at zero joint angles, the
//! torso's orientation. At zero angles a leg stands: the coxa (base-to-shoulder link) and the
//! femur point outwards level, along the leg's mounting direction, and the tibia hangs straight
//! down. Signs are the same on both sides: a positive base angle swings the leg forwards (towards
//! +y), a positive shoulder angle lifts the femur, a positive knee angle swings the tibia outwards
//! and up (extending the leg).

use super::SimConfig;
use rapier3d::prelude::*;

/// Number of legs, and of joints.
pub const LEGS: usize = 6;
pub const JOINTS: usize = 18;
/// Torso box half-extents (x: width, y: length, z: height), metres.
pub const TORSO_HALF_EXTENTS: [f32; 3] = [0.15, 0.25, 0.05];
/// Torso mass with the six base motors it carries, kg.
pub const TORSO_MASS: f32 = 5.0;
/// Length of the coxa, the fixed link from a base motor to its shoulder motor, metres.
pub const COXA_LENGTH: f32 = 0.1;
/// Capsule radii: coxa, femur, tibia (the tibia's rounded end is the foot).
pub const RADII: [f32; 3] = [0.04, 0.035, 0.025];
/// Joint torque at full action (before the 0.9 power factor), N m: a HEBI X8-9's peak torque
/// for every motor.
pub const POWERS: [f32; 3] = [20.0, 20.0, 20.0];
/// Half-width of the base (yaw) motor's range around the design's offset, radians.
pub const BASE_HALF_RANGE: f32 = 0.6;
/// Shoulder and knee ranges `[lo, hi]`, radians.
pub const SHOULDER_LIMITS: [f32; 2] = [-1.0, 1.0];
pub const KNEE_LIMITS: [f32; 2] = [-1.0, 1.5];
/// Friction of every part and of the floor.
pub const FRICTION: f32 = 0.8;
/// Hip (base motor axis) positions along the torso, per pair (front, middle, back), metres; the
/// hips sit on the torso's sides at `x = +-TORSO_HALF_EXTENTS[0]`.
const HIP_Y: [f32; 3] = [0.2, 0.0, -0.2];
/// Mounting direction of each pair's legs at zero base angle, turned forwards from sideways:
/// the corner legs splay 30 degrees forwards and backwards, the middle legs point straight out.
const MOUNT_ANGLE: [f32; 3] = [std::f32::consts::FRAC_PI_6, 0.0, -std::f32::consts::FRAC_PI_6];
/// The coxa carries the shoulder motor.
const COXA_MASS: f32 = 0.5;
/// Parts touch only the ground, not each other.
const ROBOT: Group = Group::GROUP_1;
const GROUND: Group = Group::GROUP_2;

/// Femur mass: the knee motor (0.5 kg) and a tube of 0.5 kg/m.
fn femur_mass(len: f32) -> f32 {
    0.5 + 0.5 * len
}

/// Tibia mass: a foot (0.1 kg) and a tube of 0.5 kg/m.
fn tibia_mass(len: f32) -> f32 {
    0.1 + 0.5 * len
}

/// `+1` for a right leg (even index), `-1` for a left one.
fn side(leg: usize) -> f32 {
    if leg.is_multiple_of(2) { 1.0 } else { -1.0 }
}

/// Unit direction of a leg at zero base angle, in the torso frame.
fn mount_direction(leg: usize) -> Vector {
    let (s, c) = MOUNT_ANGLE[leg / 2].sin_cos();
    Vector::new(side(leg) * c, s, 0.0)
}

/// Where the base motor's axis meets the torso's side, in the torso frame.
fn hip(leg: usize) -> Vector {
    Vector::new(side(leg) * TORSO_HALF_EXTENTS[0], HIP_Y[leg / 2], 0.0)
}

/// Joint limits `[lo, hi]` of the 18 joints for base-range offsets `offsets` (per pair).
pub fn joint_limits(offsets: &[f32; 3]) -> [[f32; 2]; JOINTS] {
    std::array::from_fn(|j| match j % 3 {
        0 => {
            let o = offsets[j / 6];
            [o - BASE_HALF_RANGE, o + BASE_HALF_RANGE]
        }
        1 => SHOULDER_LIMITS,
        _ => KNEE_LIMITS,
    })
}

/// Torso height at which no leg reaches the ground when every shoulder and knee is within
/// `noise` of zero: a foot is at most `femur sin(noise) + tibia` below its hip (hips sit at the
/// torso's mid-height), plus the foot's radius and 5 mm.
pub fn start_height(lengths: &[[f32; 2]; 3], noise: f32) -> f32 {
    let reach = lengths.iter().map(|[femur, tibia]| femur * noise.sin() + tibia).fold(0.0, f32::max);
    reach.max(TORSO_HALF_EXTENTS[2]) + RADII[2] + 0.005
}

/// One Daisy in its own world, with the ground: the torso and the 18 leg segments are one
/// multibody, the torso its free root.
pub struct Body {
    world: PhysicsWorld,
    torso: RigidBodyHandle,
    /// The body each joint moves, and the body it is mounted on.
    children: [RigidBodyHandle; JOINTS],
    parents: [RigidBodyHandle; JOINTS],
    /// Each joint's axis in its parent's frame (and in its child's: the frames agree at zero).
    axes: [Vector; JOINTS],
    /// The multibody, and each joint's link id and degree of freedom in it.
    multibody: Option<MultibodyIndex>,
    links: [usize; JOINTS],
    dofs: [usize; JOINTS],
    lengths: [[f32; 2]; 3],
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Body").field("torso", &self.torso).field("lengths", &self.lengths).finish_non_exhaustive()
    }
}

/// What [`crate::World`] changes in Daisy's body: the friction of the floor and every part, and
/// the torso's mass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ground {
    pub friction: f32,
    pub torso_mass: f32,
}

impl Body {
    /// A fresh world with the body of femur and tibia `lengths` per pair and base-range
    /// `offsets` per pair, at rest, torso level with its centre at `height` above the ground,
    /// joints at `angles` (within the limits).
    pub fn build(
        lengths: &[[f32; 2]; 3],
        offsets: &[f32; 3],
        angles: &[f32; JOINTS],
        height: f32,
        values: Ground,
        cfg: &SimConfig,
    ) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -9.81);
        let p = &mut world.integration_parameters;
        p.dt = cfg.control_dt / cfg.substeps as f32;
        p.num_solver_iterations = cfg.solver_iterations;
        p.normalized_prediction_distance = cfg.prediction_distance;
        p.num_internal_pgs_iterations = cfg.pgs_iterations;

        let ground = world.insert_body(RigidBodyBuilder::fixed());
        let floor_groups = InteractionGroups::new(GROUND, ROBOT, InteractionTestMode::And);
        let floor = ColliderBuilder::new(SharedShape::halfspace(Vector::Z)).friction(values.friction).collision_groups(floor_groups);
        world.insert_collider(floor, Some(ground));

        let groups = InteractionGroups::new(ROBOT, GROUND, InteractionTestMode::And);
        let origin = Vector::new(0.0, 0.0, height);
        let torso = world.insert_body(RigidBodyBuilder::dynamic().translation(origin).can_sleep(false));
        let [hx, hy, hz] = TORSO_HALF_EXTENTS;
        let torso_col = ColliderBuilder::cuboid(hx, hy, hz).mass(values.torso_mass).friction(values.friction).collision_groups(groups);
        world.insert_collider(torso_col, Some(torso));

        let limits = joint_limits(offsets);
        let mut children = [torso; JOINTS];
        let mut parents = [torso; JOINTS];
        let mut axes = [Vector::ZERO; JOINTS];
        let mut handles = [None; JOINTS];
        for leg in 0..LEGS {
            let [femur, tibia] = lengths[leg / 2];
            let d = mount_direction(leg);
            let pitch_axis = d.cross(Vector::Z);
            let yaw_axis = Vector::Z * side(leg);
            // (axis, anchor in the parent, segment from the joint, radius, mass)
            let parts = [
                (yaw_axis, hip(leg), d * COXA_LENGTH, RADII[0], COXA_MASS),
                (pitch_axis, d * COXA_LENGTH, d * femur, RADII[1], femur_mass(femur)),
                (pitch_axis, d * femur, Vector::new(0.0, 0.0, -tibia), RADII[2], tibia_mass(tibia)),
            ];
            // Bodies are placed at zero joint angles; the start angles are set below.
            let mut parent = torso;
            let mut joint_pos = origin;
            for (k, (axis, anchor, segment, radius, mass)) in parts.into_iter().enumerate() {
                let j = 3 * leg + k;
                joint_pos += anchor;
                let child = world.insert_body(RigidBodyBuilder::dynamic().translation(joint_pos).can_sleep(false));
                let col = ColliderBuilder::capsule_from_endpoints(Vector::ZERO, segment, radius).mass(mass);
                world.insert_collider(col.friction(values.friction).collision_groups(groups), Some(child));
                let joint = RevoluteJointBuilder::new(axis).local_anchor1(anchor).local_anchor2(Vector::ZERO).limits(limits[j]);
                handles[j] = world.insert_multibody_joint(parent, child, joint);
                (children[j], parents[j], axes[j]) = (child, parent, axis);
                parent = child;
            }
        }

        let mut body =
            Self { world, torso, children, parents, axes, multibody: None, links: [0; JOINTS], dofs: [0; JOINTS], lengths: *lengths };
        if let Some(Some(first)) = handles.first() {
            body.set_coordinates(*first, angles, cfg);
        }
        body
    }

    /// Finds every joint's link and degree of freedom, sets the joint damping and armature, and
    /// moves the joints (at zero when built) to `angles`.
    fn set_coordinates(&mut self, handle: MultibodyJointHandle, angles: &[f32; JOINTS], cfg: &SimConfig) {
        let world = &mut self.world;
        let Some((mb, _)) = world.multibody_joints.get_mut(handle) else { return };
        mb.forward_kinematics(&world.bodies, true);
        // The free root, the torso, gets rapier's default angular damping: it must fly freely.
        for d in mb.damping_mut().iter_mut().take(6) {
            *d = 0.0;
        }
        let mut disp = vec![0.0; mb.ndofs()];
        for j in 0..JOINTS {
            let Some(link) = mb.links().find(|l| l.rigid_body_handle() == self.children[j]) else { continue };
            (self.links[j], self.dofs[j]) = (link.link_id(), link.assembly_id());
            disp[self.dofs[j]] = angles[j];
            mb.armature_mut()[self.dofs[j]] = cfg.armature;
            mb.damping_mut()[self.dofs[j]] = cfg.joint_damping;
        }
        mb.apply_displacements(&disp);
        mb.forward_kinematics(&world.bodies, true);
        mb.update_rigid_bodies(&mut world.bodies, true);
        self.multibody = world.multibody_joints.rigid_body_link(self.torso).map(|l| l.multibody);
    }

    /// Advances the world by one physics step with joint `torques`, each turning its child
    /// about the joint axis and its parent the other way (rapier keeps user torques across
    /// steps, so the old ones are cleared first).
    pub fn step(&mut self, torques: &[f32; JOINTS]) {
        for h in std::iter::once(&self.torso).chain(&self.children) {
            if let Some(rb) = self.world.bodies.get_mut(*h) {
                rb.reset_torques(false);
            }
        }
        for j in 0..JOINTS {
            let Some(parent) = self.world.bodies.get(self.parents[j]) else { continue };
            let t = *parent.rotation() * self.axes[j] * torques[j];
            if let Some(rb) = self.world.bodies.get_mut(self.children[j]) {
                rb.add_torque(t, false);
            }
            if let Some(rb) = self.world.bodies.get_mut(self.parents[j]) {
                rb.add_torque(-t, false);
            }
        }
        self.world.step();
    }

    /// Joint angles and velocities (rad, rad/s), the multibody's coordinates.
    pub fn joints(&self) -> ([f32; JOINTS], [f32; JOINTS]) {
        let mut q = [f32::NAN; JOINTS];
        let mut qd = [f32::NAN; JOINTS];
        if let Some(mb) = self.multibody.and_then(|m| self.world.multibody_joints.get_multibody(m)) {
            let v = mb.generalized_velocity();
            for j in 0..JOINTS {
                // A revolute joint's one free coordinate is its rotation about the axis.
                q[j] = mb.link(self.links[j]).map_or(f32::NAN, |l| l.joint().coords()[3]);
                qd[j] = v[self.dofs[j]];
            }
        }
        (q, qd)
    }

    /// Torso centre, orientation and linear velocity (world frame).
    pub fn torso(&self) -> (Vector, Rotation, Vector) {
        match self.world.bodies.get(self.torso) {
            Some(rb) => (rb.translation(), *rb.rotation(), rb.linvel()),
            None => (Vector::NAN, Rotation::NAN, Vector::NAN),
        }
    }

    /// Appends the body's capsules (and the torso box's top edges) to `out`, turned so that the
    /// robot's forward (+y here) is the picture's x.
    pub fn draw(&self, out: &mut Vec<coadapt_core::Shape>) {
        use coadapt_core::Shape;
        let start = out.len();
        crate::draw::spatial(&self.world.colliders, out);
        let turn = |p: [f32; 3]| [p[1], -p[0], p[2]];
        for shape in &mut out[start..] {
            match shape {
                Shape::Capsule { a, b, .. } => (*a, *b) = (turn(*a), turn(*b)),
                Shape::Sphere { centre, .. } => *centre = turn(*centre),
            }
        }
    }

    /// Height of the lowest point of any part's surface (negative: a part is in the ground).
    pub fn lowest_point(&self) -> f32 {
        let Some(rb) = self.world.bodies.get(self.torso) else { return f32::NAN };
        let [hx, hy, hz] = TORSO_HALF_EXTENTS;
        let mut low = f32::INFINITY;
        for c in 0..8 {
            let corner =
                Vector::new(if c & 1 == 0 { -hx } else { hx }, if c & 2 == 0 { -hy } else { hy }, if c & 4 == 0 { -hz } else { hz });
            low = low.min(rb.position().transform_point(corner).z);
        }
        for leg in 0..LEGS {
            let [femur, tibia] = self.lengths[leg / 2];
            let d = mount_direction(leg);
            let segments = [d * COXA_LENGTH, d * femur, Vector::new(0.0, 0.0, -tibia)];
            for (k, segment) in segments.into_iter().enumerate() {
                let Some(rb) = self.world.bodies.get(self.children[3 * leg + k]) else { return f32::NAN };
                let p = rb.position();
                low = low.min(p.translation.z.min(p.transform_point(segment).z) - RADII[k]);
            }
        }
        low
    }
}
