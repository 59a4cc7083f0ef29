//! The learner role of a co-adaptation (thesis Algorithm 4): it owns the FEAR schedule. For
//! each design it asks the design optimiser for a body (or takes a fixed initial one), hands
//! the actors one episode at a time, learns from the experience they stream back, evaluates
//! the deterministic policy, and records everything in the run directory.
//!
//! The schedule is lock-step, the reference's: collect one episode, then train on it, so a
//! seed reproduces a run whatever the number of actors (more actors only add evaluation
//! capacity here; parallel collection with a rate limiter is the fleet's business).
//! Designs: `initial-designs` fixed ones with `initial-episodes` each, then
//! `episodes-per-design` for each later one, alternating exploitation and exploration
//! (`alternate = false`: every later design is an exploitation).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::{EnvSpec, Transition};
use coadapt_transport::messages::Dims;
use coadapt_transport::{Assignment, DesignKind, DesignRequest, EpisodeEnd, EpisodeMode, LearnerLinks, TransportError, Validate, Weights};
use serde::{Deserialize, Serialize};

use crate::fear::{ActingPolicy, FearLearner, FearLearnerConfig};
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
    /// Fail when an actor sends nothing for this long (seconds).
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
    population_version: u64,
    next_assignment: u64,
    seed: u64,
}

/// Episode outcome from the actors, or `None` on shutdown.
type Collected = Option<EpisodeEnd>;

impl Learner<'_> {
    fn publish_acting(&mut self, which: ActingPolicy) -> Result<u64, CoadaptError> {
        self.acting_version += 1;
        let policy = self.fear.agent(which).policy_params().to_vec();
        self.links.acting_weights.publish(Weights { version: self.acting_version, policy, q1: vec![], q2: vec![] })?;
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

    /// Runs one episode on an actor; training episodes go into the replay buffers.
    fn episode(&mut self, design_index: usize, design: &[f32], mode: EpisodeMode, global: u64) -> Result<Collected, CoadaptError> {
        let which = self.fear.acting();
        let version = self.publish_acting(which)?;
        self.next_assignment += 1;
        let id = self.next_assignment;
        let seed = mix(self.seed, 2 * global + u64::from(mode == EpisodeMode::Eval));
        let a = Assignment { id, design_index: design_index as u32, design: design.to_vec(), mode, seed, min_weights_version: version };
        self.links.assignments.send(a)?;
        // `run` has checked the field; an unrepresentable value cannot reach here.
        let timeout = Duration::try_from_secs_f64(self.cfg.episode_timeout_secs.max(1.0)).unwrap_or(Duration::from_secs(600));
        let mut last = Instant::now();
        loop {
            if self.shutdown.load(Ordering::Relaxed) {
                return Ok(None);
            }
            let Some(chunk) = self.links.experience.recv_timeout(POLL)? else {
                if last.elapsed() > timeout {
                    return Err(CoadaptError::Protocol(format!("no experience for assignment {id} within {timeout:?}")));
                }
                continue;
            };
            last = Instant::now();
            if chunk.assignment != id {
                eprintln!("learner: dropped a chunk of assignment {} while waiting for {id}", chunk.assignment);
                continue;
            }
            if let Err(e) = chunk.validate(&self.dims) {
                eprintln!("learner: dropped a malformed chunk of assignment {id}: {e}");
                continue;
            }
            if mode == EpisodeMode::Train {
                let (o, a) = (self.dims.obs, self.dims.act);
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
            if let Some(end) = chunk.end {
                return Ok(Some(end));
            }
        }
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
        loop {
            if self.shutdown.load(Ordering::Relaxed) {
                return Ok(None);
            }
            let Some(reply) = self.links.design_replies.recv_timeout(POLL)? else { continue };
            if reply.index as usize != index {
                eprintln!("learner: ignored a reply for design {} while waiting for {index}", reply.index);
                continue;
            }
            if let Err(e) = reply.validate(&self.dims) {
                return Err(CoadaptError::Protocol(format!("the optimiser's design {index} is malformed: {e}")));
            }
            return Ok(Some(reply));
        }
    }
}

/// Runs the whole co-adaptation. `initial` replaces an empty `initial-designs`.
pub fn run(
    cfg: &ScheduleConfig,
    fear_cfg: &FearLearnerConfig,
    spec: &EnvSpec,
    seed: u64,
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
    let mut l = Learner { cfg, dims, links, shutdown, fear, acting_version: 0, population_version: 0, next_assignment: 0, seed };
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
        let n = cfg.episodes_of(index);
        let mut interrupted = false;
        for e in 0..n {
            let design = row.design.clone();
            let Some(end) = l.episode(index, &design, EpisodeMode::Train, global)? else {
                interrupted = true;
                break;
            };
            steps += end.length;
            let version = l.acting_version;
            l.fear.end_episode()?;
            let eval = cfg.eval_every > 0 && (e + 1) % cfg.eval_every == 0 || e + 1 == n;
            let eval_return = if eval {
                match l.episode(index, &design, EpisodeMode::Eval, global)? {
                    Some(end) => Some(end.episode_return),
                    None => {
                        interrupted = true;
                        None
                    }
                }
            } else {
                None
            };
            row.episodes += 1;
            if let Some(r) = eval_return {
                row.last_eval_return = Some(r);
                row.best_eval_return = Some(row.best_eval_return.map_or(r, |b| b.max(r)));
            }
            let ep = EpisodeRow {
                design: index,
                episode: e,
                global_episode: global as usize,
                steps,
                train_return: end.episode_return,
                eval_return,
                weights_version: version,
                seconds: start.elapsed().as_secs_f64(),
            };
            out.episode(&ep)?;
            on_event(&RunEvent::Episode { row: &ep, episodes_in_design: n });
            global += 1;
            if interrupted {
                break;
            }
        }
        out.design(&row)?;
        l.fear.agent(ActingPolicy::Population).save(&out.checkpoint_path("population"))?;
        l.fear.agent(ActingPolicy::Individual).save(&out.checkpoint_path("individual"))?;
        on_event(&RunEvent::DesignEnd { row: &row });
        rows.push(row);
        if interrupted || shutdown.load(Ordering::Relaxed) {
            return Ok(RunOutcome { learner: l.fear, designs: rows, interrupted: true });
        }
    }
    let interrupted = rows.len() < cfg.designs;
    Ok(RunOutcome { learner: l.fear, designs: rows, interrupted })
}
