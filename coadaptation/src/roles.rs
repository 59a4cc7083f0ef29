//! The three roles of a co-adaptation, each over whatever links it is given: the same code runs
//! as threads (`coadapt run` over the in-process transport) and as separate processes
//! (`coadapt learner`, `coadapt actor`, `coadapt optimizer`).

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use crate::AppError;
use crate::error::Context;
use coadapt_actors::{Actor, PolicyKind};
use coadapt_core::{Env, EnvSpec};
use coadapt_design_optimizer::resume::StateFile;
use coadapt_design_optimizer::role::{self as optimizer, Optimizer, OptimizerSpec, RolloutError, RolloutEvaluator};
use coadapt_learner::coadapt::{self, RunEvent};
use coadapt_learner::networks;
use coadapt_learner::prototype::{self, Outcome, ResetMode};
use coadapt_learner::run_dir::RunWriter;
use coadapt_learner::snapshot;
use coadapt_transport::{ActorLinks, LearnerLinks, OptimizerLinks};

use crate::config::RunConfig;
use coadapt_log::duration;

/// The optimiser's error: its settings fail the same way every time (exit 78, not restarted);
/// the rest (a link, a design) may pass.
fn optimizer_error(e: optimizer::OptimizerError) -> AppError {
    match e {
        optimizer::OptimizerError::Config(_) => AppError::Config(e.to_string()),
        e => AppError::library(e),
    }
}

/// Simulation rollouts for the baselines: one deterministic episode of the population policy
/// per design from its reset seed, fitness the mean per-step reward; designs are shared out
/// over the threads.
struct SimEvaluator {
    actors: Vec<Actor<Box<dyn Env>>>,
    version: u64,
}

impl SimEvaluator {
    /// One deterministic rollout per design (of at most `steps` steps, 0 for the whole
    /// episode), its statistics turned into a score by `score`.
    fn rollouts(
        &mut self,
        policy: &[f32],
        designs: &[f32],
        seeds: &[u64],
        steps: usize,
        out: &mut [f32],
        score: fn(&coadapt_actors::EpisodeStats) -> f32,
    ) -> Result<(), RolloutError> {
        self.version += 1;
        let dim = designs.len() / out.len().max(1);
        let per = out.len().div_ceil(self.actors.len());
        let version = self.version;
        std::thread::scope(|s| {
            let jobs: Vec<_> = self
                .actors
                .iter_mut()
                .zip(out.chunks_mut(per.max(1)))
                .zip(designs.chunks(per.max(1) * dim))
                .zip(seeds.chunks(per.max(1)))
                .map(|(((actor, fit), des), seeds)| {
                    s.spawn(move || -> Result<(), RolloutError> {
                        actor.set_weights(version, policy).map_err(|e| RolloutError::Failed(e.into()))?;
                        for ((f, d), &seed) in fit.iter_mut().zip(des.chunks_exact(dim)).zip(seeds) {
                            let mut taken = 0usize;
                            let mut cut = |_: &coadapt_core::Transition<'_>| {
                                taken += 1;
                                if steps > 0 && taken >= steps { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
                            };
                            let st = actor.run_episode(seed, d, false, &mut cut).map_err(|e| RolloutError::Failed(e.into()))?;
                            *f = score(&st);
                        }
                        Ok(())
                    })
                })
                .collect();
            jobs.into_iter().try_for_each(|j| j.join().map_err(|_| RolloutError::Panicked)?)
        })
    }
}

impl RolloutEvaluator for SimEvaluator {
    fn evaluate(&mut self, policy: &[f32], designs: &[f32], seeds: &[u64], fitness: &mut [f32]) -> Result<(), RolloutError> {
        self.rollouts(policy, designs, seeds, 0, fitness, |st| st.episode_return / st.length.max(1) as f32)
    }

    fn returns(&mut self, policy: &[f32], designs: &[f32], seeds: &[u64], steps: usize, returns: &mut [f32]) -> Result<(), RolloutError> {
        self.rollouts(policy, designs, seeds, steps, returns, |st| st.episode_return)
    }
}

