//! The robots whose bodies coadapt optimises, behind [`coadapt_core::Env`].
//!
//! # Layout
//! - [`pendulum`]: gymnasium's Pendulum-v1 dynamics with pole length and mass as the design; no
//!   physics engine, so learning tests run in seconds.
//! - [`half_cheetah`]: the reference's HalfCheetah (PyBullet) in rapier2d, six leg lengths as the
//!   design.
//! - [`bench`](mod@bench): env steps per second under random actions.
//! - [`make`]: builds any robot by its registry name, wrapped in a time limit.

pub mod bench;
mod draw;
pub mod half_cheetah;
pub mod pendulum;

use coadapt_core::{Env, TimeLimit};

pub use half_cheetah::HalfCheetah;
pub use pendulum::Pendulum;

/// Names accepted by [`make`].
pub const ENV_NAMES: &[&str] = &["pendulum", "half-cheetah"];

#[derive(Debug, thiserror::Error)]
#[error("unknown environment `{0}` (known: {known})", known = ENV_NAMES.join(", "))]
pub struct UnknownEnv(pub String);

/// A fresh environment `name`, truncating episodes at its declared length.
pub fn make(name: &str) -> Result<Box<dyn Env>, UnknownEnv> {
    match name {
        "pendulum" => Ok(Box::new(TimeLimit::new(Pendulum::new()))),
        "half-cheetah" => Ok(Box::new(TimeLimit::new(HalfCheetah::new()))),
        other => Err(UnknownEnv(other.to_string())),
    }
}
