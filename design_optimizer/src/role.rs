//! The design optimiser role: answers the learner's design requests with the configured
//! method, scoring with the population networks it receives over the transport.
//!
//! Methods (`exploit`), all with the same request/reply shape, so the baselines of thesis
//! 5.5.2 are configurations of one run:
//! - `pso-q` (FEAR): PSO over Eq. 5.6; `cmaes-q`: CMA-ES over Eq. 5.6. Zero design rollouts.
//! - `sim-pso`, `sim-cmaes`: the same searches over the mean per-step reward of one rollout
//!   of the population policy per design, through a [`RolloutEvaluator`] (35 x 30 = 1050
//!   rollouts per design by default).
//! - `openai-es`, `cmaes-es`: one generation of a persistent ES per design (256 and 9
//!   candidates evaluated in simulation); the generation's best candidate is trained on.
//! - `random`: uniform in the box.
//! - `screened` (beyond the thesis): PSO over Eq. 5.6 proposes its best few diverse designs,
//!   a few short rollouts of the population policy choose among them ([`crate::screen`]).
//!
//! With `trust-radius > 0` the searches over Q (`pso-q`, `cmaes-q`, `screened`) look only
//! within a radius of the designs trained so far, growing as designs accumulate
//! ([`crate::trust`]; beyond the thesis).
//!
//! Exploration requests use `explore`: `random` or `novelty` (Eq. 5.7). Every reply carries
//! the Eq. 5.6 score of the chosen design under the current population networks.
//!
//! A request may list designs an operator rejected as prototypes ([`crate::reject`]): the
//! searches over Q and over rollouts score their neighbourhood (`reject-radius`) minus
//! infinity, `random` draws again, the ES baselines stop training on a rejected best, and
//! novelty search counts them as chosen designs to move away from.

use std::sync::atomic::{AtomicBool, Ordering};

use coadapt_core::{BoxSpace, Rng64, rng};
use coadapt_nn::Mlp;
use coadapt_transport::messages::Dims;
use coadapt_transport::{
    DesignKind, DesignReply, DesignRequest, OptimizerLinks, TransportError, Validate, Weights, newest_or_stop, next_or_stop,
};
use rand::Rng;

pub use crate::config::{EsTrainOn, ExploitMethod, ExploreMethod, OptimizerConfig, QModeConfig, SimSeed};
use crate::es::{AskTell, OpenAiEs, one_generation};
use crate::reject::{AllRejected, Rejected};
pub use crate::rollout::{RolloutError, RolloutEvaluator};
use crate::{Cmaes, CriticObjective, DesignObjective, ObjectiveError, QMode, SearchResult, cmaes, novelty, pso};

/// The shapes the optimiser scores with.
#[derive(Clone, Debug)]
pub struct OptimizerSpec {
    pub policy: Mlp,
    pub critic: Mlp,
    pub bounds: BoxSpace,
    /// Observation columns of the design: `design_at..design_at + bounds.dim()`.
    pub design_at: usize,
    pub obs_dim: usize,
    pub act_dim: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum OptimizerError {
    #[error("transport: {0}")]
    Transport(#[from] TransportError),
    #[error("config: {0}")]
    Config(String),
    #[error("design {index}: {why}")]
    Design { index: u32, why: String },
    /// A stop (Ctrl-C, SIGTERM, the learner's end) cut a search by simulation short: its
    /// result is no answer and is neither sent nor stored.
    #[error("design {index}: stopped during its rollouts")]
    Stopped { index: u32 },
}

/// The optimiser's state across requests.
pub struct Optimizer<'a> {
    pub(crate) cfg: OptimizerConfig,
    spec: OptimizerSpec,
    evaluator: Option<&'a mut dyn RolloutEvaluator>,
    pub(crate) es: Option<Box<dyn AskTell>>,
    /// The best ES candidate so far and its score.
    pub(crate) es_best: Option<SearchResult>,
    pub(crate) rng: Rng64,
    pub(crate) seed: u64,
    pub(crate) requests: u64,
    /// Every reply so far, by request ([`crate::resume`]).
    pub(crate) replies: std::collections::BTreeMap<crate::resume::RequestKey, crate::resume::StoredReply>,
    counters: std::sync::Arc<Counters>,
}

/// What `/metrics` shows of the optimiser (updated as it serves; read from another thread).
#[derive(Debug, Default)]
pub struct Counters {
    /// Requests answered by a search.
    pub searched: std::sync::atomic::AtomicU64,
    /// Requests answered from the stored replies (sent again by the learner).
    pub answered_again: std::sync::atomic::AtomicU64,
    /// Design rollouts spent by the simulation baselines.
    pub rollouts: std::sync::atomic::AtomicU64,
    /// Seconds of the last search and of all, as `f64` bits.
    pub last_seconds_bits: std::sync::atomic::AtomicU64,
    pub total_seconds_bits: std::sync::atomic::AtomicU64,
}

impl std::fmt::Debug for Optimizer<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Optimizer").field("cfg", &self.cfg).field("requests", &self.requests).finish_non_exhaustive()
    }
}