/// Seconds left: this start's pace (`busy` seconds for `done_here` episodes) times the
/// episodes the run still lacks (`done_in_run` of `total` written, counting those written before
/// a resume: a resumed run's ETA is the rest of the run, not the whole of it again).
fn eta_seconds(busy: f64, done_here: usize, done_in_run: usize, total: usize) -> f64 {
    if done_here == 0 {
        return 0.0;
    }
    busy / done_here as f64 * total.saturating_sub(done_in_run) as f64
}

/// The progress lines of a run into `dir`: one per design start and end, one per episode with
/// an ETA (time spent waiting for an operator left out), and what an operator is asked to do.
pub fn progress_printer(
    cfg: &RunConfig,
    dir: &Path,
    disk: Option<std::sync::Arc<coadapt_learner::disk::DiskWatch>>,
) -> impl FnMut(&RunEvent<'_>) + use<> {
    let total_episodes = cfg.schedule.total_episodes();
    let designs_total = cfg.schedule.designs;
    let start = Instant::now();
    let mut done_episodes = 0usize;
    // Per design: the actors that ran its episodes, and the policy lag they acted with.
    let (mut actors, mut lags) = (std::collections::BTreeSet::new(), Vec::new());
    let confirm = format!("coadapt confirm {}", dir.display());
    // Waiting for an operator says nothing about how long the rest takes.
    let (mut paused, mut waiting_since) = (0.0f64, None::<Instant>);
    let mut resume = move |since: &mut Option<Instant>| {
        if let Some(t) = since.take() {
            paused += t.elapsed().as_secs_f64();
        }
        paused
    };
    move |e: &RunEvent<'_>| match e {
        RunEvent::DesignStart { index, row } => {
            let pred = row.predicted_objective.map(|p| format!(", predicted objective {p:.3}")).unwrap_or_default();
            let rollouts = if row.design_rollouts > 0 { format!(", {} design rollouts", row.design_rollouts) } else { String::new() };
            coadapt_log::logln!(
                "design {}/{designs_total} [{} {}] {:?}{pred}{rollouts}",
                index + 1,
                row.kind,
                row.method,
                row.design.iter().map(|v| (v * 1000.0).round() / 1000.0).collect::<Vec<_>>()
            );
        }
        RunEvent::Episode { row, episodes_in_design } => {
            done_episodes += 1;
            actors.insert(row.actor);
            lags.push(row.policy_lag);
            let el = start.elapsed().as_secs_f64();
            let busy = (el - resume(&mut waiting_since)).max(0.0);
            let eta = eta_seconds(busy, done_episodes, row.global_episode + 1, total_episodes);
            let eval = row.eval_return.map(|r| format!(" eval {r:8.2}")).unwrap_or_default();
            let lag = if row.policy_lag > 0 { format!(" lag {}", row.policy_lag) } else { String::new() };
            let disk = disk.as_ref().map(|d| d.note()).unwrap_or_default();
            coadapt_log::logln!(
                "  design {}/{designs_total} episode {:>4}/{episodes_in_design} return {:8.2}{eval}  actor {}{lag}  [{} elapsed, ETA {}]{disk}",
                row.design + 1,
                row.episode + 1,
                row.train_return,
                row.actor,
                duration(el),
                duration(eta)
            );
        }
        RunEvent::DesignEnd { row } => {
            let f = |v: Option<f32>| v.map_or("-".into(), |v| format!("{v:.2}"));
            let lag = match lags.iter().max() {
                Some(&max) if max > 0 => {
                    format!(", policy lag mean {:.1} max {max}", lags.iter().sum::<u64>() as f64 / lags.len() as f64)
                }
                _ => String::new(),
            };
            coadapt_log::logln!(
                "design {} done: best eval {}, last eval {}; {} actor(s){lag}",
                row.index + 1,
                f(row.best_eval_return),
                f(row.last_eval_return),
                actors.len()
            );
            actors.clear();
            lags.clear();
        }
        RunEvent::AwaitingPrototype { index, row, names } => {
            waiting_since.get_or_insert_with(Instant::now);
            let dims = prototype::describe(&prototype::named_dimensions(names, &row.design));
            let flags = if row.kind == "initial" { "[--as-built ...]" } else { "[--as-built ...|--reject]" };
            coadapt_log::logln!(
                "design {}/{designs_total} [{} {}] awaits a prototype: {dims}; build it, then: {confirm} {flags}",
                index + 1,
                row.kind,
                row.method
            );
        }
        RunEvent::PrototypeDecided { row, outcome, requested } => {
            resume(&mut waiting_since);
            let what = match outcome {
                Outcome::Confirmed => "prototype confirmed".to_string(),
                Outcome::AsBuilt(v) => format!("built as {} (requested {})", rounded(v), rounded(requested)),
                Outcome::Rejected => "prototype rejected; asking the optimiser for its next-best design".to_string(),
            };
            coadapt_log::logln!("design {}/{designs_total}: {what}", row.index + 1);
        }
        RunEvent::AwaitingReset { design_index, episode, episodes_in_design, mode } => {
            waiting_since.get_or_insert_with(Instant::now);
            let what = if *mode == ResetMode::Eval { "the evaluation after episode" } else { "episode" };
            coadapt_log::logln!(
                "{what} {}/{episodes_in_design} of design {} awaits a reset: {confirm} --reset",
                episode + 1,
                design_index + 1
            );
        }
        RunEvent::Stats(_) => {}
        RunEvent::ResetConfirmed { design_index, episode, mode } => {
            resume(&mut waiting_since);
            coadapt_log::logln!("{}: reset confirmed", prototype::reset_name(*mode, *episode, *design_index));
        }
    }
}

