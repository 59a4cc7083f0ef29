//! The coadapt learner: reinforcement learning on faer networks.
//!
//! # Layout
//! - [`action_space`]: latent design-dependent action spaces (thesis 6.2, Eq. 6.1): the
//!   Q-weighted action autoencoder and correlated exploration through its decoder.
//! - [`config`]: [`SacConfig`] and [`DdpgConfig`], the reference hyper-parameters as defaults;
//!   [`ConfigError`], a run's setting (schedule, flow, snapshots) that cannot work.
//! - [`networks`]: network shapes (critic `[obs, action] -> 1`, Gaussian and deterministic
//!   policies).
//! - [`sac`]: Soft Actor-Critic, the update in the paper's notation.
//! - [`conservative`]: COMs' conservative term on FEAR's population ensemble heads (beyond
//!   the thesis): a design critic pushed down at the designs its own gradient ascent reaches.
//! - [`ddpg`]: DDPG with Ornstein-Uhlenbeck or Gaussian exploration.
//! - [`agent`]: [`Agent`], what a training loop needs of either algorithm.
//! - [`fear`]: the FEAR learner: population and individual SAC pairs, their buffers and the
//!   per-episode training schedule.
//! - [`coadapt`]: the learner role of a co-adaptation: the design schedule, episodes over the
//!   transport, evaluation, and the run directory's rows ([`run_dir`]).
//! - [`prototype`]: the prototype step for real hardware: the files through which a waiting
//!   run and `coadapt confirm` talk (designs to build, resets by hand), both sides.
//! - [`flow`]: flow control between collection and training (lock-step or a window of
//!   episodes in flight), leases that re-issue a silent actor's episode, policy lag.
//! - [`snapshot`]: snapshots of a whole run (networks, optimisers, replay buffers, schedule)
//!   written crash-safely and checked on reading, for resuming after any crash.
//! - [`disk`]: free space where the run directory lives against what the next snapshot needs
//!   (the progress line's and `/metrics`' warning before a full disk stops a run).
//! - [`train`]: RL on one environment and one design (`coadapt train`), writing `episodes.csv`;
//!   [`render`]: an episode of a robot with a trained policy as an animated GIF (`coadapt render`).

pub mod action_space;
pub mod agent;
pub mod coadapt;
pub mod config;
pub mod conservative;
pub mod ddpg;
pub mod disk;
pub mod fear;
pub mod flow;
pub mod networks;
pub mod prototype;
pub mod render;
pub mod run_dir;
pub mod run_events;
pub mod sac;
pub mod snapshot;
pub mod train;

pub use agent::{Agent, Algo};
pub use config::{ConfigError, DdpgConfig, Exploration, SacConfig};
pub use ddpg::{Ddpg, DdpgLosses, ExplorationNoise};
pub use sac::{Sac, SacLosses};