impl<'a> Optimizer<'a> {
    pub fn new(
        cfg: OptimizerConfig,
        spec: OptimizerSpec,
        evaluator: Option<&'a mut dyn RolloutEvaluator>,
        seed: u64,
    ) -> Result<Self, OptimizerError> {
        if !(cfg.pessimism.is_finite() && cfg.pessimism >= 0.0) {
            return Err(OptimizerError::Config(format!("optimizer.pessimism: {} is not a finite number >= 0", cfg.pessimism)));
        }
        if !(cfg.reject_radius.is_finite() && cfg.reject_radius >= 0.0) {
            return Err(OptimizerError::Config(format!("optimizer.reject-radius: {} is not a finite number >= 0", cfg.reject_radius)));
        }
        if !(cfg.trust_radius.is_finite() && cfg.trust_radius >= 0.0) {
            return Err(OptimizerError::Config(format!("optimizer.trust-radius: {} is not a finite number >= 0", cfg.trust_radius)));
        }
        if !(cfg.trust_growth.is_finite() && cfg.trust_growth >= 0.0) {
            return Err(OptimizerError::Config(format!("optimizer.trust-growth: {} is not a finite number >= 0", cfg.trust_growth)));
        }
        cfg.screen.check().map_err(|e| OptimizerError::Config(e.to_string()))?;
        if cfg.exploit.needs_rollouts() && evaluator.is_none() {
            return Err(OptimizerError::Config(format!("optimizer.exploit = {} needs simulation rollouts", cfg.exploit.name())));
        }
        let es: Option<Box<dyn AskTell>> = match cfg.exploit {
            ExploitMethod::OpenaiEs => Some(Box::new(
                OpenAiEs::new(&spec.bounds, &cfg.openai_es, seed)
                    .map_err(|e| OptimizerError::Config(format!("optimizer.openai-es: {e}")))?,
            )),
            ExploitMethod::CmaesEs => Some(Box::new(
                Cmaes::new(&spec.bounds, &cfg.cmaes_es, seed).map_err(|e| OptimizerError::Config(format!("optimizer.cmaes-es: {e}")))?,
            )),
            _ => None,
        };
        Ok(Self {
            rng: rng(seed, 0x4f50_5449),
            cfg,
            spec,
            evaluator,
            es,
            es_best: None,
            seed,
            requests: 0,
            replies: Default::default(),
            counters: Default::default(),
        })
    }

    /// How the objective combines the critics (`optimizer.q`).
    pub(crate) fn q_mode(&self) -> QMode {
        self.cfg.q.mode(self.cfg.pessimism)
    }

    pub(crate) fn spec_bounds(&self) -> &BoxSpace {
        &self.spec.bounds
    }

