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
//! [`EpisodeRunner`], waits for the whole episode, hands an episode that went silent to
//! another actor after a lease, and only then stores the transitions: a half-run episode never
//! reaches the replay.
//!
//! With the same weights and seeds a fleet's planned episodes equal the in-process agent's
//! bit for bit (tested); OU noise is drawn by the actor from its own stream.

use std::collections::HashMap;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use coadapt_core::Env;
use coadapt_transport::messages::{Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, Weights};
use coadapt_transport::{ActorLinks, LearnerLinks, TransportError, newest_or_stop, next_or_stop};

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
    let fail = |why: String| FleetError::Actor { actor: actor_id, why };
    let px = actor.image_len();
    let act = env.spec().act_dim();
    if env.spec().obs_dim() < px {
        return Err(fail(format!("the robot's observation has {} values, a frame needs {px}", env.spec().obs_dim())));
    }
    let default_design = env.spec().default_design.clone();
    let mut held = None;
    let mut done = 0u64;
    let mut a_t = vec![0.0; act];
    let mut frame = vec![0.0; px];
    while let Some(asg) = next_or_stop(links.assignments.as_mut(), shutdown)? {
        let Some(w) = newest_or_stop(links.weights.as_mut(), asg.min_weights_version, shutdown)? else { break };
        if w.version != asg.min_weights_version {
            continue;
        }
        if held != Some(w.version) {
            actor.set_weights(&w.policy).map_err(|e| fail(e.to_string()))?;
            held = Some(w.version);
        }
        let train = asg.mode == EpisodeMode::Train;
        let design = if asg.design.is_empty() { &default_design } else { &asg.design };
        let t0 = Instant::now();
        let mut chunk = ExperienceChunk {
            actor: actor_id,
            assignment: asg.id,
            design_index: asg.design_index,
            weights_version: w.version,
            first: true,
            ..ExperienceChunk::default()
        };
        let mut out = ActorEpisode { assignment: asg.id, train, ..ActorEpisode::default() };
        let obs = env.reset(asg.seed, design).map_err(|e| fail(format!("reset: {e}")))?;
        let Some(f) = obs.get(..px) else {
            return Err(fail(format!("reset: the observation has {} values, a frame needs {px}", obs.len())));
        };
        frame.copy_from_slice(f);
        let mut z = actor.reset(&frame).to_vec();
        for t in 0..steps {
            let start = Instant::now();
            if actor.act(train, &mut a_t).is_some() {
                out.plan_ms.push(start.elapsed().as_secs_f64() * 1e3);
            }
            let s = env.step(&a_t).map_err(|e| fail(format!("step {t}: {e}")))?;
            let (r, term, trunc) = (s.reward, s.terminated, s.truncated);
            let Some(f) = s.observation.get(..px) else {
                return Err(fail(format!("step {t}: the observation has {} values, a frame needs {px}", s.observation.len())));
            };
            frame.copy_from_slice(f);
            let next = actor.observe(&frame);
            chunk.obs.extend_from_slice(&z);
            chunk.actions.extend_from_slice(&a_t);
            chunk.rewards.push(r);
            chunk.next_obs.extend_from_slice(next);
            chunk.terminated.push(term);
            z.copy_from_slice(next);
            out.episode_return += r;
            out.steps += 1;
            let last = term || trunc || t + 1 == steps;
            if last {
                chunk.end = Some(EpisodeEnd { episode_return: out.episode_return, length: out.steps as u64 });
            }
            if last || chunk.len() >= CHUNK_STEPS {
                match links.experience.send(chunk.clone()) {
                    Ok(()) => {}
                    Err(TransportError::Closed) => return Ok(done),
                    Err(e) => return Err(e.into()),
                }
                chunk.clear();
            }
            if last {
                break;
            }
        }
        out.seconds = t0.elapsed().as_secs_f64();
        report(&out);
        done += 1;
    }
    Ok(done)
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

/// One copy of an episode that is out.
struct Out {
    heard: Instant,
    chunks: Vec<ExperienceChunk>,
    steps: usize,
}

/// The learner's side of Alg. 3 through a fleet (see the module doc).
pub struct EpisodeRunner {
    links: LearnerLinks,
    version: u64,
    next_id: u64,
    state_len: usize,
    act: usize,
    max_steps: usize,
    weights: Vec<f32>,
    /// An episode that sent nothing for this long goes out again (to whichever actor is free).
    pub lease: Duration,
    /// An episode that has not come back by then fails.
    pub deadline: Duration,
    /// Asked while waiting: `Some(why)` gives up (every actor process gone).
    pub abort: Option<Box<dyn Fn() -> Option<String> + Send>>,
}

impl std::fmt::Debug for EpisodeRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EpisodeRunner").field("version", &self.version).field("state_len", &self.state_len).finish_non_exhaustive()
    }
}

