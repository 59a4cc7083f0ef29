//! Alg. 3's episodes through a fleet: the learner trains, the actor plans where the robot is.
//!
//! The protocol, on the co-adaptation's own messages and links (in process, shared memory,
//! gRPC): for every episode the learner publishes one acting-weights version whose `policy`
//! holds the agent's packed acting networks ([`LatentAgent::acting_weights`]: actor, critic,
//! model, reward model), then one assignment whose `min_weights_version` is that version, whose
//! `seed` seeds the robot's reset and whose `mode` says explore-and-learn (`Train`) or
//! deterministic (`Eval`). An actor ([`run_actor`]) takes the weights into its
//! [`LatentActor`], runs the episode on its robot (planning every step when exploring by
//! planning) and streams the latent transitions `(z_t, a_t, r_t, z_t+1)` back, a chunk every
//! [`CHUNK_STEPS`] steps: the encoder is frozen, so the latent state is all the learner
//! needs, and a 60-value state is small where a frame is 12,288 values. The learner side,
//! [`EpisodeRunner`], waits for the whole episode and only then stores the transitions: a
//! half-run episode never reaches the replay. Leases, reissue after a silent actor and
//! exactly-once are the fleet library's ([`coadapt_fleet`]); this file says what an episode is.
//!
//! With the same weights and seeds a fleet's planned episodes equal the in-process agent's
//! bit for bit (tested); OU noise is drawn by the actor from its own stream.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use coadapt_core::{Env, Transition};
use coadapt_fleet::{ActorConfig, Check, DispatchConfig, DispatchError, Dispatcher, Done, Failure, Job, Stream, Verdict, Worker};
use coadapt_transport::messages::{Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, Weights};
use coadapt_transport::{ActorLinks, LearnerLinks, TransportError};

use crate::{LatentActor, LatentAgent};

/// Steps per experience chunk an actor sends (the learner hears from it at least this often).
pub const CHUNK_STEPS: usize = 50;

/// What went wrong with a fleet episode.
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    #[error("transport: {0}")]
    Transport(#[from] TransportError),
    #[error("actor {actor}: {why}")]
    Actor { actor: u64, why: String },
    #[error("{0}")]
    Learner(String),
}

/// A fleet that failed may come back after a restart.
impl coadapt_fleet::supervise::exit::ExitCode for FleetError {}

impl From<DispatchError> for FleetError {
    fn from(e: DispatchError) -> Self {
        match e {
            DispatchError::Transport(t) => Self::Transport(t),
            other => Self::Learner(other.to_string()),
        }
    }
}

/// One episode's planning latency on the actor (milliseconds per planned step).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ActorEpisode {
    pub assignment: u64,
    pub train: bool,
    pub steps: usize,
    pub episode_return: f32,
    /// Milliseconds of each planned step (empty when not planning).
    pub plan_ms: Vec<f64>,
    /// Wall-clock seconds of the whole episode on the actor (robot steps included).
    pub seconds: f64,
}

/// Alg. 3's episodes on one actor: the latent planner behind the robot's camera.
struct Planner<'a> {
    actor: &'a mut LatentActor,
    env: &'a mut dyn Env,
    steps: usize,
    report: &'a mut dyn FnMut(&ActorEpisode),
    default_design: Vec<f32>,
    a_t: Vec<f32>,
    frame: Vec<f32>,
    z: Vec<f32>,
}

