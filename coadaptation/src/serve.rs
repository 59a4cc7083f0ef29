//! A run's design critic for the design service: Eq. 5.6 with the run's networks
//! ([`design_model`], also what the live service of a running learner serves), a designs.csv row
//! as a history row, and a finished run's model and history from its newest snapshot ([`load`],
//! for `coadapt serve`) with its operator page ([`page`]).

use std::path::Path;
use std::sync::Arc;

use coadapt_design_service::{DesignModel, HistoryRow, StaticSource};
use coadapt_learner::fear::{ActingPolicy, FearLearner};
use coadapt_learner::{coadapt, networks, run_dir, snapshot};

use crate::error::Context;

/// Eq. 5.6 of `cfg`'s run with population networks `(policy, [q1, q2, heads...])` of `version`
/// over `start_states`, with the run's `optimizer.q`: what the optimiser maximises.
pub fn design_model(
    cfg: &crate::RunConfig,
    spec: &coadapt_core::EnvSpec,
    version: u64,
    run_id: String,
    (phi, critics): (&[f32], &[&[f32]]),
    start_states: &[f32],
) -> crate::Result<DesignModel> {
    let hidden = &cfg.learner.sac.hidden;
    let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), hidden)?;
    let critic = networks::critic(spec.obs_dim(), spec.act_dim(), hidden)?;
    let mode = cfg.optimizer.q.mode(cfg.optimizer.pessimism);
    // Every critic always: Q1 alone scores under `q1`, min-of-twin takes the first two, and
    // all of them give each score's disagreement (over the ensemble when the run has one).
    let thetas = critics;
    DesignModel::new(
        spec.name.clone(),
        spec.design_names.clone(),
        spec.design.clone(),
        version,
        run_id,
        (&policy, phi, &critic, thetas),
        start_states,
        spec.state_dim,
        mode,
    )
    .map_err(crate::AppError::library)
}

/// The population agent's critics: the twin, then any ensemble heads.
fn population_critics(pop: &coadapt_learner::Sac) -> Vec<&[f32]> {
    [pop.critic_params(0).0, pop.critic_params(1).0].into_iter().chain((0..pop.extra_heads()).map(|i| pop.head_params(i))).collect()
}

/// A designs.csv row as the service's history row.
pub fn history_row(r: run_dir::DesignRow) -> HistoryRow {
    HistoryRow {
        index: r.index,
        kind: r.kind,
        design: r.design,
        episodes: r.episodes,
        best_eval_return: r.best_eval_return,
        last_eval_return: r.last_eval_return,
        predicted_objective: r.predicted_objective,
        design_rollouts: r.design_rollouts,
        method: r.method,
        prototype: r.prototype,
    }
}

/// The model and history of the run in `dir`.
pub fn load(dir: &Path) -> crate::Result<StaticSource> {
    let cfg = crate::resume::stored_config(dir)?;
    let env = cfg.make_env()?;
    let spec = env.spec();
    let root = crate::resume::snapshot_root(dir);
    let (from, manifest, mut state, skipped) =
        snapshot::load_latest(&root).with_context(|| format!("{} has no readable snapshot to serve", dir.display()))?;
    for why in &skipped {
        coadapt_log::logln!("serve: skipped snapshot {why}");
    }
    let mut fear = FearLearner::new(spec.obs_dim(), spec.act_dim(), cfg.learner.clone(), cfg.seed)?;
    fear.load_state(&mut state).map_err(|e| crate::error::failed!("snapshot {}: {e}", from.display()))?;
    let version = coadapt::population_version(&state).map_err(|e| crate::error::failed!("snapshot {}: {e}", from.display()))?;
    let n = cfg.schedule.start_state_batch.max(1);
    let starts = fear
        .sample_start_states(n)
        .ok_or_else(|| crate::error::failed!("snapshot {}: no start states yet (no episode finished)", from.display()))?;
    let pop = fear.agent(ActingPolicy::Population);
    let model = design_model(&cfg, spec, version, manifest.run_id.clone(), (pop.policy_params(), &population_critics(pop)), &starts)?;
    let path = dir.join("designs.csv");
    let len = std::fs::metadata(&path).with_context(|| format!("reading {}", path.display()))?.len();
    let history = run_dir::read_designs(&path, len)?.into_iter().map(history_row).collect();
    coadapt_log::logln!(
        "serve: {} from {} ({}), population weights version {version}, {n} start states",
        dir.display(),
        from.display(),
        manifest.label
    );
    Ok(StaticSource { model: Arc::new(model), history })
}

/// The operator page of the run in `dir` (`coadapt serve`: from its files, with `source`'s
/// critic for the landscape until the run has written its own), behind `auth`'s tokens.
pub fn page(
    dir: &Path,
    source: Arc<dyn coadapt_design_service::ModelSource>,
    auth: &coadapt_auth::ServerAuth,
) -> crate::Result<axum::Router> {
    let cfg = crate::resume::stored_config(dir)?;
    let spec = cfg.make_env()?.spec().clone();
    let page = crate::page::Page::new(crate::page::PageSetup {
        dir: std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf()),
        cfg,
        spec,
        tokens: auth.tokens.clone(),
        tls: auth.tls.is_some(),
        live: None,
        model: Some(source),
    });
    Ok(page.router())
}
