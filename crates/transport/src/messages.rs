//! The messages of a co-adaptation, as plain domain types.
//!
//! Network weights travel as one flat `f32` buffer per network (PyTorch's
//! `parameters_to_vector` order), so a broadcast is one copy, never a per-layer serialisation.
//! Every message validates itself ([`Validate`]) against the dimensions the receiver expects;
//! a transport that crosses a process boundary calls it before handing a message over.

use crate::traits::Versioned;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MessageError {
    #[error("{field}: {why}")]
    Field { field: &'static str, why: String },
}

fn field(field: &'static str, why: impl Into<String>) -> MessageError {
    MessageError::Field { field, why: why.into() }
}

fn finite(name: &'static str, v: &[f32]) -> Result<(), MessageError> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(field(name, format!("value {i} is {}", v[i]))),
        None => Ok(()),
    }
}

fn len(name: &'static str, v: &[f32], expected: usize) -> Result<(), MessageError> {
    if v.len() == expected { Ok(()) } else { Err(field(name, format!("{} values, expected {expected}", v.len()))) }
}

/// The dimensions a receiver expects; messages are checked against them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dims {
    pub obs: usize,
    pub act: usize,
    pub design: usize,
}

/// What can check itself against the expected dimensions.
pub trait Validate {
    fn validate(&self, dims: &Dims) -> Result<(), MessageError>;
}

/// Versioned network weights: the policy, and for the design optimiser the twin critics
/// and any ensemble heads (empty for actors, which only act).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Weights {
    pub version: u64,
    pub policy: Vec<f32>,
    pub q1: Vec<f32>,
    pub q2: Vec<f32>,
    /// Critics beyond the twin, each shaped as `q1` (`learner.population-critics`).
    pub heads: Vec<Vec<f32>>,
}

impl Versioned for Weights {
    fn version(&self) -> u64 {
        self.version
    }
}

impl Validate for Weights {
    fn validate(&self, _: &Dims) -> Result<(), MessageError> {
        if self.policy.is_empty() {
            return Err(field("policy", "no values"));
        }
        if self.q1.len() != self.q2.len() {
            return Err(field("q2", format!("{} values but q1 has {}", self.q2.len(), self.q1.len())));
        }
        if let Some(i) = self.heads.iter().position(|h| h.len() != self.q1.len()) {
            return Err(field("heads", format!("head {} has {} values but q1 has {}", i + 1, self.heads[i].len(), self.q1.len())));
        }
        finite("policy", &self.policy)?;
        finite("q1", &self.q1)?;
        finite("q2", &self.q2)?;
        self.heads.iter().try_for_each(|h| finite("heads", h))
    }
}

/// Whether an episode explores and is learned from, or evaluates the deterministic policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EpisodeMode {
    Train,
    Eval,
}

/// One episode for an actor to run.
#[derive(Clone, Debug, PartialEq)]
pub struct Assignment {
    /// Unique per run; experience chunks carry it back.
    pub id: u64,
    pub design_index: u32,
    pub design: Vec<f32>,
    pub mode: EpisodeMode,
    /// Seeds the episode's reset (same seed, same start).
    pub seed: u64,
    /// Act with weights of at least this version (lock-step: exactly the newest).
    pub min_weights_version: u64,
}

impl Validate for Assignment {
    fn validate(&self, dims: &Dims) -> Result<(), MessageError> {
        len("design", &self.design, dims.design)?;
        finite("design", &self.design)
    }
}

/// How an episode ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeEnd {
    pub episode_return: f32,
    pub length: u64,
}

/// Consecutive transitions of one episode, column-wise (`n` rows each).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExperienceChunk {
    /// The actor that ran the episode (for policy lag and liveness).
    pub actor: u64,
    pub assignment: u64,
    pub design_index: u32,
    /// Weights version the transitions were acted with.
    pub weights_version: u64,
    /// This chunk starts the episode (its first `obs` row is the start state).
    pub first: bool,
    pub obs: Vec<f32>,
    pub actions: Vec<f32>,
    pub rewards: Vec<f32>,
    pub next_obs: Vec<f32>,
    pub terminated: Vec<bool>,
    /// Set on the episode's last chunk.
    pub end: Option<EpisodeEnd>,
}

