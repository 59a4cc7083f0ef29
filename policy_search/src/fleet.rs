//! Rollouts through a fleet of actors: on a real robot the rollouts of an iteration are the
//! expensive part and independent of each other, so they go out over the same transports as a
//! co-adaptation's episodes (in process, shared memory, gRPC).
//!
//! The protocol, on the fleet's existing messages: an iteration publishes one acting-weights
//! version whose `policy` holds every rollout's open-loop actions (`rollouts x steps x
//! action_dim`: the sampled parameters already multiplied out with the time features, which is
//! all an episodic policy is; a few kB, no network), then one assignment per rollout whose
//! `seed` is the rollout's index and whose `min_weights_version` is that version. An actor
//! ([`run_actor`]) plays the rollout's actions on its robot ([`PlanarEnv`](coadapt_robots::bimanual::PlanarEnv)
//! here, any [`Env`] in general) and streams the transitions and the episode's return back. The learner side,
//! [`FleetRunner`], is a [`RolloutRunner`]: it waits for every rollout and sums each rollout's
//! cost from its observations. Leases, reissue and exactly-once are the fleet library's
//! ([`coadapt_fleet`]); this file says only what a rollout is.

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use coadapt_core::{Env, Transition};
use coadapt_fleet::{ActorConfig, Check, DispatchConfig, Dispatcher, Done, Failure, Job, Stream, Verdict, Worker};
use coadapt_transport::messages::{Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, Weights};
use coadapt_transport::{ActorLinks, LearnerLinks};

use crate::{RolloutError, RolloutRunner};

/// Rollouts on one actor: the iteration's actions, played on its robot.
struct Rollouts<'e> {
    env: &'e mut dyn Env,
    steps: usize,
    actor_id: u64,
    weights: Option<Arc<Weights>>,
    prev: Vec<f32>,
}

impl Worker for Rollouts<'_> {
    type Error = String;

    fn set_weights(&mut self, weights: &Arc<Weights>) -> Result<(), String> {
        self.weights = Some(weights.clone());
        Ok(())
    }

    fn run(&mut self, a: &Assignment, stream: &mut Stream<'_>) -> Result<Option<EpisodeEnd>, Failure<String>> {
        let (id, steps, d) = (self.actor_id, self.steps, self.env.spec().act_dim());
        let Some(w) = self.weights.as_ref() else { return Err(Failure::Fatal("no weights".into())) };
        let r = usize::try_from(a.seed).unwrap_or(usize::MAX);
        let Some(actions) = r.checked_mul(steps * d).and_then(|at| w.policy.get(at..at + steps * d)) else {
            coadapt_log::logln!(
                "actor {id}: assignment {} names rollout {r}, beyond the {} the iteration holds; skipped",
                a.id,
                w.policy.len() / (steps * d).max(1)
            );
            return Ok(None);
        };
        let obs = self.env.reset(a.seed, &a.design).map_err(|e| Failure::Env(format!("actor {id}: reset: {e}")))?;
        self.prev.clear();
        self.prev.extend_from_slice(obs);
        let (mut ret, mut length) = (0.0f32, 0u64);
        for t in 0..steps {
            let act = &actions[t * d..(t + 1) * d];
            let step = self.env.step(act).map_err(|e| Failure::Env(format!("actor {id}: step {t}: {e}")))?;
            ret += step.reward;
            length += 1;
            let last = step.terminated || step.truncated;
            let sent = stream.push(&Transition {
                obs: &self.prev,
                action: act,
                reward: step.reward,
                next_obs: step.observation,
                terminated: step.terminated,
            });
            self.prev.clear();
            self.prev.extend_from_slice(step.observation);
            if last || sent.is_break() {
                break;
            }
        }
        Ok(Some(EpisodeEnd { episode_return: ret, length }))
    }
}

/// Runs the rollouts the learner hands out on `env` until the assignment queue closes or
/// `shutdown` is set; returns how many it ran. Each rollout is `steps` steps (the task's: a
/// remote robot may not say its episode length). A rollout whose weights are not the
/// iteration's any more (the learner moved on) is skipped.
pub fn run_actor(
    env: &mut dyn Env,
    steps: usize,
    actor_id: u64,
    links: &mut ActorLinks,
    shutdown: &AtomicBool,
) -> Result<u64, RolloutError> {
    let mut worker = Rollouts { env, steps, actor_id, weights: None, prev: Vec::new() };
    let cfg = ActorConfig { exact_weights: true, record_eval: true, ..ActorConfig::default() };
    let summary = coadapt_fleet::actor::run(&mut worker, actor_id, links, &cfg, shutdown)
        .map_err(|e| RolloutError(format!("actor {actor_id}: {e}")))?;
    Ok(summary.episodes)
}

/// A rollout of the iteration, as the dispatcher names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Rollout(usize);

impl std::fmt::Display for Rollout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "rollout {}", self.0)
    }
}

/// What a rollout must look like: `steps` transitions of the task's widths.
struct RolloutCheck {
    steps: usize,
    action_dim: usize,
    obs_dim: usize,
}

