//! The design optimiser's settings (`[optimizer]`): the methods, the objective's critic, and
//! each search's knobs. Defaults are the reference's.

use serde::{Deserialize, Serialize};

use crate::es::OpenAiEsConfig;
use crate::{CmaesConfig, NoveltyConfig, PsoConfig, QMode};

/// How exploitation designs are chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExploitMethod {
    #[default]
    PsoQ,
    CmaesQ,
    SimPso,
    SimCmaes,
    OpenaiEs,
    CmaesEs,
    Random,
    Screened,
}

impl ExploitMethod {
    pub fn name(self) -> &'static str {
        match self {
            Self::PsoQ => "pso-q",
            Self::CmaesQ => "cmaes-q",
            Self::SimPso => "sim-pso",
            Self::SimCmaes => "sim-cmaes",
            Self::OpenaiEs => "openai-es",
            Self::CmaesEs => "cmaes-es",
            Self::Random => "random",
            Self::Screened => "screened",
        }
    }

    pub fn needs_rollouts(self) -> bool {
        matches!(self, Self::SimPso | Self::SimCmaes | Self::OpenaiEs | Self::CmaesEs | Self::Screened)
    }
}

/// How exploration designs are chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExploreMethod {
    #[default]
    Random,
    Novelty,
}

/// Which critic scores Eq. 5.6.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum QModeConfig {
    /// Q1 alone, as the reference.
    #[default]
    Q1,
    /// min(Q1, Q2).
    MinOfTwin,
    /// The critics' mean minus `pessimism` times their standard deviation: a design objective
    /// that distrusts the critic where its heads disagree (beyond the thesis). The heads are the
    /// twin, and with `learner.population-critics` above 2 the ensemble heads too (a lower
    /// confidence bound over an ensemble).
    Pessimistic,
    /// The mean of the critics beyond the twin (`learner.population-critics` above 2): with
    /// `[learner.conservative]` on, critics trained to be low where their own ascent over
    /// designs goes, which score designs and act on nothing (beyond the thesis, after COMs).
    Heads,
}

impl QModeConfig {
    /// The objective's mode, with `pessimism` the k of `pessimistic`.
    pub fn mode(self, pessimism: f32) -> QMode {
        match self {
            QModeConfig::Q1 => QMode::First,
            QModeConfig::MinOfTwin => QMode::MinOfTwin,
            QModeConfig::Pessimistic => QMode::MeanMinusKStd(pessimism),
            QModeConfig::Heads => QMode::Heads,
        }
    }
}

/// The optimiser's settings; defaults are the reference's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct OptimizerConfig {
    /// `pso-q` (FEAR), `cmaes-q`, `sim-pso`, `sim-cmaes`, `openai-es`, `cmaes-es`, `random` or
    /// `screened` (PSO over Q proposes, short rollouts decide: `[optimizer.screen]`).
    pub exploit: ExploitMethod,
    /// `random` or `novelty`.
    pub explore: ExploreMethod,
    /// `q1` (the reference), `min-of-twin`, `pessimistic` or `heads`.
    pub q: QModeConfig,
    /// k of `q = "pessimistic"`: the objective is mean - k sd over the critics' heads.
    pub pessimism: f32,
    /// Cores for scoring the swarm over Q.
    pub cores: usize,
    /// PSO over Q (and novelty search's PSO).
    pub pso: PsoConfig,
    /// CMA-ES over Q.
    pub cmaes: CmaesConfig,
    pub novelty: NoveltyConfig,
    /// PSO over rollouts (35 x 30).
    pub sim_pso: PsoConfig,
    /// CMA-ES over rollouts (35 candidates x 30 generations by default, the sim-PSO budget).
    pub sim_cmaes: CmaesConfig,
    pub openai_es: OpenAiEsConfig,
    /// CMA-ES one generation per design (9 candidates).
    pub cmaes_es: CmaesConfig,
    /// What the ES baselines train on: `best-seen` (the best candidate of every generation so
    /// far, the thesis) or `generation-best` (the best of the generation just scored).
    pub es_train_on: EsTrainOn,
    /// Reset seeds of the simulation baselines' rollouts: `fresh` (one per rollout, the
    /// reference) or `fixed` (the same start for every candidate).
    pub sim_seed: SimSeed,
    /// How far (box-normalised Euclidean distance: each dimension divided by its width) a
    /// proposal must be from every design an operator rejected as a prototype; 0.05 = 5 % of
    /// the box.
    pub reject_radius: f32,
    /// The trust region of the searches over Q (`pso-q`, `cmaes-q`, `screened`): the radius
    /// (box-normalised distance) around the designs trained so far within which they look, at
    /// five designs; 0 (the default, the thesis) searches the whole box.
    pub trust_radius: f32,
    /// How the trust region widens: `r = trust-radius * (designs seen / 5)^trust-growth`.
    pub trust_growth: f32,
    /// `exploit = "screened"`: candidates, rollouts per candidate, steps per rollout, spacing.
    pub screen: crate::screen::ScreenConfig,
}

impl Default for OptimizerConfig {
    fn default() -> Self {
        Self {
            exploit: ExploitMethod::PsoQ,
            explore: ExploreMethod::Random,
            q: QModeConfig::Q1,
            pessimism: 2.0,
            cores: 2,
            pso: PsoConfig::default(),
            cmaes: CmaesConfig::default(),
            novelty: NoveltyConfig::default(),
            sim_pso: PsoConfig { particles: 35, iterations: 30, ..PsoConfig::default() },
            sim_cmaes: CmaesConfig { population: Some(35), generations: 30, tol_x: 0.0, ..CmaesConfig::default() },
            openai_es: OpenAiEsConfig::default(),
            cmaes_es: CmaesConfig { population: Some(9), ..CmaesConfig::default() },
            es_train_on: EsTrainOn::BestSeen,
            sim_seed: SimSeed::Fresh,
            reject_radius: 0.05,
            trust_radius: 0.0,
            trust_growth: 0.5,
            screen: crate::screen::ScreenConfig::default(),
        }
    }
}

/// Which candidate of the ES baselines is trained on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EsTrainOn {
    /// The highest-scoring candidate of all generations so far ("the best design seen").
    #[default]
    BestSeen,
    /// The highest-scoring candidate of the generation just scored.
    GenerationBest,
}

/// Which reset seed each simulation rollout of the baselines starts from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SimSeed {
    /// A fresh seed per rollout, as the reference (each `env.reset()` draws a new start state):
    /// the fitness carries the start-state noise that the thesis names as this baseline's
    /// weakness.
    #[default]
    Fresh,
    /// The run's seed for every rollout: every candidate starts from the same state, a
    /// noise-free (and so flattering) comparison.
    Fixed,
}