fn rounded(v: &[f32]) -> String {
    format!("{:?}", v.iter().map(|v| (v * 1000.0).round() / 1000.0).collect::<Vec<_>>())
}

/// The learner: runs the schedule over `links` and writes the run directory `dir` (created
/// here; `config.toml` is written first). With `resume`, a run directory that holds a run is
/// continued from its newest sound snapshot (one that holds none starts over, once its config
/// is checked); without, it must not hold one.
pub fn learner(
    cfg: &RunConfig,
    spec: &EnvSpec,
    dir: &Path,
    links: &mut LearnerLinks,
    shutdown: &AtomicBool,
    resume: bool,
) -> crate::Result<coadapt::RunOutcome> {
    let run_id = coadapt_fleet::new_run_id();
    let root = crate::resume::snapshot_root(dir);
    let mut snaps =
        coadapt::Snapshots { cfg: cfg.snapshot.clone(), root: Some(root.clone()), run_id: run_id.clone(), ..Default::default() };
    let holds_run = dir.join("designs.csv").exists();
    if holds_run && !resume {
        crate::error::bail!("{} already holds a run (designs.csv exists); choose another --out, or --resume it", dir.display());
    }
    // A fresh start takes the population networks of another run, if asked (a resumed run has
    // them in its snapshot already).
    let transfer = || -> crate::Result<Option<coadapt_learner::coadapt::Transfer>> {
        let Some(src) = crate::transfer::source(&cfg.init_population, spec, &cfg.learner.sac.hidden)? else { return Ok(None) };
        coadapt_log::logln!("learner: population networks from {}", src.networks.display());
        crate::transfer::transfer(&src, cfg.init_population.replay).map(Some)
    };
    let mut writer = if holds_run {
        crate::resume::check_compatible(&crate::resume::stored_config(dir)?, cfg)?;
        if snapshot::list(&root)?.is_empty() {
            snaps.transfer = transfer()?;
            coadapt_log::logln!("learner: {} has no snapshot yet: starting the run over (run id {run_id})", dir.display());
            RunWriter::create(dir).with_context(|| format!("creating run directory {}", dir.display()))?
        } else {
            let (from, manifest, state, skipped) = snapshot::load_latest(&root)?;
            for why in &skipped {
                coadapt_log::logln!("learner: skipped snapshot {why}");
            }
            let at = coadapt::resume_point(&state).map_err(|e| crate::error::failed!("snapshot {}: {e}", from.display()))?;
            coadapt_log::logln!(
                "learner: resuming {} from {} ({}; written by run id {}), run id {run_id}",
                dir.display(),
                from.display(),
                manifest.label,
                manifest.run_id
            );
            snaps.resume = Some(state);
            snaps.next_sequence = manifest.sequence + 1;
            RunWriter::resume(dir, at).with_context(|| format!("reopening run directory {}", dir.display()))?
        }
    } else {
        snaps.transfer = transfer()?;
        RunWriter::create(dir).with_context(|| format!("creating run directory {}", dir.display()))?
    };
    let config_text = toml::to_string(cfg).map_err(AppError::library)?;
    std::fs::write(dir.join("config.toml"), &config_text).context("writing config.toml")?;
    writer.events().set_design_names(spec.design_names.clone());
    if writer.episodes_bytes() <= coadapt_learner::run_dir::EPISODES_HEADER.len() as u64 + 1 {
        // A fresh start (a resume has its config in the file already, at step 0).
        writer.events().text("run/config", 0, &format!("```toml\n{config_text}```")).context("writing the event file")?;
    }
    // Dropped when the run returns: Watch streams end, the server stops.
    let design_service = crate::design_live::start(cfg, spec, &run_id, links, &mut writer)?;
    // The operator may answer from another directory: name the run directory in full.
    let full_dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    let disk = std::sync::Arc::new(coadapt_learner::disk::DiskWatch::new(&full_dir, &crate::resume::snapshot_root(&full_dir)));
    let mut print = progress_printer(cfg, &full_dir, Some(disk.clone()));
    let stats = std::sync::Arc::new(std::sync::Mutex::new(coadapt::Stats::default()));
    if !cfg.metrics.learner_listen.is_empty() {
        let source = crate::metrics::Source::Learner(stats.clone(), Some(disk.clone()));
        let at = crate::metrics::serve(&cfg.metrics.learner_listen, source)?;
        coadapt_log::logln!("learner: metrics on http://{at}/metrics");
    }
    let mut on_event = |e: &RunEvent<'_>| {
        crate::health::observe(e);
        if let Some(live) = &design_service {
            live.observe(e);
            if let RunEvent::DesignStart { row, .. } = e {
                live.design_started(row);
            }
        }
        match e {
            RunEvent::Stats(s) => {
                disk.snapshot_taken(s.snapshot_bytes);
                *stats.lock().unwrap_or_else(|e| e.into_inner()) = **s;
            }
            e => print(e),
        }
        // The plots as the run goes, not only at its end (each replaced whole).
        if let RunEvent::DesignEnd { .. } = e
            && let Err(err) = crate::plot::redraw_live(&full_dir)
        {
            coadapt_log::logln!("warning: plots not redrawn: {err:#}");
        }
    };
    let outcome = coadapt::run(
        &cfg.schedule,
        &cfg.learner,
        spec,
        cfg.seed,
        &cfg.flow,
        cfg.actors,
        links,
        &mut writer,
        shutdown,
        &mut on_event,
        &mut snaps,
    )?;
    if snaps.taken > 0 {
        coadapt_log::logln!(
            "learner: {} snapshot(s) in {:.2} s, the last {:.1} MB",
            snaps.taken,
            snaps.seconds,
            snaps.last_bytes as f64 / 1e6
        );
    }
    Ok(outcome)
}

