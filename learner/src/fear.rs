//! The FEAR learner (thesis Algorithm 4): population and individual SAC networks, their replay
//! buffers and the per-episode training schedule.
//!
//! - The *population* pair (pi_pop, Q_pop) trains on all experience (`Replay_pop`) and is what
//!   the design optimiser scores designs with.
//! - The *individual* pair trains mostly on the current design (`Replay_indvd`, emptied at each
//!   new design), with a batch mixing `population-batch` population samples into
//!   `species-batch` species samples (26 + 230 = 256 by default).
//! - At each new design the individual networks are copied from the population ones with fresh
//!   Adam state. The first `warmup-episodes` episodes of a design act with the population policy
//!   and train nothing; after every later episode the individual pair takes
//!   `individual-updates` steps and, from design `population-updates-from-design` on, the
//!   population pair takes `population-updates` steps.
//! - Every episode's first observation goes to `Replay_s0`, from which the optimiser draws the
//!   start-state batch of Eq. 5.6.

use coadapt_core::{Batch, ReplayBuffer, ReplayError, Rng64, Transition, rng};
use coadapt_nn::NnError;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::snapshot::{SnapshotError, StateIn, StateOut};
use crate::{Sac, SacConfig, SacLosses};

/// FEAR's learner settings; defaults are the reference's (DESIGN.md section 2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct FearLearnerConfig {
    /// SAC settings of both network pairs (`batch-size` is ignored: see the two batch fields).
    pub sac: SacConfig,
    /// Population samples in each individual batch.
    pub population_batch: usize,
    /// Species (current design) samples in each individual batch.
    pub species_batch: usize,
    /// Individual updates after each training episode.
    pub individual_updates: usize,
    /// Population updates after each training episode (batch of `sac.batch-size` from the
    /// population buffer).
    pub population_updates: usize,
    /// Zero-based index of the first design whose episodes also train the population networks.
    /// 3, the reference's `train_pop = design_counter > 3` with a counter from 1: the population
    /// pair trains from the fourth design on (with the five initial designs, on the last two
    /// of them before the first design is chosen over its critic).
    pub population_updates_from_design: usize,
    /// Episodes at the start of each design that act with the population policy and train
    /// nothing.
    pub warmup_episodes: usize,
    pub population_capacity: usize,
    pub species_capacity: usize,
    /// Start states kept for the design objective.
    pub start_state_capacity: usize,
    /// Train only the population networks and act with them (the thesis's Fig. 5.7 ablation).
    pub population_only: bool,
    /// Critics of the population pair: the twin (2, FEAR's) plus ensemble heads that regress on
    /// the twin's Bellman target from their own initialisations and change nothing the twin, the
    /// policy or an action does. The design optimiser's `q = "pessimistic"` scores a design by
    /// the mean minus `pessimism` sd over all of them, and the design service reports their
    /// disagreement (beyond the thesis: issue 28's ensemble lower confidence bound).
    pub population_critics: usize,
    /// `[learner.conservative]`: COMs' conservative term on the population pair's ensemble heads
    /// (beyond the thesis, issue 28; off by default; needs `population-critics` above 2), which
    /// the design optimiser's `q = "heads"` scores designs with: [`crate::conservative`].
    pub conservative: crate::conservative::ConservativeConfig,
    /// What a NaN or infinite loss or parameter does: `stop` the run (naming the update), or
    /// `roll-back` both network pairs (and their optimisers and generator) to where they were
    /// before the episode's updates, report it and go on; `max-rollbacks-in-a-row` roll-backs
    /// without a good episode between them stop the run.
    pub on_non_finite: OnNonFinite,
    pub max_rollbacks_in_a_row: usize,
}

/// See [`FearLearnerConfig::on_non_finite`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnNonFinite {
    #[default]
    Stop,
    RollBack,
}