    pub(crate) fn objective(&self, w: &Weights, start_states: &[f32]) -> Result<DesignObjective, ObjectiveError> {
        let thetas: Vec<&[f32]> = match self.cfg.q {
            QModeConfig::Q1 => vec![&w.q1],
            QModeConfig::MinOfTwin => vec![&w.q1, &w.q2],
            // Every head the learner sends: the twin, and the ensemble heads of
            // `learner.population-critics` when there are more.
            // (`heads` reads them from the third on.)
            QModeConfig::Pessimistic | QModeConfig::Heads => [&w.q1, &w.q2].into_iter().chain(&w.heads).map(Vec::as_slice).collect(),
        };
        let objective = DesignObjective::new(
            &self.spec.policy,
            &w.policy,
            &self.spec.critic,
            &thetas,
            start_states,
            self.spec.design_at,
            self.spec.bounds.dim(),
        )?;
        objective.check_mode(self.q_mode())?;
        Ok(objective)
    }

    /// The counters for `/metrics`.
    pub fn counters(&self) -> std::sync::Arc<Counters> {
        self.counters.clone()
    }

    /// Chooses the design of `req` with population weights `w`.
    pub fn choose(&mut self, req: &DesignRequest, w: &Weights) -> Result<DesignReply, OptimizerError> {
        self.choose_until(req, w, &AtomicBool::new(false))
    }

    /// [`Optimizer::choose`], with the searches by simulation (`sim-pso`, `sim-cmaes`, the ES
    /// generations, `screened`'s rollouts) given up between batches of rollouts once `stop` is
    /// set ([`OptimizerError::Stopped`]): a Daisy sim-PSO choice is minutes of rollouts, and a
    /// stop should not wait for them. (An ES state told the cut generation is not to be used
    /// again; the serve loop stops.)
    pub fn choose_until(&mut self, req: &DesignRequest, w: &Weights, stop: &AtomicBool) -> Result<DesignReply, OptimizerError> {
        let err = |why: String| OptimizerError::Design { index: req.index, why };
        self.requests += 1;
        let seed = self.seed.wrapping_add(self.requests.wrapping_mul(0x9E37_79B9));
        let objective = self.objective(w, &req.start_states).map_err(|e| err(e.to_string()))?;
        let mut q = CriticObjective::new(&objective, self.q_mode(), self.cfg.cores);
        let bounds = self.spec.bounds.clone();
        let rejected = Rejected::new(&req.rejected, &bounds, self.cfg.reject_radius);
        let trust = crate::trust::TrustRegion::new(&req.chosen, &bounds, self.cfg.trust_radius, self.cfg.trust_growth);
        let (method, result, rollouts): (&str, SearchResult, u64) = match req.kind {
            DesignKind::Explore => match self.cfg.explore {
                ExploreMethod::Random => ("random", self.random(&rejected).map_err(|e| err(e.to_string()))?, 0),
                ExploreMethod::Novelty => {
                    // A rejected body is one to move away from, like a chosen one.
                    let seen = [req.chosen.as_slice(), req.rejected.as_slice()].concat();
                    let r = novelty::most_novel(&seen, &bounds, &self.cfg.novelty, seed).map_err(|e| err(e.to_string()))?;
                    ("novelty", r, 0)
                }
            },
            DesignKind::Exploit => {
                let m = self.cfg.exploit;
                let r = match m {
                    ExploitMethod::PsoQ | ExploitMethod::CmaesQ | ExploitMethod::Screened if trust.is_some() => {
                        let region = trust.as_ref().expect("checked");
                        let mut inside = region.wrap(&mut q);
                        self.over_q(m, &mut inside, &w.policy, &bounds, &rejected, seed, stop).map(|mut r| {
                            region.project(&mut r.design);
                            r
                        })
                    }
                    ExploitMethod::PsoQ | ExploitMethod::CmaesQ | ExploitMethod::Screened => {
                        self.over_q(m, &mut q, &w.policy, &bounds, &rejected, seed, stop)
                    }
                    ExploitMethod::Random => self.random(&rejected).map_err(|e| crate::SearchError::Config(e.to_string())),
                    ExploitMethod::SimPso | ExploitMethod::SimCmaes | ExploitMethod::OpenaiEs | ExploitMethod::CmaesEs => {
                        self.by_simulation(m, &w.policy, &bounds, &rejected, seed, stop)
                    }
                };
                if m.needs_rollouts() && stop.load(Ordering::Relaxed) {
                    return Err(OptimizerError::Stopped { index: req.index });
                }
                let r = r.map_err(|e| err(e.to_string()))?;
                if rejected.near(&r.design) {
                    return Err(err(format!(
                        "{} found nothing outside optimizer.reject-radius ({}) of the {} rejected design(s); lower the radius",
                        m.name(),
                        self.cfg.reject_radius,
                        req.rejected.len() / bounds.dim().max(1)
                    )));
                }
                // `screened` counts the rollouts it ran in `evaluations`.
                let rollouts = if m.needs_rollouts() { r.evaluations as u64 } else { 0 };
                (m.name(), r, rollouts)
            }
        };
        let mut predicted = [0.0];
        q.evaluate_one(&result.design, &mut predicted);
        Ok(DesignReply {
            index: req.index,
            design: result.design,
            method: method.into(),
            predicted_objective: predicted[0].is_finite().then_some(predicted[0]),
            design_rollouts: rollouts,
        })
    }