/// One actor: runs the episodes it is handed until the learner is done.
pub fn actor(cfg: &RunConfig, spec: &EnvSpec, id: u64, links: &mut ActorLinks, shutdown: &AtomicBool) -> crate::Result<()> {
    let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), &cfg.learner.sac.hidden)?;
    let mut actor = Actor::new(cfg.make_env()?, policy, PolicyKind::SquashedGaussian, cfg.seed.wrapping_add(id))?;
    let s = coadapt_actors::role::run(&mut actor, id, links, cfg.chunk_len, cfg.remote.env_retries, shutdown)
        .with_context(|| format!("actor {id}"))?;
    coadapt_log::logln!(
        "actor {id}: done after {} episodes, {} steps, {} episode(s) dropped on environment failures",
        s.episodes,
        s.steps,
        s.failed_episodes
    );
    Ok(())
}

/// The design optimiser: answers design requests until the learner is done. With `state_dir`,
/// it continues from the state saved there and saves its state after every reply.
pub fn optimizer(
    cfg: &RunConfig,
    spec: &EnvSpec,
    links: &mut OptimizerLinks,
    shutdown: &AtomicBool,
    state_dir: Option<&Path>,
) -> crate::Result<()> {
    let hidden = &cfg.learner.sac.hidden;
    // The design objective's products in the learner's precision (learner.sac.precision).
    let precision = cfg.learner.sac.precision;
    let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), hidden)?.with_precision(precision);
    let critic = networks::critic(spec.obs_dim(), spec.act_dim(), hidden)?.with_precision(precision);
    let ospec = OptimizerSpec {
        policy: policy.clone(),
        critic,
        bounds: spec.design.clone(),
        design_at: spec.state_dim,
        obs_dim: spec.obs_dim(),
        act_dim: spec.act_dim(),
    };
    let mut sim = if cfg.optimizer.exploit.needs_rollouts() {
        let actors = (0..cfg.sim_threads.max(1))
            .map(|i| Ok(Actor::new(cfg.make_env()?, policy.clone(), PolicyKind::SquashedGaussian, cfg.seed ^ (0x5349_4d00 + i as u64))?))
            .collect::<crate::Result<Vec<_>>>()?;
        Some(SimEvaluator { actors, version: 0 })
    } else {
        None
    };
    let mut opt = Optimizer::new(cfg.optimizer.clone(), ospec, sim.as_mut().map(|s| s as &mut dyn RolloutEvaluator), cfg.seed)
        .map_err(optimizer_error)?;
    if !cfg.metrics.optimizer_listen.is_empty() {
        let at = crate::metrics::serve(&cfg.metrics.optimizer_listen, crate::metrics::Source::Optimizer(opt.counters()))?;
        coadapt_log::logln!("optimizer: metrics on http://{at}/metrics");
    }
    let store = match state_dir {
        Some(d) => {
            let store = StateFile::in_dir(d).with_context(|| format!("creating {}", d.display()))?;
            let (state, skipped) = store.load().with_context(|| format!("reading {}", store.path().display()))?;
            for why in &skipped {
                coadapt_log::logln!("optimizer: state: {why}");
            }
            if let Some((s, replies)) = state {
                let n = replies.len();
                opt.restore(s, replies).map_err(|e| crate::error::failed!("{}: {e}", store.path().display()))?;
                coadapt_log::logln!("optimizer: continuing from {} ({n} replies so far)", store.path().display());
            }
            Some(store)
        }
        None => None,
    };
    optimizer::run(&mut opt, links, shutdown, store.as_ref()).map_err(optimizer_error).context("design optimiser")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::eta_seconds;

    #[test]
    fn a_resumed_runs_eta_counts_only_the_episodes_it_still_lacks() {
        // A fresh run: 10 episodes in 40 s, 90 to go at 4 s each.
        assert_eq!(eta_seconds(40.0, 10, 10, 100), 360.0);
        // Resumed at episode 900 of 1,000: 10 episodes since, at 4 s each, leave 90.
        assert_eq!(eta_seconds(40.0, 10, 910, 1000), 360.0);
        // Done, or nothing yet to measure a pace by.
        assert_eq!(eta_seconds(40.0, 10, 1000, 1000), 0.0);
        assert_eq!(eta_seconds(0.0, 0, 0, 1000), 0.0);
    }
}