impl EpisodeRunner {
    /// Episodes of at most `max_steps` steps on latent states of `state_len` values and
    /// `act` actions.
    pub fn new(links: LearnerLinks, state_len: usize, act: usize, max_steps: usize) -> Self {
        Self {
            links,
            version: 0,
            next_id: 0,
            state_len,
            act,
            max_steps,
            weights: Vec::new(),
            lease: Duration::from_secs(120),
            deadline: Duration::from_secs(3600),
            abort: None,
        }
    }

    fn assignment(&mut self, index: u32, train: bool, seed: u64) -> Assignment {
        self.next_id += 1;
        Assignment {
            id: self.next_id,
            design_index: index,
            design: vec![],
            mode: if train { EpisodeMode::Train } else { EpisodeMode::Eval },
            seed,
            min_weights_version: self.version,
        }
    }

    /// Whether `chunks` form one whole, well-shaped episode of the current version.
    fn check(&self, chunks: &[ExperienceChunk]) -> Result<(), String> {
        let (s, a) = (self.state_len, self.act);
        let mut steps = 0;
        for (i, c) in chunks.iter().enumerate() {
            let n = c.len();
            if c.obs.len() != n * s || c.next_obs.len() != n * s || c.actions.len() != n * a || c.terminated.len() != n {
                return Err(format!("chunk {i} is malformed ({n} rewards, {} state values, {} actions)", c.obs.len(), c.actions.len()));
            }
            if c.first != (i == 0) {
                return Err(format!("chunk {i}: first = {}", c.first));
            }
            if c.weights_version != self.version {
                return Err(format!("chunk {i} acted with weights {}, not {}", c.weights_version, self.version));
            }
            steps += n;
        }
        let end = chunks.last().and_then(|c| c.end).ok_or("no end")?;
        if end.length != steps as u64 || steps == 0 || steps > self.max_steps {
            return Err(format!("{steps} steps, the end says {} (at most {})", end.length, self.max_steps));
        }
        Ok(())
    }

    /// Runs one episode of `agent`'s current networks on an actor: exploring and stored in the
    /// agent's replay (`train`), or deterministic. `index` names it in the assignment.
    pub fn episode(&mut self, agent: &mut LatentAgent, train: bool, seed: u64, index: u32) -> Result<FleetEpisode, FleetError> {
        agent.acting_weights(&mut self.weights);
        self.version += 1;
        let w = Weights { version: self.version, policy: std::mem::take(&mut self.weights), q1: vec![], q2: vec![] };
        self.links.acting_weights.publish(w)?;
        let first = self.assignment(index, train, seed);
        let started = Instant::now();
        let mut out: HashMap<u64, Out> = HashMap::new();
        out.insert(first.id, Out { heard: Instant::now(), chunks: Vec::new(), steps: 0 });
        self.links.assignments.send(first)?;
        let mut reissued = 0u32;
        loop {
            if let Some(why) = self.abort.as_ref().and_then(|f| f()) {
                return Err(FleetError::Learner(why));
            }
            if started.elapsed() > self.deadline {
                return Err(FleetError::Learner(format!("episode {index} not back after {:?}: are the actors running?", self.deadline)));
            }
            // A silent copy goes out again under a new id; its late chunks are ignored.
            let silent: Vec<u64> = out.iter().filter(|(_, o)| o.heard.elapsed() > self.lease).map(|(id, _)| *id).collect();
            for id in silent {
                out.remove(&id);
                let again = self.assignment(index, train, seed);
                out.insert(again.id, Out { heard: Instant::now(), chunks: Vec::new(), steps: 0 });
                self.links.assignments.send(again)?;
                reissued += 1;
            }
            let Some(chunk) = self.links.experience.recv_timeout(Duration::from_millis(100))? else { continue };
            let id = chunk.assignment;
            let Some(o) = out.get_mut(&id) else { continue };
            o.heard = Instant::now();
            o.steps += chunk.len();
            let actor = chunk.actor;
            let ended = chunk.end.is_some();
            o.chunks.push(chunk);
            if o.steps > self.max_steps || ended {
                let Some(o) = out.remove(&id) else { continue };
                if let Err(why) = self.check(&o.chunks) {
                    coadapt_log::logln!("latent fleet: episode {index} from actor {actor} refused ({why}); it goes out again");
                    let again = self.assignment(index, train, seed);
                    out.insert(again.id, Out { heard: Instant::now(), chunks: Vec::new(), steps: 0 });
                    self.links.assignments.send(again)?;
                    reissued += 1;
                    continue;
                }
                let (s, a) = (self.state_len, self.act);
                let mut ret = 0.0f32;
                for c in &o.chunks {
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
                if reissued > 0 {
                    coadapt_log::logln!("latent fleet: episode {index} went out {reissued} more time(s) after {:?} of silence", self.lease);
                }
                return Ok(FleetEpisode { episode_return: ret, steps: o.steps, actor, seconds: started.elapsed().as_secs_f64(), reissued });
            }
        }
    }
}