impl Check<Rollout> for RolloutCheck {
    fn chunk(&mut self, c: &ExperienceChunk) -> Result<(), String> {
        let k = c.len();
        if c.next_obs.len() != k * self.obs_dim || c.actions.len() != k * self.action_dim {
            return Err(format!("{k} rewards, {} observation values, {} actions", c.next_obs.len(), c.actions.len()));
        }
        Ok(())
    }

    fn episode(&mut self, d: &Done<Rollout>) -> Verdict {
        if d.steps != self.steps || d.end.length != self.steps as u64 {
            return Verdict::Again(format!("ended after {} steps, expected {}", d.steps, self.steps));
        }
        Verdict::Accept
    }
}

/// The learner's side of rollouts through a fleet (see the module doc).
pub struct FleetRunner {
    links: Mutex<(LearnerLinks, Dispatcher<Rollout>, u64)>,
    steps: usize,
    action_dim: usize,
    obs_dim: usize,
    step_cost: fn(&[f32]) -> f64,
}

impl std::fmt::Debug for FleetRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FleetRunner").field("steps", &self.steps).field("action_dim", &self.action_dim).finish_non_exhaustive()
    }
}

impl FleetRunner {
    /// Rollouts of `steps x action_dim` actions on robots with observations of `obs_dim`;
    /// `step_cost` reads a step's cost from its observation. A rollout that sent nothing for a
    /// minute goes out again; an iteration not back within an hour fails (see the setters).
    pub fn new(links: LearnerLinks, steps: usize, action_dim: usize, obs_dim: usize, step_cost: fn(&[f32]) -> f64) -> Self {
        let cfg = DispatchConfig {
            lease: Duration::from_secs(60),
            deadline: Some(Duration::from_secs(3600)),
            max_steps: steps,
            ..DispatchConfig::default()
        };
        Self { links: Mutex::new((links, Dispatcher::new("search", cfg), 0)), steps, action_dim, obs_dim, step_cost }
    }

    fn dispatcher(&mut self) -> &mut Dispatcher<Rollout> {
        &mut self.links.get_mut().unwrap_or_else(|e| e.into_inner()).1
    }

    /// A rollout that sent nothing for `lease` goes out again (to whichever actor is free).
    pub fn set_lease(&mut self, lease: Duration) {
        self.dispatcher().cfg.lease = lease;
    }

    /// A rollout not back `deadline` after it went out fails the iteration.
    pub fn set_deadline(&mut self, deadline: Duration) {
        self.dispatcher().cfg.deadline = Some(deadline);
    }

    /// Asked while waiting: `Some(why)` gives up on the iteration (every actor process gone).
    pub fn set_abort(&mut self, abort: Box<dyn Fn() -> Option<String> + Send + Sync>) {
        self.dispatcher().abort = Some(abort);
    }
}

impl RolloutRunner for FleetRunner {
    fn run(&self, rollouts: &[Vec<f32>]) -> Result<Vec<(f64, f64)>, RolloutError> {
        let n = rollouts.len();
        let per = self.steps * self.action_dim;
        if let Some(i) = rollouts.iter().position(|a| a.len() != per) {
            return Err(RolloutError(format!("rollout {i} has {} actions, expected {per}", rollouts[i].len())));
        }
        let mut guard = self.links.lock().unwrap_or_else(|e| e.into_inner());
        let (links, dispatcher, version) = &mut *guard;
        let err = |e: coadapt_fleet::DispatchError| RolloutError(e.to_string());
        // What a failed iteration left out is not waited for.
        dispatcher.forget_all();
        *version += 1;
        let version = *version;
        links
            .acting_weights
            .publish(Weights { version, policy: rollouts.concat(), q1: vec![], q2: vec![], heads: vec![] })
            .map_err(|e| RolloutError(e.to_string()))?;
        for r in 0..n {
            let job = Job {
                design_index: u32::try_from(version).unwrap_or(u32::MAX),
                design: vec![],
                mode: EpisodeMode::Train,
                seed: r as u64,
                min_weights_version: version,
            };
            dispatcher.issue(links, job, Rollout(r)).map_err(err)?;
        }
        let mut check = RolloutCheck { steps: self.steps, action_dim: self.action_dim, obs_dim: self.obs_dim };
        let mut results: Vec<Option<(f64, f64)>> = vec![None; n];
        let mut reissued = 0u32;
        let never = AtomicBool::new(false);
        while results.iter().any(Option::is_none) {
            let Some(done) = dispatcher.next_done(links, &never, &mut check).map_err(err)? else { break };
            reissued += done.reissued;
            let (mut ret, mut cost) = (0.0f64, 0.0f64);
            for c in &done.chunks {
                ret += c.rewards.iter().map(|&r| f64::from(r)).sum::<f64>();
                cost += c.next_obs.chunks_exact(self.obs_dim.max(1)).map(self.step_cost).sum::<f64>();
            }
            if let Some(slot) = results.get_mut(done.tag.0) {
                *slot = Some((ret, cost));
            }
        }
        if reissued > 0 {
            coadapt_log::logln!("search: {reissued} rollout(s) of this iteration went out again");
        }
        Ok(results.into_iter().map(|r| r.unwrap_or((0.0, f64::NAN))).collect())
    }
}