impl Worker for Planner<'_> {
    type Error = String;

    fn set_weights(&mut self, w: &Arc<Weights>) -> Result<(), String> {
        self.actor.set_weights(&w.policy).map_err(|e| e.to_string())
    }

    fn run(&mut self, asg: &Assignment, stream: &mut Stream<'_>) -> Result<Option<EpisodeEnd>, Failure<String>> {
        let Self { actor, env, steps, report, default_design, a_t, frame, z } = self;
        let px = frame.len();
        let train = asg.mode == EpisodeMode::Train;
        let design = if asg.design.is_empty() { &*default_design } else { &asg.design };
        let t0 = Instant::now();
        let mut out = ActorEpisode { assignment: asg.id, train, ..ActorEpisode::default() };
        let obs = env.reset(asg.seed, design).map_err(|e| Failure::Env(format!("reset: {e}")))?;
        let Some(f) = obs.get(..px) else {
            return Err(Failure::Fatal(format!("reset: the observation has {} values, a frame needs {px}", obs.len())));
        };
        frame.copy_from_slice(f);
        z.clear();
        z.extend_from_slice(actor.reset(frame));
        for t in 0..*steps {
            let start = Instant::now();
            if actor.act(train, a_t).is_some() {
                out.plan_ms.push(start.elapsed().as_secs_f64() * 1e3);
            }
            let s = env.step(a_t).map_err(|e| Failure::Env(format!("step {t}: {e}")))?;
            let (r, term, trunc) = (s.reward, s.terminated, s.truncated);
            let Some(f) = s.observation.get(..px) else {
                return Err(Failure::Fatal(format!("step {t}: the observation has {} values, a frame needs {px}", s.observation.len())));
            };
            frame.copy_from_slice(f);
            let next = actor.observe(frame);
            let sent = stream.push(&Transition { obs: z, action: a_t, reward: r, next_obs: next, terminated: term });
            z.copy_from_slice(next);
            out.episode_return += r;
            out.steps += 1;
            if term || trunc || sent.is_break() {
                break;
            }
        }
        out.seconds = t0.elapsed().as_secs_f64();
        report(&out);
        Ok(Some(EpisodeEnd { episode_return: out.episode_return, length: out.steps as u64 }))
    }
}

/// Runs the episodes the learner hands out on `env` (its observation's first
/// `actor.image_len()` values are the frame) with `actor`, at most `steps` per episode, until
/// the assignment queue closes or `shutdown` is set; `report` hears of every finished
/// episode. Returns how many episodes it ran. An assignment whose weights are not the newest
/// any more (the learner moved on, or gave it to another actor) is skipped.
pub fn run_actor(
    actor: &mut LatentActor,
    env: &mut dyn Env,
    steps: usize,
    actor_id: u64,
    links: &mut ActorLinks,
    shutdown: &AtomicBool,
    report: &mut dyn FnMut(&ActorEpisode),
) -> Result<u64, FleetError> {
    let px = actor.image_len();
    if env.spec().obs_dim() < px {
        return Err(FleetError::Actor {
            actor: actor_id,
            why: format!("the robot's observation has {} values, a frame needs {px}", env.spec().obs_dim()),
        });
    }
    let (act, default_design) = (env.spec().act_dim(), env.spec().default_design.clone());
    let mut worker = Planner { actor, env, steps, report, default_design, a_t: vec![0.0; act], frame: vec![0.0; px], z: Vec::new() };
    let cfg = ActorConfig { chunk_len: CHUNK_STEPS, exact_weights: true, record_eval: true, env_retries: 0 };
    let summary = coadapt_fleet::actor::run(&mut worker, actor_id, links, &cfg, shutdown)
        .map_err(|e| FleetError::Actor { actor: actor_id, why: e.to_string() })?;
    Ok(summary.episodes)
}

/// How one fleet episode went, as the learner saw it.
#[derive(Clone, Debug, PartialEq)]
pub struct FleetEpisode {
    pub episode_return: f32,
    pub steps: usize,
    /// The actor whose run was kept.
    pub actor: u64,
    /// Wall-clock seconds from the assignment to the episode's end, on the learner.
    pub seconds: f64,
    /// How often the episode went out again after a silent actor.
    pub reissued: u32,
}

/// An episode of the run, as the dispatcher names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Episode(u32);

impl std::fmt::Display for Episode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "episode {}", self.0)
    }
}

/// What an episode must look like: latent states and actions of the agent's widths, acted with
/// the weights just published.
struct LatentCheck {
    state_len: usize,
    act: usize,
    version: u64,
}

impl Check<Episode> for LatentCheck {
    fn chunk(&mut self, c: &ExperienceChunk) -> Result<(), String> {
        let (n, s, a) = (c.len(), self.state_len, self.act);
        if c.obs.len() != n * s || c.next_obs.len() != n * s || c.actions.len() != n * a || c.terminated.len() != n {
            return Err(format!("{n} rewards, {} state values, {} actions", c.obs.len(), c.actions.len()));
        }
        if c.weights_version != self.version {
            return Err(format!("acted with weights {}, not {}", c.weights_version, self.version));
        }
        Ok(())
    }