    /// Uniform in the box, drawn again while it falls near a rejected design (at most
    /// [`RANDOM_DRAWS`] times).
    fn random(&mut self, rejected: &Rejected) -> Result<SearchResult, AllRejected> {
        random_design(&self.spec.bounds, &mut self.rng, rejected, self.cfg.reject_radius)
    }

    /// The searches over Q: PSO (`pso-q`), CMA-ES (`cmaes-q`), or PSO whose best diverse
    /// designs are screened by short rollouts (`screened`).
    #[allow(clippy::too_many_arguments)] // the search's inputs, each used
    fn over_q(
        &mut self,
        m: ExploitMethod,
        q: &mut dyn crate::SwarmObjective,
        policy: &[f32],
        bounds: &BoxSpace,
        rejected: &Rejected,
        seed: u64,
        stop: &AtomicBool,
    ) -> Result<SearchResult, crate::SearchError> {
        match m {
            ExploitMethod::CmaesQ => cmaes::maximise(&mut rejected.guard(q), bounds, &self.cfg.cmaes, seed),
            ExploitMethod::Screened if self.cfg.screen.candidates > 1 => {
                let mut guarded = rejected.guard(q);
                let mut recorded = crate::screen::Recorded::new(&mut guarded);
                let best = pso::maximise(&mut recorded, bounds, &self.cfg.pso, seed)?;
                let scale: Vec<f32> =
                    bounds.low.iter().zip(&bounds.high).map(|(lo, hi)| if hi > lo { 1.0 / (hi - lo) } else { 0.0 }).collect();
                let sc = self.cfg.screen.clone();
                let candidates =
                    crate::screen::diverse_best(&recorded.designs, &recorded.scores, bounds.dim(), &scale, sc.candidates, sc.separation);
                if stop.load(Ordering::Relaxed) {
                    return Ok(best);
                }
                self.screen(policy, candidates, best)
            }
            ExploitMethod::Screened => {
                pso::maximise(&mut rejected.guard(q), bounds, &self.cfg.pso, seed).map(|r| SearchResult { evaluations: 0, ..r })
            }
            _ => pso::maximise(&mut rejected.guard(q), bounds, &self.cfg.pso, seed),
        }
    }