impl Default for FearLearnerConfig {
    fn default() -> Self {
        Self {
            sac: SacConfig::default(),
            population_batch: 26,
            species_batch: 230,
            individual_updates: 1000,
            population_updates: 250,
            population_updates_from_design: 3,
            warmup_episodes: 3,
            population_capacity: 10_000_000,
            species_capacity: 1_000_000,
            start_state_capacity: 100_000,
            population_only: false,
            population_critics: 2,
            conservative: crate::conservative::ConservativeConfig::default(),
            on_non_finite: OnNonFinite::Stop,
            max_rollbacks_in_a_row: 5,
        }
    }
}

impl FearLearnerConfig {
    /// The settings that cannot work, named as a config file spells them.
    pub fn check(&self) -> Result<(), crate::ConfigError> {
        if self.population_critics < 2 {
            return Err(crate::ConfigError::TooFewCritics(self.population_critics));
        }
        self.conservative.check()?;
        if self.conservative.weight > 0.0 && self.population_critics == 2 {
            return Err(crate::ConfigError::Invalid(
                "learner.conservative.weight: the term trains the ensemble heads beyond the twin critics and this run has none; \
                 set learner.population-critics = 3 (one conservative head) and optimizer.q = \"heads\" to score designs with it"
                    .into(),
            ));
        }
        Ok(())
    }
}

/// Why an episode's training stopped.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// An update produced a NaN or infinite loss or parameter. The networks are left as they
    /// are, so nothing non-finite is published if the caller stops here.
    #[error(
        "the {pair} networks' update {update} (design {design}, episode {episode} of the design) produced a non-finite {what}; \
         the run stops rather than publish these weights (lower the learning rates or check the rewards)"
    )]
    NonFinite { pair: &'static str, update: u64, design: usize, episode: usize, what: String },
}

/// The first non-finite loss of `l`, named.
fn non_finite_loss(l: &SacLosses) -> Option<String> {
    [
        ("critic 1 loss", l.q1),
        ("critic 2 loss", l.q2),
        ("policy loss", l.policy),
        ("alpha loss", l.alpha),
        ("log pi", l.log_pi),
        ("ensemble heads' loss", l.heads),
        ("conservative gap", l.conservative_gap),
    ]
    .into_iter()
    .find(|(_, v)| !v.is_finite())
    .map(|(name, v)| format!("{name} ({v})"))
}

/// The first non-finite parameter of `sac`, named.
fn non_finite_param(sac: &Sac) -> Option<String> {
    let (t1, b1) = sac.critic_params(0);
    let (t2, b2) = sac.critic_params(1);
    [("policy", sac.policy_params()), ("critic 1", t1), ("critic 2", t2), ("target critic 1", b1), ("target critic 2", b2)]
        .into_iter()
        .find_map(|(name, p)| p.iter().position(|v| !v.is_finite()).map(|i| format!("{name} parameter {i} ({})", p[i])))
        .or_else(|| {
            (0..sac.extra_heads()).find_map(|h| {
                let p = sac.head_params(h);
                p.iter().position(|v| !v.is_finite()).map(|i| format!("ensemble head {} parameter {i} ({})", h + 1, p[i]))
            })
        })
        .or_else(|| (!sac.alpha().is_finite()).then(|| format!("alpha ({})", sac.alpha())))
}

/// The scalars of [`FearLearner::save_state`].
#[derive(Serialize, Deserialize)]
struct FearScalars {
    design_index: Option<usize>,
    episode_in_design: usize,
    #[serde(with = "crate::snapshot::bits::rng")]
    rng: Rng64,
}

/// Which network pair acts in the current episode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ActingPolicy {
    Population,
    Individual,
}

/// What one episode's training did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EpisodeTraining {
    pub individual_updates: usize,
    pub population_updates: usize,
    /// Losses of the last individual (or, population-only, population) update.
    pub last: Option<SacLosses>,
    /// Losses of the last population update (the conservative term's gap is watched there).
    pub last_population: Option<SacLosses>,
    /// The updates produced a non-finite value (named) and the networks were rolled back.
    pub rolled_back: Option<String>,
}

