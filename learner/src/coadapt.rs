//! The learner role of a co-adaptation (thesis Algorithm 4): it owns the FEAR schedule. For
//! each design it asks the design optimiser for a body (or takes a fixed initial one), hands
//! the actors one episode at a time, learns from the experience they stream back, evaluates
//! the deterministic policy, and records everything in the run directory.
//!
//! How episodes are spread over the actors is [`crate::flow`]'s business: lock-step (the
//! reference: collect one episode, then train on it, so a seed reproduces a run whatever the
//! number of actors) or a window of episodes in flight; either way each training episode buys
//! the same updates.
//! Designs: `initial-designs` fixed ones with `initial-episodes` each, then
//! `episodes-per-design` for each later one, alternating exploitation and exploration
//! (`alternate = false`: every later design is an exploitation).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::{EnvSpec, Transition};
use coadapt_transport::messages::Dims;
use coadapt_transport::{Assignment, DesignKind, DesignRequest, EpisodeMode, LearnerLinks, TransportError, Validate, Weights};
use serde::{Deserialize, Serialize};

use crate::fear::{ActingPolicy, FearLearner, FearLearnerConfig};
use crate::flow::{Completed, FlowConfig, LearnerTime, Pending};
use crate::run_dir::{DesignRow, EpisodeRow, RunWriter};

/// The co-adaptation schedule; defaults are the reference's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct ScheduleConfig {
    /// Designs in the whole run, the initial ones included.
    pub designs: usize,
    /// The fixed designs the run starts with (empty: the robot's reference set; see
    /// `coadapt run --help`).
    pub initial_designs: Vec<Vec<f32>>,
    /// Episodes on each initial design.
    pub initial_episodes: usize,
    /// Episodes on each later design.
    pub episodes_per_design: usize,
    /// Alternate exploitation and exploration after the initial designs (false: exploit only).
    pub alternate: bool,
    /// Start states per design-objective evaluation (n of Eq. 5.6).
    pub start_state_batch: usize,
    /// Evaluate the deterministic policy after every this many episodes of a design (and
    /// always after its last); 0: only after the last.
    pub eval_every: usize,
    /// Fail when no actor has sent anything for this long (seconds): the fleet is gone.
    pub episode_timeout_secs: f64,
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        Self {
            designs: 50,
            initial_designs: Vec::new(),
            initial_episodes: 300,
            episodes_per_design: 100,
            alternate: true,
            start_state_batch: 32,
            eval_every: 1,
            episode_timeout_secs: 600.0,
        }
    }
}

impl ScheduleConfig {
    /// Episodes of design `i`.
    pub fn episodes_of(&self, i: usize) -> usize {
        if i < self.initial_designs.len() { self.initial_episodes } else { self.episodes_per_design }
    }

    pub fn total_episodes(&self) -> usize {
        (0..self.designs).map(|i| self.episodes_of(i)).sum()
    }