    /// `screened`: `screen.rollouts` rollouts of each candidate from the same reset seeds; the
    /// highest mean return wins (its score is that mean return).
    fn screen(&mut self, policy: &[f32], candidates: Vec<Vec<f32>>, best: SearchResult) -> Result<SearchResult, crate::SearchError> {
        let fail = |e: RolloutError| crate::SearchError::Config(format!("screening rollouts failed: {e}"));
        if candidates.len() < 2 {
            return Ok(SearchResult { evaluations: 0, ..best });
        }
        let Some(ev) = self.evaluator.as_deref_mut() else {
            return Err(crate::SearchError::Config("screened needs simulation rollouts".into()));
        };
        let (r, k) = (self.cfg.screen.rollouts, candidates.len());
        let seeds: Vec<u64> = (0..r).map(|_| self.rng.random::<u64>()).collect();
        let designs: Vec<f32> = candidates.iter().flat_map(|c| std::iter::repeat_n(c.as_slice(), r).flatten().copied()).collect();
        let seeds: Vec<u64> = (0..k).flat_map(|_| seeds.iter().copied()).collect();
        let mut returns = vec![0.0f32; k * r];
        ev.returns(policy, &designs, &seeds, self.cfg.screen.steps, &mut returns).map_err(fail)?;
        let means: Vec<f32> = returns.chunks_exact(r).map(|c| c.iter().sum::<f32>() / r as f32).collect();
        // The first of the highest means (the critic's order breaks ties).
        let mut win = 0;
        for (i, m) in means.iter().enumerate() {
            if crate::swarm::key(*m) > crate::swarm::key(means[win]) {
                win = i;
            }
        }
        Ok(SearchResult { design: candidates[win].clone(), score: means[win], history: means, evaluations: k * r })
    }

    fn by_simulation(
        &mut self,
        m: ExploitMethod,
        policy: &[f32],
        bounds: &BoxSpace,
        rejected: &Rejected,
        seed: u64,
        stop: &AtomicBool,
    ) -> Result<SearchResult, crate::SearchError> {
        let Some(ev) = self.evaluator.as_deref_mut() else {
            return Err(crate::SearchError::Config(format!("{} needs simulation rollouts", m.name())));
        };
        let mut failure: Option<RolloutError> = None;
        let (mode, fixed, rng) = (self.cfg.sim_seed, self.seed, &mut self.rng);
        let mut seeds = Vec::new();
        let mut sim = |designs: &[f32], fitness: &mut [f32]| {
            // Stopping: the search runs out its generations on no scores, at once.
            if stop.load(Ordering::Relaxed) {
                fitness.fill(f32::NAN);
                return;
            }
            seeds.clear();
            seeds.extend((0..fitness.len()).map(|_| match mode {
                SimSeed::Fresh => rng.random::<u64>(),
                SimSeed::Fixed => fixed,
            }));
            if let Err(e) = ev.evaluate(policy, designs, &seeds, fitness) {
                fitness.fill(f32::NAN);
                failure.get_or_insert(e);
            }
        };
        let mut sim = rejected.guard(&mut sim);
        let r = match m {
            ExploitMethod::SimPso => pso::maximise(&mut sim, bounds, &self.cfg.sim_pso, seed),
            ExploitMethod::SimCmaes => cmaes::maximise(&mut sim, bounds, &self.cfg.sim_cmaes, seed),
            _ => match self.es.as_deref_mut() {
                Some(es) => one_generation(es, &mut sim),
                None => Err(crate::SearchError::Config("no ES state".into())),
            },
        };
        if let Some(e) = failure {
            return Err(crate::SearchError::Config(format!("rollouts failed: {e}")));
        }
        let r = r?;
        if !matches!(m, ExploitMethod::OpenaiEs | ExploitMethod::CmaesEs) {
            return Ok(r);
        }
        // A rejected best is no longer the best seen: the operator will not build it.
        if self.es_best.as_ref().is_some_and(|b| rejected.near(&b.design)) {
            self.es_best = None;
        }
        if self.es_best.as_ref().is_none_or(|b| r.score > b.score) {
            self.es_best = Some(r.clone());
        }
        Ok(match (self.cfg.es_train_on, &self.es_best) {
            (EsTrainOn::BestSeen, Some(best)) => SearchResult { evaluations: r.evaluations, history: r.history, ..best.clone() },
            _ => r,
        })
    }
}

impl CriticObjective<'_> {
    fn evaluate_one(&mut self, design: &[f32], out: &mut [f32; 1]) {
        crate::SwarmObjective::evaluate(self, design, out);
    }
}