/// The learner's state across designs.
#[derive(Debug)]
pub struct FearLearner {
    pub cfg: FearLearnerConfig,
    population: Sac,
    individual: Sac,
    pop_replay: ReplayBuffer,
    species_replay: ReplayBuffer,
    start_states: ReplayBuffer,
    design_index: Option<usize>,
    episode_in_design: usize,
    ind_batch: Batch,
    pop_batch: Batch,
    rng: Rng64,
    rollbacks_in_a_row: usize,
}

impl FearLearner {
    pub fn new(obs_dim: usize, act_dim: usize, cfg: FearLearnerConfig, seed: u64) -> Result<Self, NnError> {
        let heads = cfg.population_critics.saturating_sub(2);
        let population = Sac::with_heads(obs_dim, act_dim, cfg.sac.clone(), seed, heads)?;
        let individual = Sac::new(obs_dim, act_dim, cfg.sac.clone(), seed.wrapping_add(1))?;
        Ok(Self {
            pop_replay: ReplayBuffer::new(obs_dim, act_dim, cfg.population_capacity),
            species_replay: ReplayBuffer::new(obs_dim, act_dim, cfg.species_capacity),
            // Start states reuse the buffer type; only `obs` matters.
            start_states: ReplayBuffer::new(obs_dim, 0, cfg.start_state_capacity),
            ind_batch: Batch::new(cfg.population_batch + cfg.species_batch, obs_dim, act_dim),
            pop_batch: Batch::new(cfg.sac.batch_size, obs_dim, act_dim),
            population,
            individual,
            design_index: None,
            episode_in_design: 0,
            rng: rng(seed, 4),
            rollbacks_in_a_row: 0,
            cfg,
        })
    }

    /// The design box of the robot (`low`, `high`, one bound per design coordinate; the
    /// observation is the state with the design appended): what the conservative term
    /// ([`FearLearnerConfig::conservative`]) searches over. With its weight above 0 the
    /// population pair's ensemble heads train with the term from here on; with 0 this changes
    /// nothing.
    pub fn set_design_box(&mut self, low: &[f32], high: &[f32]) {
        // The spec's observation is state then design (its conformance suite checks it), so the
        // design is the observation's last `low.len()` columns.
        let obs = self.pop_replay.obs_dim();
        debug_assert!(low.len() <= obs, "a design wider than the observation");
        let design = obs.saturating_sub(low.len())..obs;
        self.population.set_conservative(self.cfg.conservative.on_box(design, low, high));
    }

    /// Starts design `index`: the individual networks become copies of the population ones
    /// (fresh Adam state) and the species buffer is emptied.
    pub fn begin_design(&mut self, index: usize) {
        self.individual.copy_networks_from(&self.population);
        self.species_replay.clear();
        self.design_index = Some(index);
        self.episode_in_design = 0;
    }

    /// The policy the next episode acts with.
    pub fn acting(&self) -> ActingPolicy {
        if self.cfg.population_only || self.episode_in_design < self.cfg.warmup_episodes {
            ActingPolicy::Population
        } else {
            ActingPolicy::Individual
        }
    }

    /// The agent of `which` pair (for acting and for the design optimiser).
    pub fn agent(&self, which: ActingPolicy) -> &Sac {
        match which {
            ActingPolicy::Population => &self.population,
            ActingPolicy::Individual => &self.individual,
        }
    }

    pub fn agent_mut(&mut self, which: ActingPolicy) -> &mut Sac {
        match which {
            ActingPolicy::Population => &mut self.population,
            ActingPolicy::Individual => &mut self.individual,
        }
    }

    /// Stores one transition of the current design in both buffers.
    pub fn add_transition(&mut self, t: &Transition<'_>) -> Result<(), ReplayError> {
        self.pop_replay.push(t)?;
        self.species_replay.push(t)
    }

    /// Stores an episode's first observation for the design objective.
    pub fn add_start_state(&mut self, obs: &[f32]) -> Result<(), ReplayError> {
        self.start_states.push(&Transition { obs, action: &[], reward: 0.0, next_obs: obs, terminated: false })
    }