    fn episode(&mut self, d: &Done<Episode>) -> Verdict {
        if d.chunks.first().is_none_or(|c| !c.first) {
            return Verdict::Again("its first chunk is not marked first".into());
        }
        if d.end.length != d.steps as u64 || d.steps == 0 {
            return Verdict::Again(format!("{} steps, the end says {}", d.steps, d.end.length));
        }
        Verdict::Accept
    }
}

/// The learner's side of Alg. 3 through a fleet (see the module doc).
pub struct EpisodeRunner {
    links: LearnerLinks,
    dispatcher: Dispatcher<Episode>,
    version: u64,
    state_len: usize,
    act: usize,
    weights: Vec<f32>,
}

impl std::fmt::Debug for EpisodeRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EpisodeRunner").field("version", &self.version).field("state_len", &self.state_len).finish_non_exhaustive()
    }
}

impl EpisodeRunner {
    /// Episodes of at most `max_steps` steps on latent states of `state_len` values and
    /// `act` actions. An episode that sent nothing for two minutes goes out again; one not
    /// back within an hour fails (see the setters).
    pub fn new(links: LearnerLinks, state_len: usize, act: usize, max_steps: usize) -> Self {
        let cfg = DispatchConfig {
            lease: Duration::from_secs(120),
            deadline: Some(Duration::from_secs(3600)),
            max_steps,
            ..DispatchConfig::default()
        };
        Self { links, dispatcher: Dispatcher::new("latent fleet", cfg), version: 0, state_len, act, weights: Vec::new() }
    }

    /// An episode that sent nothing for `lease` goes out again (to whichever actor is free).
    pub fn set_lease(&mut self, lease: Duration) {
        self.dispatcher.cfg.lease = lease;
    }

    /// An episode not back `deadline` after it went out fails.
    pub fn set_deadline(&mut self, deadline: Duration) {
        self.dispatcher.cfg.deadline = Some(deadline);
    }

    /// Asked while waiting: `Some(why)` gives up (every actor process gone).
    pub fn set_abort(&mut self, abort: Box<dyn Fn() -> Option<String> + Send + Sync>) {
        self.dispatcher.abort = Some(abort);
    }

    /// Runs one episode of `agent`'s current networks on an actor: exploring and stored in the
    /// agent's replay (`train`), or deterministic. `index` names it in the assignment.
    pub fn episode(&mut self, agent: &mut LatentAgent, train: bool, seed: u64, index: u32) -> Result<FleetEpisode, FleetError> {
        agent.acting_weights(&mut self.weights);
        self.version += 1;
        let w = Weights { version: self.version, policy: std::mem::take(&mut self.weights), q1: vec![], q2: vec![], heads: vec![] };
        self.links.acting_weights.publish(w)?;
        let mode = if train { EpisodeMode::Train } else { EpisodeMode::Eval };
        let job = Job { design_index: index, design: vec![], mode, seed, min_weights_version: self.version };
        // What a failed episode left out is not waited for.
        self.dispatcher.forget_all();
        self.dispatcher.issue(&mut self.links, job, Episode(index))?;
        let mut check = LatentCheck { state_len: self.state_len, act: self.act, version: self.version };
        let never = AtomicBool::new(false);
        let Some(done) = self.dispatcher.next_done(&mut self.links, &never, &mut check)? else {
            return Err(FleetError::Learner(format!("episode {index}: stopped")));
        };
        let (s, a) = (self.state_len, self.act);
        let mut ret = 0.0f32;
        for c in &done.chunks {
            for i in 0..c.len() {
                ret += c.rewards[i];
                if train {
                    agent
                        .store(
                            &c.obs[i * s..(i + 1) * s],
                            &c.actions[i * a..(i + 1) * a],
                            c.rewards[i],
                            &c.next_obs[i * s..(i + 1) * s],
                            c.terminated[i],
                        )
                        .map_err(|e| FleetError::Learner(format!("storing episode {index}: {e}")))?;
                }
            }
        }
        if done.reissued > 0 {
            coadapt_log::logln!("latent fleet: episode {index} went out {} more time(s)", done.reissued);
        }
        Ok(FleetEpisode { episode_return: ret, steps: done.steps, actor: done.actor, seconds: done.seconds, reissued: done.reissued })
    }
}
