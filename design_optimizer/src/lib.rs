//! The coadapt design optimiser: chooses the next body from the learned critic.
//!
//! # Layout
//! - [`objective`]: the design objective of FEAR (thesis Eq. 5.6),
//!   `f(xi) = mean_s Q(s_xi, tanh(mu(s_xi)), s_xi)` over a batch of start states whose design
//!   columns are replaced by `xi`, evaluated for a whole swarm of designs in one batched,
//!   two-core pass; [`CriticObjective`] is it as a [`SwarmObjective`].
//! - [`swarm`]: what the searches share: the [`SwarmObjective`] trait (a batched function to
//!   maximise, also any `FnMut(&[f32], &mut [f32])`), [`SearchResult`], [`Progress`].
//! - [`pso`]: global-best particle swarm optimisation, the reference's 700 particles x 250
//!   iterations as pyswarms' `GlobalBestPSO` runs them, with a choice of bound rules.
//! - [`cmaes`]: Hansen's CMA-ES, in box-normalised coordinates with reflection at the bounds.
//! - [`es`]: the population-based ES baselines of Ha (thesis 5.5.2), one generation per
//!   design: the [`AskTell`] interface shared by [`OpenAiEs`] (estool's OpenAI-ES, 256
//!   candidates) and [`Cmaes`] (lambda 9), and [`one_generation`]: ask, score the candidates in
//!   one batched call, tell, return the generation's best.
//! - [`novelty`]: novelty search (thesis Eq. 5.7), the mean distance to the m nearest chosen
//!   designs, maximised by the PSO.
//! - [`landscape`]: the design landscape of thesis Fig. 5.9: [`landscape::Pca2`], the plane of the
//!   first two principal components of the designs tried, and [`landscape::grid`], a grid over
//!   it mapped back to (clipped) designs for the objective to score.
//! - [`reject`]: designs an operator rejected as prototypes, and the radius around each that
//!   no proposal may enter (an objective wrapper scoring it minus infinity).
//! - [`role`]: the optimiser role: design requests in, designs out, by PSO/CMA-ES over Q,
//!   the simulation baselines (through a [`rollout::RolloutEvaluator`]), ES or random; and
//!   exploration by random designs or novelty; its settings in [`config`] (`[optimizer]`,
//!   re-exported from `role`).
//! - [`rollout`]: [`rollout::RolloutEvaluator`], what scores designs by simulation for the
//!   baselines and the screened rollouts, and [`rollout::RolloutError`], why it could not.
//! - [`calibration`]: at each exploitation request, the objective's value for the chosen design,
//!   the next random design and every design trained before, with that request's networks
//!   (`calibration.csv`: does the critic order bodies as the robot does?).
//! - [`trust`]: a trust region around the designs trained so far, widening as they accumulate:
//!   the searches over Q score every design at its projection into it (beyond the thesis).
//! - [`screen`]: critic-screened rollouts: PSO over Q proposes its best few diverse designs,
//!   short rollouts of the population policy choose among them (beyond the thesis).
//! - [`resume`]: the optimiser's state file (generator, request count, ES state, every reply
//!   by request), so a restarted optimiser continues exactly where it stopped.
//!
//! Every search is seeded (`coadapt_core::rng(seed, <its stream>)`): the same seed gives the
//! same design.

pub mod calibration;
pub mod cmaes;
pub mod config;
pub mod es;
pub mod landscape;
pub mod novelty;
pub mod objective;
pub mod pso;
pub mod reject;
pub mod resume;
pub mod role;
pub mod rollout;
pub mod screen;
pub mod swarm;
pub mod trust;

pub use cmaes::Cmaes;
pub use cmaes::CmaesConfig;
pub use es::{AskTell, OpenAiEs, OpenAiEsConfig, one_generation};
pub use novelty::{Novelty, NoveltyConfig};
pub use objective::{CriticObjective, DesignObjective, ObjectiveError, ObjectiveWorkspace, QMode};
pub use pso::{BoundHandling, PsoConfig};
pub use swarm::{Progress, SearchError, SearchResult, SwarmObjective};