    pub fn start_states(&self) -> usize {
        self.start_states.len()
    }

    /// `n` start states drawn uniformly with replacement (`n x obs_dim`), or `None` if none.
    pub fn sample_start_states(&mut self, n: usize) -> Option<Vec<f32>> {
        if self.start_states.is_empty() {
            return None;
        }
        let mut out = Vec::with_capacity(n * self.start_states.obs_dim());
        for _ in 0..n {
            let i = self.rng.random_range(0..self.start_states.len());
            out.extend_from_slice(self.start_states.get(i).obs);
        }
        Some(out)
    }

    pub fn population_transitions(&self) -> usize {
        self.pop_replay.len()
    }

    /// Transitions of the current design in the species buffer.
    pub fn species_transitions(&self) -> usize {
        self.species_replay.len()
    }

    /// Ends an episode of the current design and trains as the schedule says. Every update's
    /// losses, and each pair's parameters after its updates, are checked for NaN and
    /// infinities ([`TrainError::NonFinite`] names the first and the update that made it);
    /// with `on-non-finite = "roll-back"` the networks return to their state before this
    /// episode's updates instead, and the result says so.
    pub fn end_episode(&mut self) -> Result<EpisodeTraining, TrainError> {
        if self.cfg.on_non_finite == OnNonFinite::Stop {
            return self.train_episode();
        }
        let saved = (self.population.clone(), self.individual.clone(), self.rng.clone());
        match self.train_episode() {
            Err(e @ TrainError::NonFinite { .. }) => {
                self.rollbacks_in_a_row += 1;
                if self.rollbacks_in_a_row > self.cfg.max_rollbacks_in_a_row {
                    return Err(e);
                }
                (self.population, self.individual, self.rng) = saved;
                Ok(EpisodeTraining { rolled_back: Some(e.to_string()), ..EpisodeTraining::default() })
            }
            other => {
                if other.is_ok() {
                    self.rollbacks_in_a_row = 0;
                }
                other
            }
        }
    }

    fn train_episode(&mut self) -> Result<EpisodeTraining, TrainError> {
        let episode = self.episode_in_design;
        let warm = self.episode_in_design < self.cfg.warmup_episodes;
        self.episode_in_design += 1;
        let mut out = EpisodeTraining::default();
        if warm {
            return Ok(out);
        }
        let design = self.design_index.unwrap_or(0);
        if !self.cfg.population_only {
            for _ in 0..self.cfg.individual_updates {
                let parts = [(&self.pop_replay, self.cfg.population_batch), (&self.species_replay, self.cfg.species_batch)];
                ReplayBuffer::sample_mixed(&parts, &mut self.rng, &mut self.ind_batch)?;
                let l = self.individual.update(&self.ind_batch);
                if let Some(what) = non_finite_loss(&l) {
                    return Err(TrainError::NonFinite { pair: "individual", update: self.individual.updates(), design, episode, what });
                }
                out.last = Some(l);
                out.individual_updates += 1;
            }
            if let Some(what) = non_finite_param(&self.individual) {
                return Err(TrainError::NonFinite { pair: "individual", update: self.individual.updates(), design, episode, what });
            }
        }
        if self.cfg.population_only || design >= self.cfg.population_updates_from_design {
            let n = if self.cfg.population_only { self.cfg.individual_updates } else { self.cfg.population_updates };
            for _ in 0..n {
                self.pop_replay.sample(&mut self.rng, &mut self.pop_batch)?;
                let l = self.population.update(&self.pop_batch);
                if let Some(what) = non_finite_loss(&l) {
                    return Err(TrainError::NonFinite { pair: "population", update: self.population.updates(), design, episode, what });
                }
                if self.cfg.population_only {
                    out.last = Some(l);
                }
                out.last_population = Some(l);
                out.population_updates += 1;
            }
            if let Some(what) = non_finite_param(&self.population) {
                return Err(TrainError::NonFinite { pair: "population", update: self.population.updates(), design, episode, what });
            }
        }
        Ok(out)
    }

