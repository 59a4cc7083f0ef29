//! The robots whose bodies coadapt optimises, behind [`coadapt_core::Env`].
//!
//! # Layout
//! - [`pendulum`]: gymnasium's Pendulum-v1 dynamics with pole length and mass as the design; no
//!   physics engine, so learning tests run in seconds.
//! - [`half_cheetah`]: the reference's HalfCheetah (PyBullet) in rapier2d, six leg lengths as the
//!   design.
//! - [`walker`], [`hopper`]: the thesis's Walker (MuJoCo's walker2d) and four-joint Hopper
//!   (dm_control's hopper) in rapier2d, leg segment lengths (and the Hopper's nose) as the design.
//! - [`planar`]: what the rapier2d robots share: the capsule body built from a plan, the physics
//!   setting and the environment around it.
//! - [`daisy`]: the thesis's Daisy hexapod (HEBI, 6 legs x 3 motors) in rapier3d, segment lengths
//!   and base-motor range offsets per leg pair as the design.
//! - [`reach`]: a three-joint arm reaching a target by small joint deltas, rewarded only on
//!   success (20 steps): the stand-in for the thesis's Baxter peg insertion (ch. 4), from pixels.
//! - [`bimanual`]: the bimanual planar reaching benchmark of ch. 2 (two six-joint arms following
//!   goal paths; no design), its kinematics and [`bimanual::PlanarEnv`], the robot an actor steps
//!   for policy search through a fleet.
//! - [`bench`](mod@bench): env steps per second under random actions.
//! - [`world`]: [`World`], the friction, actuator strength and torso mass a robot meets (each
//!   the robot's own unless set).
//! - [`make`], [`make_in`]: build any robot by its registry name (in a [`World`]), wrapped in a
//!   time limit.

pub mod bench;
pub mod bimanual;
pub mod daisy;
mod draw;
pub mod half_cheetah;
pub mod hopper;
pub mod pendulum;
pub mod planar;
pub mod reach;
pub mod walker;
pub mod world;

use coadapt_core::{Env, TimeLimit};

pub use daisy::Daisy;
pub use half_cheetah::HalfCheetah;
pub use hopper::Hopper;
pub use pendulum::Pendulum;
pub use reach::Reach;
pub use walker::Walker;
pub use world::{World, WorldError};

/// Names accepted by [`make`].
pub const ENV_NAMES: &[&str] = &["pendulum", "half-cheetah", "walker", "hopper", "daisy", "reach"];

#[derive(Debug, thiserror::Error)]
#[error("unknown environment `{0}` (known: {known})", known = ENV_NAMES.join(", "))]
pub struct UnknownEnv(pub String);

/// The fixed designs a co-adaptation of robot `name` starts with, the same for every seed (the
/// thesis fixes them across runs: the original body plus four random ones). HalfCheetah's are
/// the reference implementation's five (DESIGN.md section 2). The reference co-adapted no other
/// robot, so Walker's, Hopper's and Daisy's four others were drawn once, uniform in each box
/// and rounded to two decimals (Python's `random.Random(5)`, one `uniform(low, high)` per
/// coordinate, Walker then Hopper then Daisy), and are fixed here. `None` for robots without a
/// design (Pendulum).
pub fn reference_initial_designs(name: &str) -> Option<Vec<Vec<f32>>> {
    match name {
        "half-cheetah" => Some(vec![
            vec![1.0; 6],
            vec![1.41, 0.96, 1.97, 1.73, 1.97, 1.17],
            vec![1.52, 1.07, 1.11, 1.97, 1.51, 0.99],
            vec![1.08, 1.18, 1.39, 1.76, 1.85, 0.92],
            vec![0.85, 1.54, 0.97, 1.38, 1.10, 1.49],
        ]),
        "walker" => Some(vec![
            vec![1.0; 6],
            vec![1.12, 1.24, 1.3, 1.44, 1.24, 1.42],
            vec![0.53, 0.97, 1.44, 1.15, 1.4, 0.61],
            vec![0.97, 0.75, 1.04, 1.07, 0.51, 0.72],
            vec![0.78, 1.42, 1.27, 0.66, 1.3, 0.64],
        ]),
        "hopper" => Some(vec![
            vec![1.0; 5],
            vec![2.66, 0.69, 0.5, 1.81, 0.81],
            vec![1.25, 1.97, 1.81, 0.93, 1.94],
            vec![2.39, 1.52, 0.81, 1.91, 1.54],
            vec![3.88, 1.84, 0.95, 1.04, 0.75],
        ]),
        "daisy" => Some(vec![
            vec![0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.0, 0.0, 0.0],
            vec![0.18, 0.14, 0.23, 0.35, 0.12, 0.38, -0.06, -0.08, 0.13],
            vec![0.3, 0.24, 0.3, 0.39, 0.14, 0.49, -0.19, 0.1, 0.14],
            vec![0.13, 0.42, 0.26, 0.34, 0.12, 0.14, -0.13, 0.18, -0.12],
            vec![0.41, 0.47, 0.48, 0.25, 0.25, 0.32, 0.11, -0.16, 0.1],
        ]),
        _ => None,
    }
}

/// A fresh environment `name`, truncating episodes at its declared length.
pub fn make(name: &str) -> Result<Box<dyn Env>, UnknownEnv> {
    make_in(name, &World::default()).map_err(|e| match e {
        MakeError::Unknown(e) => e,
        MakeError::World(e) => unreachable!("the default world fits every robot: {e}"),
    })
}

/// Why [`make_in`] could not build a robot: both are settings to fix.
#[derive(Debug, thiserror::Error)]
pub enum MakeError {
    #[error(transparent)]
    Unknown(#[from] UnknownEnv),
    #[error(transparent)]
    World(#[from] WorldError),
}

/// [`make`] in `world`: the legged robots take every [`World`] value; Pendulum and Reach, which
/// have no ground, motors or torso of the kind, refuse any but the defaults.
pub fn make_in(name: &str, world: &World) -> Result<Box<dyn Env>, MakeError> {
    let w = world.clone();
    Ok(match name {
        "pendulum" => {
            world.check_unchanged("pendulum")?;
            Box::new(TimeLimit::new(Pendulum::new()))
        }
        "half-cheetah" => Box::new(TimeLimit::new(HalfCheetah::in_world(w)?)),
        "walker" => Box::new(TimeLimit::new(Walker::in_world(w)?)),
        "hopper" => Box::new(TimeLimit::new(Hopper::in_world(w)?)),
        "daisy" => Box::new(TimeLimit::new(Daisy::in_world(w)?)),
        "reach" => {
            world.check_unchanged("reach")?;
            Box::new(TimeLimit::new(Reach::new()))
        }
        other => return Err(UnknownEnv(other.to_string()).into()),
    })
}