impl ExperienceChunk {
    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }

    pub fn clear(&mut self) {
        self.obs.clear();
        self.actions.clear();
        self.rewards.clear();
        self.next_obs.clear();
        self.terminated.clear();
        self.first = false;
        self.end = None;
    }
}

impl Validate for ExperienceChunk {
    fn validate(&self, dims: &Dims) -> Result<(), MessageError> {
        let n = self.rewards.len();
        len("obs", &self.obs, n * dims.obs)?;
        len("actions", &self.actions, n * dims.act)?;
        len("next_obs", &self.next_obs, n * dims.obs)?;
        if self.terminated.len() != n {
            return Err(field("terminated", format!("{} flags for {n} rewards", self.terminated.len())));
        }
        if self.first && n == 0 {
            return Err(field("first", "a first chunk needs the start state"));
        }
        finite("obs", &self.obs)?;
        finite("actions", &self.actions)?;
        finite("rewards", &self.rewards)?;
        finite("next_obs", &self.next_obs)?;
        if let Some(end) = self.end
            && !end.episode_return.is_finite()
        {
            return Err(field("end.episode_return", format!("{}", end.episode_return)));
        }
        Ok(())
    }
}

/// Why the learner wants a new design.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DesignKind {
    /// The best design by the optimiser's method (PSO over Q, a simulation baseline, ...).
    Exploit,
    /// An exploratory design (uniform random or novelty search).
    Explore,
}

/// The learner asks the optimiser for design `index`.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignRequest {
    pub index: u32,
    pub kind: DesignKind,
    /// Score with population weights of at least this version.
    pub weights_version: u64,
    /// Start states for Eq. 5.6 (`n x obs`, their design columns are replaced).
    pub start_states: Vec<f32>,
    /// Every design chosen so far (`k x design`), for novelty search.
    pub chosen: Vec<f32>,
    /// Every design an operator rejected as a prototype so far in the run (`k x design`): the
    /// optimiser proposes none within `optimizer.reject-radius` of them.
    pub rejected: Vec<f32>,
}

impl Validate for DesignRequest {
    fn validate(&self, dims: &Dims) -> Result<(), MessageError> {
        if self.start_states.is_empty() || !self.start_states.len().is_multiple_of(dims.obs) {
            return Err(field("start_states", format!("{} values is not a positive multiple of {}", self.start_states.len(), dims.obs)));
        }
        if !self.chosen.len().is_multiple_of(dims.design) {
            return Err(field("chosen", format!("{} values is not a multiple of {}", self.chosen.len(), dims.design)));
        }
        if !self.rejected.len().is_multiple_of(dims.design) {
            return Err(field("rejected", format!("{} values is not a multiple of {}", self.rejected.len(), dims.design)));
        }
        finite("start_states", &self.start_states)?;
        finite("chosen", &self.chosen)?;
        finite("rejected", &self.rejected)
    }
}

/// The optimiser's answer.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignReply {
    pub index: u32,
    pub design: Vec<f32>,
    /// How it was chosen: `exploit`, `explore`, `random`, `sim-pso`, ... (free text for
    /// `designs.csv`).
    pub method: String,
    /// Eq. 5.6 at the chosen design under the population networks.
    pub predicted_objective: Option<f32>,
    /// Rollouts in simulation spent choosing it (zero for FEAR).
    pub design_rollouts: u64,
}

impl Validate for DesignReply {
    fn validate(&self, dims: &Dims) -> Result<(), MessageError> {
        len("design", &self.design, dims.design)?;
        finite("design", &self.design)?;
        if let Some(p) = self.predicted_objective
            && !p.is_finite()
        {
            return Err(field("predicted_objective", format!("{p}")));
        }
        // The method's name goes into designs.csv and progress lines: a short word, nothing
        // that could forge a row or a line.
        let ok = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '+');
        if self.method.is_empty() || self.method.len() > MAX_METHOD_LEN || !self.method.chars().all(ok) {
            return Err(field(
                "method",
                format!(
                    "{:?} is not 1 to {MAX_METHOD_LEN} letters, digits, '-', '_', '.' or '+'",
                    self.method.chars().take(80).collect::<String>()
                ),
            ));
        }
        Ok(())
    }
}

/// Longest name of a design method in a reply.
pub const MAX_METHOD_LEN: usize = 64;
