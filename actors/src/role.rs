//! The actor role: take an episode assignment, act with the newest weights, stream the
//! experience back, repeat until the learner closes the assignment queue or shutdown is asked.

use std::ops::ControlFlow;
use std::sync::atomic::AtomicBool;

use coadapt_core::Env;
use coadapt_transport::{ActorLinks, EpisodeEnd, EpisodeMode, ExperienceChunk, TransportError, newest_or_stop, next_or_stop};

use crate::{Actor, ActorError};

#[derive(Debug, thiserror::Error)]
pub enum ActorRoleError {
    #[error(transparent)]
    Actor(#[from] ActorError),
    #[error("transport: {0}")]
    Transport(#[from] TransportError),
}

/// What an actor did before it stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ActorSummary {
    pub episodes: u64,
    pub steps: u64,
    /// Episodes that failed in the environment and were dropped (and run again).
    pub failed_episodes: u64,
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
    let chunk_len = chunk_len.max(1);
    let mut summary = ActorSummary::default();
    let mut chunk = ExperienceChunk::default();
    while let Some(a) = next_or_stop(links.assignments.as_mut(), shutdown)? {
        let Some(weights) = newest_or_stop(links.weights.as_mut(), a.min_weights_version, shutdown)? else { break };
        if weights.version != actor.weights_version() {
            actor.set_weights(weights.version, &weights.policy)?;
        }
        let train = a.mode == EpisodeMode::Train;
        let mut failures = 0u32;
        let (stats, sent) = loop {
            actor.reseed_noise(a.seed);
            chunk.clear();
            chunk.actor = actor_id;
            chunk.assignment = a.id;
            chunk.design_index = a.design_index;
            chunk.weights_version = actor.weights_version();
            chunk.first = train;
            let mut sent: Result<(), TransportError> = Ok(());
            let mut steps = 0usize;
            let result = actor.run_episode(a.seed, &a.design, train, &mut |t| {
                steps += 1;
                if train {
                    chunk.obs.extend_from_slice(t.obs);
                    chunk.actions.extend_from_slice(t.action);
                    chunk.rewards.push(t.reward);
                    chunk.next_obs.extend_from_slice(t.next_obs);
                    chunk.terminated.push(t.terminated);
                }
                if steps.is_multiple_of(chunk_len) {
                    let full = std::mem::take(&mut chunk);
                    chunk.actor = full.actor;
                    chunk.assignment = full.assignment;
                    chunk.design_index = full.design_index;
                    chunk.weights_version = full.weights_version;
                    if let Err(e) = links.experience.send(full) {
                        sent = Err(e);
                        return ControlFlow::Break(());
                    }
                }
                ControlFlow::Continue(())
            });
            match result {
                Ok(stats) => break (stats, sent),
                Err(ActorError::Env(e)) if failures < env_retries && !shutdown.load(std::sync::atomic::Ordering::Relaxed) => {
                    failures += 1;
                    summary.failed_episodes += 1;
                    coadapt_log::logln!(
                        "actor {actor_id}: episode of assignment {} dropped after {steps} steps ({failures} in a row), running it again: {e}",
                        a.id
                    );
                }
                Err(e) => return Err(e.into()),
            }
        };
        chunk.end = Some(EpisodeEnd { episode_return: stats.episode_return, length: stats.length });
        match sent.and_then(|()| links.experience.send(std::mem::take(&mut chunk))) {
            Ok(()) => {}
            // The learner has finished and taken nothing more: a normal end.
            Err(TransportError::Closed) => break,
            Err(e) => return Err(e.into()),
        }
        summary.episodes += 1;
        summary.steps = summary.steps.saturating_add(stats.length);
    }
    Ok(summary)
}
