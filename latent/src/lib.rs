//! DDPG from pixels that explores by planning in a learned latent space (thesis ch. 4).
//!
//! # Layout
//! - `embedding`: the time-contrastive autoencoder (Eq. 4.1, 4.2), [`Embedding`]: convolutional
//!   encoder to a 20-D code on the unit sphere, mirrored decoder, the loss and its gradients.
//! - `dynamics`: the latent dynamics (Eq. 4.3-4.5), [`LatentDynamics`], and the planning
//!   objective f_Q of Alg. 3 (Eq. 4.11) with its gradient through the frozen model and critic,
//!   [`Planner`].
//! - `embedding_io`: [`save_embedding`] / [`load_embedding`], a trained embedding as one
//!   safetensors file (validated on load).
//! - `fleet`: Alg. 3's episodes through a fleet of actors: [`EpisodeRunner`] (the learner's
//!   side: weights out, whole episodes back into the replay) and [`run_actor`] (plans and acts
//!   where the robot is).
//! - `lbfgsb`: [`Lbfgsb`], L-BFGS within box bounds (projected), the planner's optimiser.
//! - `value`: the value critic through the learned model (Eq. 4.9, 4.10), [`ValueLosses`].
//! - `train_embedding`: [`FrameSet`] (episodes' frames, sampled as triples) and
//!   [`EmbeddingTrainer`] (Adam on both networks), to train the embedding once.
//! - `value_ddpg`: [`ValueDdpg`], DDPG with the value critic (actor, V, targets, Adam, OU).
//! - `actor`: the acting half, where the robot is: [`FrameStack`] (encoder, stacked state),
//!   [`PlanScratch`] (one planning step), [`LatentActor`] (the agent's acting networks, set
//!   from the learner's packed weights).
//! - `agent`: Alg. 3, [`LatentAgent`]: DDPG (Q or V critic) on the stacked latent state, OU or
//!   planned exploration (three objectives), the model, the reward model and DDPG trained at
//!   each episode's end.
//! - [`app`]: `coadapt latent` and `coadapt latent-actor` as a library: the config, the runs
//!   and their run directory, `--resume`, the embedding built once, the episodes on actors
//!   started here, the plot; [`app::run`] and [`app::actor`] take the binary's shutdown flag.

mod actor;
mod agent;
pub mod app;
mod dynamics;
mod embedding;
mod embedding_io;
mod fleet;
mod lbfgsb;
mod train_embedding;
mod value;
mod value_ddpg;

pub use actor::{ActingWeightsError, FrameStack, LatentActor, PlanNets, PlanScratch};
pub use agent::{AgentConfig, Critic, Explore, LatentAgent, RewardModel};
pub use dynamics::{CriticKind, LatentDynamics, NoRewardModel, Objective, PlanWork, Planner};
pub use embedding::{Embedding, EmbeddingConfig, EmbeddingWork, LossParts};
pub use embedding_io::{EmbeddingFileError, load_embedding, save_embedding};
pub use fleet::{ActorEpisode, CHUNK_STEPS, EpisodeRunner, FleetEpisode, FleetError, run_actor};
pub use lbfgsb::{Lbfgsb, LbfgsbResult};
pub use train_embedding::{EmbeddingTrainer, FrameSet, NotFrames};
pub use value::ValueLosses;
pub use value_ddpg::{ValueDdpg, ValueParams};
