//! The actor role: take an episode assignment, act with the newest weights, stream the
//! experience back, repeat until the learner closes the assignment queue or shutdown is asked.
//! The loop is the fleet library's ([`coadapt_fleet::actor`]); this file says what an episode
//! of the co-adaptation is: the SAC policy on the assigned body.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use coadapt_core::Env;
pub use coadapt_fleet::ActorSummary;
use coadapt_fleet::{ActorConfig, ActorLoopError, Failure, Stream, Worker};
use coadapt_transport::{ActorLinks, Assignment, EpisodeEnd, EpisodeMode, TransportError, Weights};

use crate::{Actor, ActorError};

#[derive(Debug, thiserror::Error)]
pub enum ActorRoleError {
    #[error(transparent)]
    Actor(#[from] ActorError),
    #[error("transport: {0}")]
    Transport(#[from] TransportError),
}

/// A robot that failed or a link that broke may do better after a restart.
impl coadapt_fleet::supervise::exit::ExitCode for ActorRoleError {}

impl From<ActorLoopError<ActorError>> for ActorRoleError {
    fn from(e: ActorLoopError<ActorError>) -> Self {
        match e {
            ActorLoopError::Worker(e) => Self::Actor(e),
            ActorLoopError::Transport(e) => Self::Transport(e),
        }
    }
}

impl<E: Env> Worker for Actor<E> {
    type Error = ActorError;

    fn set_weights(&mut self, w: &Arc<Weights>) -> Result<(), ActorError> {
        Actor::set_weights(self, w.version, &w.policy)
    }

    fn run(&mut self, a: &Assignment, stream: &mut Stream<'_>) -> Result<Option<EpisodeEnd>, Failure<ActorError>> {
        self.reseed_noise(a.seed);
        match self.run_episode(a.seed, &a.design, a.mode == EpisodeMode::Train, &mut |t| stream.push(t)) {
            Ok(stats) => Ok(Some(EpisodeEnd { episode_return: stats.episode_return, length: stats.length })),
            Err(e @ ActorError::Env(_)) => Err(Failure::Env(e)),
            Err(e) => Err(Failure::Fatal(e)),
        }
    }
}

/// Runs assignments until the queue closes (`Ok`) or `shutdown` is set. Training episodes send
/// every transition in chunks of `chunk_len`; evaluation episodes send an empty chunk every
/// `chunk_len` steps (so the learner knows the actor is alive) and their end. Chunks carry
/// `actor_id`.
///
/// An episode that fails in the environment (a remote robot gone, a non-finite observation) is
/// dropped and run again from its first step, up to `env_retries` times in a row; its first
/// chunk is marked `first` again, which tells the learner to forget what the failed attempt
/// sent, so only whole episodes reach a replay buffer.
pub fn run<E: Env>(
    actor: &mut Actor<E>,
    actor_id: u64,
    links: &mut ActorLinks,
    chunk_len: usize,
    env_retries: u32,
    shutdown: &AtomicBool,
) -> Result<ActorSummary, ActorRoleError> {
    let cfg = ActorConfig { chunk_len, env_retries, record_eval: false, exact_weights: false };
    Ok(coadapt_fleet::actor::run(actor, actor_id, links, &cfg, shutdown)?)
}
