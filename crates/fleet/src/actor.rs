//! The actor's side of a fleet: take an assignment, act with the newest weights, stream the
//! experience back, repeat until the learner closes the assignment queue or shutdown is asked.
//!
//! What an episode *is* belongs to the experiment ([`Worker`]): a SAC policy on a robot, a
//! latent planner behind a camera, a rollout's open-loop actions. The loop around it is the
//! same for all of them and lives here: waiting for work and weights, loading weights only when
//! their version changes, chunking the transitions ([`Stream`]) so the learner hears from the
//! actor at least every `chunk_len` steps (evaluation episodes that record nothing send empty
//! keep-alive chunks), and running an episode again from its first step when its environment
//! fails, marked `first` again so the learner forgets the failed attempt.

use std::fmt::Display;
use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use coadapt_core::Transition;
use coadapt_transport::{
    ActorLinks, Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, Sender, TransportError, Weights, newest_or_stop, next_or_stop,
};

/// How an actor streams its episodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ActorConfig {
    /// Transitions per chunk (the learner hears from the actor at least this often).
    pub chunk_len: usize,
    /// Times in a row an episode whose environment failed is run again before the actor stops.
    pub env_retries: u32,
    /// Send evaluation episodes' transitions too (false: only keep-alives and the end).
    pub record_eval: bool,
    /// Skip an assignment whose weights are not exactly its `min_weights_version` any more (the
    /// learner moved on); false: act with the newest weights of at least that version.
    pub exact_weights: bool,
}

impl Default for ActorConfig {
    fn default() -> Self {
        Self { chunk_len: 50, env_retries: 0, record_eval: false, exact_weights: false }
    }
}

/// Why an episode did not finish.
#[derive(Debug)]
pub enum Failure<E> {
    /// The environment failed (a remote robot gone, a non-finite observation): worth running
    /// the episode again.
    Env(E),
    /// Anything else: the actor stops.
    Fatal(E),
}

/// One experiment's episodes on one actor.
pub trait Worker {
    type Error: Display;
    /// Takes weights of a version it has not held yet.
    fn set_weights(&mut self, weights: &Arc<Weights>) -> Result<(), Self::Error>;
    /// Runs assignment `a`, handing every transition to `stream` (stopping when it says
    /// `Break`: the learner has gone). `Ok(None)`: the assignment cannot be run here and is
    /// skipped (the worker says why).
    fn run(&mut self, a: &Assignment, stream: &mut Stream<'_>) -> Result<Option<EpisodeEnd>, Failure<Self::Error>>;
}

/// An actor loop's error.
#[derive(Debug, thiserror::Error)]
pub enum ActorLoopError<E: Display> {
    #[error("{0}")]
    Worker(E),
    // The cause in the message, not as a source: `{:#}` would print it twice.
    #[error("transport: {0}")]
    Transport(TransportError),
}

/// What an actor did before it stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ActorSummary {
    pub episodes: u64,
    pub steps: u64,
    /// Episodes that failed in the environment and were dropped (and run again).
    pub failed_episodes: u64,
    /// Assignments skipped (stale weights, or the worker could not run them).
    pub skipped: u64,
}

/// Where an episode's transitions go: chunks of `chunk_len` to the learner.
pub struct Stream<'a> {
    chunk: ExperienceChunk,
    record: bool,
    chunk_len: usize,
    steps: u64,
    tx: &'a mut dyn Sender<ExperienceChunk>,
    failed: Option<TransportError>,
}

impl std::fmt::Debug for Stream<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stream").field("steps", &self.steps).field("record", &self.record).finish_non_exhaustive()
    }
}

impl<'a> Stream<'a> {
    fn new(
        tx: &'a mut dyn Sender<ExperienceChunk>,
        actor: u64,
        a: &Assignment,
        weights_version: u64,
        record: bool,
        chunk_len: usize,
    ) -> Self {
        let chunk = ExperienceChunk {
            actor,
            assignment: a.id,
            design_index: a.design_index,
            weights_version,
            first: record,
            ..ExperienceChunk::default()
        };
        Self { chunk, record, chunk_len: chunk_len.max(1), steps: 0, tx, failed: None }
    }