    /// The kind of design `i` (`None`: a fixed initial design).
    pub fn kind_of(&self, i: usize) -> Option<DesignKind> {
        let n = self.initial_designs.len();
        if i < n {
            None
        } else if self.alternate && (i - n) % 2 == 1 {
            Some(DesignKind::Explore)
        } else {
            Some(DesignKind::Exploit)
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CoadaptError {
    #[error("config: {0}")]
    Config(String),
    #[error("transport: {0}")]
    Transport(#[from] TransportError),
    #[error("{0}")]
    Protocol(String),
    #[error("replay: {0}")]
    Replay(#[from] coadapt_core::ReplayError),
    /// A non-finite update (the message names the pair, the update, the design and episode).
    #[error(transparent)]
    Train(#[from] crate::fear::TrainError),
    #[error("writing the run directory: {0}")]
    Io(#[from] std::io::Error),
    #[error("saving a checkpoint: {0}")]
    Checkpoint(#[from] coadapt_nn::NnError),
}

/// What the learner reports as it goes (for progress lines).
#[derive(Clone, Debug)]
pub enum RunEvent<'a> {
    DesignStart { index: usize, row: &'a DesignRow },
    Episode { row: &'a EpisodeRow, episodes_in_design: usize },
    DesignEnd { row: &'a DesignRow },
}

/// What a finished (or interrupted) run leaves.
#[derive(Debug)]
pub struct RunOutcome {
    pub learner: FearLearner,
    pub designs: Vec<DesignRow>,
    pub interrupted: bool,
    /// Where the learner's time went.
    pub time: LearnerTime,
}

fn mix(seed: u64, i: u64) -> u64 {
    let mut z = seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z ^ (z >> 27)
}

const POLL: Duration = Duration::from_millis(100);

struct Learner<'a> {
    cfg: &'a ScheduleConfig,
    dims: Dims,
    links: &'a mut LearnerLinks,
    shutdown: &'a AtomicBool,
    fear: FearLearner,
    acting_version: u64,
    /// The acting policy changed since it was last published.
    acting_dirty: bool,
    acting_which: Option<ActingPolicy>,
    population_version: u64,
    next_assignment: u64,
    seed: u64,
    lease: Duration,
    /// No message at all for this long fails the run (every actor gone).
    silence: Duration,
    pending: Vec<Pending>,
    time: LearnerTime,
}

impl Learner<'_> {
    /// Publishes the acting policy if it changed; returns the version actors must act with.
    fn publish_acting(&mut self) -> Result<u64, CoadaptError> {
        let which = self.fear.acting();
        if !self.acting_dirty && self.acting_which == Some(which) {
            return Ok(self.acting_version);
        }
        let t = Instant::now();
        self.acting_version += 1;
        let policy = self.fear.agent(which).policy_params().to_vec();
        self.links.acting_weights.publish(Weights { version: self.acting_version, policy, q1: vec![], q2: vec![] })?;
        self.acting_dirty = false;
        self.acting_which = Some(which);
        self.time.sending += t.elapsed().as_secs_f64();
        Ok(self.acting_version)
    }

    fn publish_population(&mut self) -> Result<u64, CoadaptError> {
        self.population_version += 1;
        let pop = self.fear.agent(ActingPolicy::Population);
        let w = Weights {
            version: self.population_version,
            policy: pop.policy_params().to_vec(),
            q1: pop.critic_params(0).0.to_vec(),
            q2: pop.critic_params(1).0.to_vec(),
        };
        self.links.population_weights.publish(w)?;
        Ok(self.population_version)
    }

    /// Hands episode `episode` of design `design_index` to the actors.
    fn issue(&mut self, design_index: usize, design: &[f32], episode: usize, global: u64, mode: EpisodeMode) -> Result<(), CoadaptError> {
        let version = self.publish_acting()?;
        let seed = mix(self.seed, 2 * global + u64::from(mode == EpisodeMode::Eval));
        self.send_assignment(
            design_index,
            design,
            Pending { id: 0, episode, global, mode, seed, min_weights_version: version, chunks: Vec::new(), last_heard: Instant::now() },
        )
    }

    fn send_assignment(&mut self, design_index: usize, design: &[f32], mut p: Pending) -> Result<(), CoadaptError> {
        let t = Instant::now();
        self.next_assignment += 1;
        p.id = self.next_assignment;
        p.last_heard = Instant::now();
        let a = Assignment {
            id: p.id,
            design_index: design_index as u32,
            design: design.to_vec(),
            mode: p.mode,
            seed: p.seed,
            min_weights_version: p.min_weights_version,
        };
        self.links.assignments.send(a)?;
        self.pending.push(p);
        self.time.sending += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Issues again every episode whose actor has fallen silent.
    fn reissue_expired(&mut self, design_index: usize, design: &[f32]) -> Result<(), CoadaptError> {
        while let Some(i) = self.pending.iter().position(|p| p.last_heard.elapsed() > self.lease) {
            let mut p = self.pending.swap_remove(i);
            let old = p.id;
            p.chunks.clear();
            self.send_assignment(design_index, design, p)?;
            self.time.reissued += 1;
            eprintln!(
                "learner: assignment {old} (design {design_index}) silent for {:?}: issued again as {}",
                self.lease, self.next_assignment
            );
        }
        Ok(())
    }

    /// Waits for the next episode to come back; `None` on shutdown.
    fn next_completed(&mut self, design_index: usize, design: &[f32]) -> Result<Option<Completed>, CoadaptError> {
        let mut heard = Instant::now();
        loop {
            if self.shutdown.load(Ordering::Relaxed) {
                return Ok(None);
            }
            // Every time round, not only when the queue is quiet: with many actors it rarely is.
            self.reissue_expired(design_index, design)?;
            let t = Instant::now();
            let got = match self.links.experience.recv_timeout(POLL) {
                Ok(got) => got,
                // Every actor has gone for now; restarted or new ones may join.
                Err(TransportError::Closed) => {
                    std::thread::sleep(POLL);
                    None
                }
                Err(e) => return Err(e.into()),
            };
            self.time.waiting += t.elapsed().as_secs_f64();
            let Some(chunk) = got else {
                if heard.elapsed() > self.silence {
                    return Err(CoadaptError::Protocol(format!(
                        "no actor has sent anything for {:?} ({} episodes outstanding): are the actors running?",
                        self.silence,
                        self.pending.len()
                    )));
                }
                continue;
            };
            heard = Instant::now();
            let Some(i) = self.pending.iter().position(|p| p.id == chunk.assignment) else {
                // A late chunk of an episode already issued again elsewhere.
                continue;
            };
            if let Err(e) = chunk.validate(&self.dims) {
                let p = self.pending.swap_remove(i);
                eprintln!("learner: a malformed chunk of assignment {} from actor {}: {e}; issuing the episode again", p.id, chunk.actor);
                self.send_assignment(design_index, design, Pending { chunks: Vec::new(), ..p })?;
                continue;
            }
            let p = &mut self.pending[i];
            p.last_heard = Instant::now();
            let end = chunk.end;
            if chunk.first && !p.chunks.is_empty() {
                // The actor ran the episode again from its start (the first attempt failed in
                // its environment): what that attempt sent is forgotten.
                eprintln!(
                    "learner: actor {} restarted assignment {}: dropping {} chunk(s) of its failed attempt",
                    chunk.actor,
                    p.id,
                    p.chunks.len()
                );
                p.chunks.clear();
                self.time.restarted += 1;
            }
            if !chunk.is_empty() || chunk.end.is_some() {
                p.chunks.push(chunk);
            }
            if let Some(end) = end {
                let p = self.pending.swap_remove(i);
                let last = p.chunks.last();
                let actor = last.map_or(0, |c| c.actor);
                let weights_version = p.chunks.iter().map(|c| c.weights_version).min().unwrap_or(p.min_weights_version);
                let policy_lag = self.acting_version.saturating_sub(weights_version);
                self.time.max_policy_lag = self.time.max_policy_lag.max(policy_lag);
                return Ok(Some(Completed {
                    episode: p.episode,
                    global: p.global,
                    mode: p.mode,
                    chunks: p.chunks,
                    end,
                    actor,
                    weights_version,
                    policy_lag,
                }));
            }
        }
    }

    /// Puts a finished training episode into the replay buffers and trains on it.
    fn learn_from(&mut self, c: &Completed) -> Result<(), CoadaptError> {
        let (o, a) = (self.dims.obs, self.dims.act);
        for chunk in &c.chunks {
            if chunk.first {
                self.fear.add_start_state(&chunk.obs[..o])?;
            }
            for i in 0..chunk.len() {
                self.fear.add_transition(&Transition {
                    obs: &chunk.obs[i * o..(i + 1) * o],
                    action: &chunk.actions[i * a..(i + 1) * a],
                    reward: chunk.rewards[i],
                    next_obs: &chunk.next_obs[i * o..(i + 1) * o],
                    terminated: chunk.terminated[i],
                })?;
            }
        }
        let t = Instant::now();
        self.fear.end_episode()?;
        self.time.training += t.elapsed().as_secs_f64();
        self.acting_dirty = true;
        Ok(())
    }

    fn request_design(
        &mut self,
        index: usize,
        kind: DesignKind,
        chosen: &[f32],
    ) -> Result<Option<coadapt_transport::DesignReply>, CoadaptError> {
        let version = self.publish_population()?;
        let start_states = self
            .fear
            .sample_start_states(self.cfg.start_state_batch.max(1))
            .ok_or_else(|| CoadaptError::Protocol("no start states yet: the run needs at least one initial design".into()))?;
        let req = DesignRequest { index: index as u32, kind, weights_version: version, start_states, chosen: chosen.to_vec() };
        self.links.design_requests.send(req)?;
        let t = Instant::now();
        let result = loop {
            if self.shutdown.load(Ordering::Relaxed) {
                break Ok(None);
            }
            let reply = match self.links.design_replies.recv_timeout(POLL) {
                Ok(Some(reply)) => reply,
                Ok(None) => continue,
                // The optimiser has gone; a restarted one answers the request it finds.
                Err(TransportError::Closed) => {
                    std::thread::sleep(POLL);
                    continue;
                }
                Err(e) => break Err(e.into()),
            };
            if reply.index as usize != index {
                eprintln!("learner: ignored a reply for design {} while waiting for {index}", reply.index);
                continue;
            }
            if let Err(e) = reply.validate(&self.dims) {
                break Err(CoadaptError::Protocol(format!("the optimiser's design {index} is malformed: {e}")));
            }
            break Ok(Some(reply));
        };
        self.time.waiting += t.elapsed().as_secs_f64();
        result
    }
}

/// Runs the whole co-adaptation. `initial` replaces an empty `initial-designs`.
pub fn run(
    cfg: &ScheduleConfig,
    fear_cfg: &FearLearnerConfig,
    spec: &EnvSpec,
    seed: u64,
    flow: &FlowConfig,
    actors: usize,
    links: &mut LearnerLinks,
    out: &mut RunWriter,
    shutdown: &AtomicBool,
    on_event: &mut dyn FnMut(&RunEvent<'_>),
) -> Result<RunOutcome, CoadaptError> {
    let dims = Dims { obs: spec.obs_dim(), act: spec.act_dim(), design: spec.design_dim() };
    if cfg.initial_designs.is_empty() {
        return Err(CoadaptError::Config("schedule.initial-designs: at least one initial design is needed".into()));
    }
    let t = cfg.episode_timeout_secs;
    if !(t.is_finite() && t > 0.0 && Duration::try_from_secs_f64(t).is_ok()) {
        return Err(CoadaptError::Config(format!("schedule.episode-timeout-secs: {t} is not a positive number of seconds")));
    }
    for (i, d) in cfg.initial_designs.iter().enumerate() {
        spec.design.check_finite("design", d).map_err(|e| CoadaptError::Config(format!("schedule.initial-designs[{i}]: {e}")))?;
    }
    let fear = FearLearner::new(dims.obs, dims.act, fear_cfg.clone(), seed).map_err(|e| CoadaptError::Config(e.to_string()))?;
    let lease = flow.lease().map_err(CoadaptError::Config)?;
    let in_flight = flow.in_flight(actors);
    let mut l = Learner {
        cfg,
        dims,
        links,
        shutdown,
        fear,
        acting_version: 0,
        acting_dirty: true,
        acting_which: None,
        population_version: 0,
        next_assignment: 0,
        seed,
        lease,
        silence: Duration::from_secs_f64(t),
        pending: Vec::new(),
        time: LearnerTime::default(),
    };
    let start = Instant::now();
    let mut rows: Vec<DesignRow> = Vec::new();
    let mut chosen: Vec<f32> = Vec::new();
    let (mut global, mut steps) = (0u64, 0u64);
    for index in 0..cfg.designs {
        let mut row = match cfg.kind_of(index) {
            None => DesignRow {
                index,
                kind: "initial".into(),
                design: cfg.initial_designs[index].clone(),
                episodes: 0,
                best_eval_return: None,
                last_eval_return: None,
                predicted_objective: None,
                design_rollouts: 0,
                method: "fixed".into(),
            },
            Some(kind) => {
                let Some(reply) = l.request_design(index, kind, &chosen)? else { break };
                DesignRow {
                    index,
                    kind: if kind == DesignKind::Exploit { "exploit" } else { "explore" }.into(),
                    design: reply.design,
                    episodes: 0,
                    best_eval_return: None,
                    last_eval_return: None,
                    predicted_objective: reply.predicted_objective,
                    design_rollouts: reply.design_rollouts,
                    method: reply.method,
                }
            }
        };
        chosen.extend_from_slice(&row.design);
        on_event(&RunEvent::DesignStart { index, row: &row });
        l.fear.begin_design(index);
        l.acting_dirty = true;
        let n = cfg.episodes_of(index);
        let design = row.design.clone();
        let base = global;
        let (mut issued, mut written) = (0usize, 0usize);
        // Training episodes back and trained on, waiting for their evaluation.
        let mut awaiting_eval: Vec<(Completed, u64)> = Vec::new();
        let mut interrupted = false;
        while written < n {
            while l.pending.len() < in_flight && issued < n {
                l.issue(index, &design, issued, base + issued as u64, EpisodeMode::Train)?;
                issued += 1;
            }
            let Some(c) = l.next_completed(index, &design)? else {
                interrupted = true;
                break;
            };
            let ((c, steps_then), eval_return) = match c.mode {
                EpisodeMode::Train => {
                    l.learn_from(&c)?;
                    steps += c.end.length;
                    let e = c.episode;
                    if cfg.eval_every > 0 && (e + 1) % cfg.eval_every == 0 || e + 1 == n {
                        l.issue(index, &design, e, c.global, EpisodeMode::Eval)?;
                        awaiting_eval.push((c, steps));
                        continue;
                    }
                    ((c, steps), None)
                }
                EpisodeMode::Eval => {
                    let Some(i) = awaiting_eval.iter().position(|(t, _)| t.episode == c.episode) else {
                        return Err(CoadaptError::Protocol(format!("an evaluation of episode {} nobody asked for", c.episode)));
                    };
                    (awaiting_eval.swap_remove(i), Some(c.end.episode_return))
                }
            };
            row.episodes += 1;
            if let Some(r) = eval_return {
                row.last_eval_return = Some(r);
                row.best_eval_return = Some(row.best_eval_return.map_or(r, |b| b.max(r)));
            }
            let ep = EpisodeRow {
                design: index,
                episode: c.episode,
                global_episode: c.global as usize,
                steps: steps_then,
                train_return: c.end.episode_return,
                eval_return,
                weights_version: c.weights_version,
                actor: c.actor,
                policy_lag: c.policy_lag,
                seconds: start.elapsed().as_secs_f64(),
            };
            out.episode(&ep)?;
            on_event(&RunEvent::Episode { row: &ep, episodes_in_design: n });
            written += 1;
            global += 1;
        }
        // An interrupted design drops what is still out; the actors' late chunks are ignored.
        l.pending.clear();
        out.design(&row)?;
        l.fear.agent(ActingPolicy::Population).save(&out.checkpoint_path("population"))?;
        l.fear.agent(ActingPolicy::Individual).save(&out.checkpoint_path("individual"))?;
        on_event(&RunEvent::DesignEnd { row: &row });
        rows.push(row);
        if interrupted || shutdown.load(Ordering::Relaxed) {
            return Ok(RunOutcome { learner: l.fear, designs: rows, interrupted: true, time: l.time });
        }
    }
    let interrupted = rows.len() < cfg.designs;
    Ok(RunOutcome { learner: l.fear, designs: rows, interrupted, time: l.time })
}
