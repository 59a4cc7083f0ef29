//! `coadapt latent` as a library: the run directory of DDPG from pixels exploring by latent
//! planning (config, embedding, runs, resume, episodes on actors, plot, summary) and the actor
//! process. The binary parses the command line into a [`LatentConfig`] ([`resolve`]) and calls
//! [`run`], [`embedding`] or [`actor`] with its shutdown flag.
//!
//! - `config`: [`LatentConfig`] (`[camera]`, the agent, `[embedding]`, the fleet), the command
//!   line's [`Overrides`] and the checks, [`resolve`].
//! - `embed`: the frozen embedding, built once from state-based DDPG's frames
//!   ([`EmbeddingSettings`], [`FrameSource`], [`load_or_build`]).
//! - `run`: [`run`], the runs and `episodes.csv`, checkpoints and the summary.
//! - `resume`: `--resume`, the finished runs of a stopped run directory kept.
//! - `actors`: the episodes on actors that plan where the robot is (threads, or `coadapt
//!   latent-actor` processes), and [`actor`], the actor process's loop.
//! - `plot`: `plots/returns.svg`.
//!
//! Its errors are the fleet's [`AppError`](coadapt_fleet::app::AppError), as every application's.

mod actors;
mod config;
mod embed;
mod plot;
mod resume;
mod run;

pub use actors::actor;
pub use config::{CameraSettings, LatentConfig, Overrides, resolve};
pub use embed::{EmbeddingSettings, FrameSource, build, load_or_build};
pub use run::{embedding, run};