    /// Steps streamed so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// One step; `Break` once the learner cannot be reached (stop the episode).
    pub fn push(&mut self, t: &Transition<'_>) -> ControlFlow<()> {
        if self.failed.is_some() {
            return ControlFlow::Break(());
        }
        self.steps += 1;
        if self.record {
            let c = &mut self.chunk;
            c.obs.extend_from_slice(t.obs);
            c.actions.extend_from_slice(t.action);
            c.rewards.push(t.reward);
            c.next_obs.extend_from_slice(t.next_obs);
            c.terminated.push(t.terminated);
        }
        if self.steps.is_multiple_of(self.chunk_len as u64) {
            let next = ExperienceChunk {
                actor: self.chunk.actor,
                assignment: self.chunk.assignment,
                design_index: self.chunk.design_index,
                weights_version: self.chunk.weights_version,
                ..ExperienceChunk::default()
            };
            let full = std::mem::replace(&mut self.chunk, next);
            if let Err(e) = self.tx.send(full) {
                self.failed = Some(e);
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    }

    /// Sends the rest of the episode with its end.
    fn finish(mut self, end: EpisodeEnd) -> Result<(), TransportError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        self.chunk.end = Some(end);
        self.tx.send(self.chunk)
    }
}

/// Runs assignments with `worker` until the queue closes (`Ok`) or `shutdown` is set.
pub fn run<W: Worker>(
    worker: &mut W,
    actor_id: u64,
    links: &mut ActorLinks,
    cfg: &ActorConfig,
    shutdown: &AtomicBool,
) -> Result<ActorSummary, ActorLoopError<W::Error>> {
    let mut summary = ActorSummary::default();
    let mut held = None;
    while let Some(a) = next_or_stop(links.assignments.as_mut(), shutdown)? {
        let Some(weights) = newest_or_stop(links.weights.as_mut(), a.min_weights_version, shutdown)? else { break };
        if cfg.exact_weights && weights.version != a.min_weights_version {
            summary.skipped += 1;
            continue;
        }
        if held != Some(weights.version) {
            worker.set_weights(&weights).map_err(ActorLoopError::Worker)?;
            held = Some(weights.version);
        }
        let record = a.mode == EpisodeMode::Train || cfg.record_eval;
        let mut failures = 0u32;
        let sent = loop {
            let mut stream = Stream::new(links.experience.as_mut(), actor_id, &a, weights.version, record, cfg.chunk_len);
            match worker.run(&a, &mut stream) {
                Ok(Some(end)) => break stream.finish(end).map(|()| Some(end)),
                Ok(None) => break Ok(None),
                Err(Failure::Env(e)) if failures < cfg.env_retries && !shutdown.load(Ordering::Relaxed) => {
                    failures += 1;
                    summary.failed_episodes += 1;
                    coadapt_log::logln!(
                        "actor {actor_id}: episode of assignment {} dropped after {} steps ({failures} in a row), running it again: {e}",
                        a.id,
                        stream.steps()
                    );
                }
                Err(Failure::Env(e) | Failure::Fatal(e)) => return Err(ActorLoopError::Worker(e)),
            }
        };
        match sent {
            Ok(Some(end)) => {
                summary.episodes += 1;
                summary.steps = summary.steps.saturating_add(end.length);
            }
            Ok(None) => summary.skipped += 1,
            // The learner has finished and takes nothing more: a normal end.
            Err(TransportError::Closed) => break,
            Err(e) => return Err(e.into()),
        }
    }
    Ok(summary)
}

impl<E: Display> From<TransportError> for ActorLoopError<E> {
    fn from(e: TransportError) -> Self {
        Self::Transport(e)
    }
}