    /// Writes both pairs, the three buffers, the schedule position and the generator.
    pub fn save_state(&self, out: &mut StateOut) -> std::io::Result<()> {
        self.population.save_state("population", out)?;
        self.individual.save_state("individual", out)?;
        for (name, buf) in
            [("replay.population", &self.pop_replay), ("replay.species", &self.species_replay), ("replay.start", &self.start_states)]
        {
            let (arrays, next) = buf.raw();
            for (part, a) in ["obs", "act", "rew", "next_obs", "done"].iter().zip(arrays) {
                out.f32s(&format!("{name}.{part}"), a)?;
            }
            out.put(&format!("{name}.next"), &next)?;
        }
        out.put("fear", &FearScalars { design_index: self.design_index, episode_in_design: self.episode_in_design, rng: self.rng.clone() })
    }

    /// Restores what [`Self::save_state`] wrote into a learner built with the same settings.
    pub fn load_state(&mut self, inp: &mut StateIn) -> Result<(), SnapshotError> {
        self.population.load_state("population", inp)?;
        self.individual.load_state("individual", inp)?;
        for (name, buf) in [
            ("replay.population", &mut self.pop_replay),
            ("replay.species", &mut self.species_replay),
            ("replay.start", &mut self.start_states),
        ] {
            let mut take = |part: &str| inp.f32s_any(&format!("{name}.{part}"));
            let arrays = [take("obs")?, take("act")?, take("rew")?, take("next_obs")?, take("done")?];
            let next: usize = inp.get(&format!("{name}.next"))?;
            buf.restore_raw(arrays, next).map_err(|e| SnapshotError::Mismatch(format!("{name}: {e}")))?;
        }
        let f: FearScalars = inp.get("fear")?;
        (self.design_index, self.episode_in_design, self.rng) = (f.design_index, f.episode_in_design, f.rng);
        Ok(())
    }

    /// Transfer (thesis section 6.1): the population networks (policy, both critics and their
    /// targets) from a checkpoint of another run with the same shapes ([`Sac::save`]); Adam's
    /// moments, alpha and the buffers stay this learner's. The first design copies them into
    /// the individual pair, as every design does.
    pub fn init_population(&mut self, networks: &std::path::Path) -> Result<(), NnError> {
        self.population.load(networks)
    }

    /// Transfer with experience: the population replay of another run's snapshot (its
    /// capacity must be this run's); returns the transitions taken.
    pub fn load_population_replay(&mut self, inp: &mut StateIn) -> Result<usize, SnapshotError> {
        let name = "replay.population";
        let mut take = |part: &str| inp.f32s_any(&format!("{name}.{part}"));
        let arrays = [take("obs")?, take("act")?, take("rew")?, take("next_obs")?, take("done")?];
        let next: usize = inp.get(&format!("{name}.next"))?;
        self.pop_replay.restore_raw(arrays, next).map_err(|e| SnapshotError::Mismatch(format!("{name}: {e}")))?;
        Ok(self.pop_replay.len())
    }

    /// `n` population updates on batches from the population buffer, outside the per-episode
    /// schedule (while the run waits for a prototype or a reset); checked for non-finite
    /// losses and parameters as [`Self::end_episode`] checks them. Returns the updates made: 0
    /// while the population buffer is empty.
    pub fn train_population(&mut self, n: usize) -> Result<usize, TrainError> {
        if self.pop_replay.is_empty() || n == 0 {
            return Ok(0);
        }
        let (design, episode) = (self.design_index.unwrap_or(0), self.episode_in_design);
        for _ in 0..n {
            self.pop_replay.sample(&mut self.rng, &mut self.pop_batch)?;
            let l = self.population.update(&self.pop_batch);
            if let Some(what) = non_finite_loss(&l) {
                return Err(TrainError::NonFinite { pair: "population", update: self.population.updates(), design, episode, what });
            }
        }
        if let Some(what) = non_finite_param(&self.population) {
            return Err(TrainError::NonFinite { pair: "population", update: self.population.updates(), design, episode, what });
        }
        Ok(n)
    }
}