/// [`Optimizer::random`] drawing from `rng` (the calibration passes a copy of the optimiser's
/// generator, to see the next random design without drawing it).
pub(crate) fn random_design(bounds: &BoxSpace, rng: &mut Rng64, rejected: &Rejected, radius: f32) -> Result<SearchResult, AllRejected> {
    let mut d = vec![0.0; bounds.dim()];
    for _ in 0..RANDOM_DRAWS {
        bounds.sample(rng, &mut d);
        if !rejected.near(&d) {
            return Ok(SearchResult { design: d, score: f32::NAN, history: vec![], evaluations: 0 });
        }
    }
    Err(AllRejected { draws: RANDOM_DRAWS, radius })
}

/// Random draws before `random` gives up finding a design away from every rejected one.
pub const RANDOM_DRAWS: usize = 10_000;

/// Serves design requests until the learner closes the queue (`Ok`) or `shutdown` is set. A
/// request answered before (the learner sent it again after a deadline, or a resumed learner
/// asks again) gets the same reply without a new search. With `store`, the optimiser's state
/// is appended there after every reply, before it is sent.
pub fn run(
    opt: &mut Optimizer<'_>,
    links: &mut OptimizerLinks,
    shutdown: &AtomicBool,
    store: Option<&crate::resume::StateFile>,
) -> Result<u64, OptimizerError> {
    let dims = Dims { obs: opt.spec.obs_dim, act: opt.spec.act_dim, design: opt.spec.bounds.dim() };
    let mut served = 0;
    while let Some(req) = next_or_stop(links.requests.as_mut(), shutdown)? {
        if let Err(e) = req.validate(&dims) {
            return Err(OptimizerError::Design { index: req.index, why: format!("malformed request: {e}") });
        }
        let key = crate::resume::RequestKey::of(&req, dims.design);
        if let Some(r) = opt.replies.get(&key) {
            coadapt_log::logln!("optimizer: design {} was answered before; sending the same reply", req.index);
            opt.counters.answered_again.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            match links.replies.send(r.reply(req.index)) {
                Err(_) if shutdown.load(std::sync::atomic::Ordering::Relaxed) => break,
                r => r?,
            }
            continue;
        }
        let Some(w) = newest_or_stop(links.weights.as_mut(), req.weights_version, shutdown)? else { break };
        let t = std::time::Instant::now();
        let reply = match opt.choose_until(&req, &w, shutdown) {
            Err(OptimizerError::Stopped { index }) => {
                coadapt_log::logln!("optimizer: design {index}: stopped during its rollouts (the learner asks again on resume)");
                break;
            }
            r => r?,
        };
        {
            use std::sync::atomic::Ordering::Relaxed;
            let (c, secs) = (&opt.counters, t.elapsed().as_secs_f64());
            c.searched.fetch_add(1, Relaxed);
            c.rollouts.fetch_add(reply.design_rollouts, Relaxed);
            c.last_seconds_bits.store(secs.to_bits(), Relaxed);
            let total = f64::from_bits(c.total_seconds_bits.load(Relaxed)) + secs;
            c.total_seconds_bits.store(total.to_bits(), Relaxed);
        }
        if let Some(s) = store {
            // Evidence, not the run: a failure to score or write is reported and the run goes on.
            let file = crate::calibration::CalibrationFile::beside(s.path());
            match opt.calibration(&req, &w, &reply) {
                Ok(rows) => {
                    if let Err(e) = file.append(&rows) {
                        coadapt_log::logln!("optimizer: design {}: writing {}: {e}", req.index, file.path().display());
                    }
                }
                Err(e) => coadapt_log::logln!("optimizer: design {}: calibration scores: {e}", req.index),
            }
        }
        let stored = crate::resume::StoredReply::of(&reply);
        if let Some(s) = store {
            s.append(key, &stored, &opt.state().map_err(|e| OptimizerError::Config(e.to_string()))?)
                .map_err(|e| OptimizerError::Config(format!("writing {}: {e}", s.path().display())))?;
        }
        opt.replies.insert(key, stored);
        match links.replies.send(reply) {
            // Stopping (Ctrl-C) while a search ran: the learner has gone already and the
            // reply is kept in the state for its resume.
            Err(_) if shutdown.load(std::sync::atomic::Ordering::Relaxed) => break,
            r => r?,
        }
        served += 1;
    }
    Ok(served)
}
