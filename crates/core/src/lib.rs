//! Shared, I/O-free pieces of coadapt, used by every role.
//!
//! # Layout
//! - [`space`]: [`BoxSpace`], the bounded boxes of actions, observations and designs.
//! - [`env`]: the [`Env`] trait (gymnasium-like, with a design vector at reset), its [`EnvSpec`],
//!   errors, the [`Shape`]s a body is drawn with, and the [`TimeLimit`] wrapper that truncates
//!   episodes.
//! - [`replay`]: [`ReplayBuffer`] of flat transitions and [`Batch`], including batches drawn from
//!   several buffers in fixed proportions (FEAR's 26 population + 230 species samples).
//! - [`conformance`]: the suite every `Env` implementation runs in its tests.
//! - [`render`]: a small rasteriser of bodies ([`Shape`]s) into palette-indexed frames;
//!   [`pixels`]: [`Pixels`], the wrapper that gives any drawable robot stacked RGB frames as its
//!   observation, with action repeat.
//!
//! Randomness everywhere is [`Rng64`] (PCG-64 MCG): fast, seedable, and the same stream on every
//! platform, so a seed reproduces a run.

pub mod conformance;
pub mod env;
pub mod pixels;
pub mod render;
pub mod replay;
pub mod space;

pub use env::{Env, EnvError, EnvSpec, Shape, Step, TimeLimit};
pub use pixels::{Pixels, PixelsConfig};
pub use replay::{Batch, ReplayBuffer, ReplayError, ReplayRestoreError, Transition};
pub use space::{BoxSpace, SpaceError};

/// The project's random number generator.
pub type Rng64 = rand_pcg::Pcg64Mcg;

/// A generator for stream `stream` of `seed` (e.g. one per actor, or env vs learner).
pub fn rng(seed: u64, stream: u64) -> Rng64 {
    use rand::SeedableRng;
    // Mix so that neighbouring (seed, stream) pairs do not give correlated states.
    let mut z = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    Rng64::seed_from_u64(z ^ (z >> 31))
}
