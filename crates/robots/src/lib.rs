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
//! - [`bench`](mod@bench): env steps per second under random actions.
//! - [`make`]: builds any robot by its registry name, wrapped in a time limit.

pub mod bench;
pub mod daisy;
mod draw;
pub mod half_cheetah;
pub mod hopper;
pub mod pendulum;
pub mod planar;
pub mod walker;

use coadapt_core::{Env, TimeLimit};

pub use daisy::Daisy;
pub use half_cheetah::HalfCheetah;
pub use hopper::Hopper;
pub use pendulum::Pendulum;
pub use walker::Walker;

/// Names accepted by [`make`].
pub const ENV_NAMES: &[&str] = &["pendulum", "half-cheetah", "walker", "hopper", "daisy"];

#[derive(Debug, thiserror::Error)]
#[error("unknown environment `{0}` (known: {known})", known = ENV_NAMES.join(", "))]
pub struct UnknownEnv(pub String);

/// The fixed designs a co-adaptation of robot `name` starts with: the reference's five for
/// HalfCheetah (DESIGN.md section 2: the original body and four fixed others); for the other
/// robots, which the reference did not co-adapt, `None` (the caller picks the original design
/// plus random ones).
pub fn reference_initial_designs(name: &str) -> Option<Vec<Vec<f32>>> {
    match name {
        "half-cheetah" => Some(vec![
            vec![1.0; 6],
            vec![1.41, 0.96, 1.97, 1.73, 1.97, 1.17],
            vec![1.52, 1.07, 1.11, 1.97, 1.51, 0.99],
            vec![1.08, 1.18, 1.39, 1.76, 1.85, 0.92],
            vec![0.85, 1.54, 0.97, 1.38, 1.10, 1.49],
        ]),
        _ => None,
    }
}

/// A fresh environment `name`, truncating episodes at its declared length.
pub fn make(name: &str) -> Result<Box<dyn Env>, UnknownEnv> {
    match name {
        "pendulum" => Ok(Box::new(TimeLimit::new(Pendulum::new()))),
        "half-cheetah" => Ok(Box::new(TimeLimit::new(HalfCheetah::new()))),
        "walker" => Ok(Box::new(TimeLimit::new(Walker::new()))),
        "hopper" => Ok(Box::new(TimeLimit::new(Hopper::new()))),
        "daisy" => Ok(Box::new(TimeLimit::new(Daisy::new()))),
        other => Err(UnknownEnv(other.to_string())),
    }
}
