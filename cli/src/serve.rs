//! `coadapt serve RUN_DIR`: a run's design critic for clients in any language, from its newest
//! snapshot and its designs.csv: `coadapt.v1.DesignService` and the Open Inference Protocol
//! model `design-critic` (`proto/README.md`).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use coadapt_design_optimizer::objective::QMode;
use coadapt_design_optimizer::role::QModeConfig;
use coadapt_design_service::{DesignModel, HistoryRow, ServeConfig, StaticSource};
use coadapt_learner::fear::{ActingPolicy, FearLearner};
use coadapt_learner::{coadapt, networks, run_dir, snapshot};

/// Serve a run's design critic: DesignService (Info, Score, History) and the Open Inference
/// Protocol model `design-critic` (input `design` FP32 [N, D]; outputs `value`, `spread` and
/// `disagreement`, FP32 [N, 1] each).
///
/// The values are the thesis's Eq. 5.6 with the population networks of the run's newest
/// snapshot, averaged over a batch of `schedule.start-state-batch` start states drawn from the
/// run's start-state buffer (the same draw every time the run is served), with the run's
/// `optimizer.q` (Q1, min of twin, or pessimistic). Serves until Ctrl-C or SIGTERM; the address
/// is printed on stdout as `grpc://ADDR`.
///
/// How far to trust a difference between two scores: the README's "Reading a score" gives the
/// critic's calibration on the design benchmark per robot (how often the body it preferred
/// reached the higher return once trained, and what a difference of 1 was worth in return),
/// generated from docs/campaign/results. On 2026-11-26 (one seed per robot) its preference for
/// a chosen body over bodies the run had trained was mostly right, over an untried body no
/// better than a coin: use scores to decide which bodies to try, not as their returns.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The run directory (of `coadapt run` or `coadapt learner`).
    pub run_dir: PathBuf,
    /// Address to listen on (port 0 picks a free port).
    #[arg(long, default_value = "127.0.0.1:50061")]
    pub listen: String,
    /// TLS (--tls-cert, --tls-key; --client-auth with --tls-ca for mutual TLS) and tokens
    /// (--tokens-file: clients, optimisers and operators may query). Without TLS only loopback
    /// addresses are served unless --insecure: anyone who reaches the port would read the
    /// run's designs and critic.
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
    /// Most designs one Score or ModelInfer call may carry.
    #[arg(long, default_value_t = 10_000)]
    pub max_score_batch: usize,
}

/// Eq. 5.6 of `cfg`'s run with population networks `(policy, q1, q2)` of `version` over
/// `start_states`, with the run's `optimizer.q`: what the optimiser maximises.
pub fn design_model(
    cfg: &crate::run::RunConfig,
    spec: &coadapt_core::EnvSpec,
    version: u64,
    run_id: String,
    (phi, q1, q2): (&[f32], &[f32], &[f32]),
    start_states: &[f32],
) -> anyhow::Result<DesignModel> {
    let hidden = &cfg.learner.sac.hidden;
    let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), hidden)?;
    let critic = networks::critic(spec.obs_dim(), spec.act_dim(), hidden)?;
    let mode = match cfg.optimizer.q {
        QModeConfig::Q1 => QMode::First,
        QModeConfig::MinOfTwin => QMode::MinOfTwin,
        QModeConfig::Pessimistic => QMode::MeanMinusKStd(cfg.optimizer.pessimism),
    };
    // Both critics always: Q1 alone scores under `q1`, and the pair gives each score's
    // disagreement.
    let thetas: Vec<&[f32]> = vec![q1, q2];
    Ok(DesignModel::new(
        spec.name.clone(),
        spec.design_names.clone(),
        spec.design.clone(),
        version,
        run_id,
        (&policy, phi, &critic, &thetas),
        start_states,
        spec.state_dim,
        mode,
    )?)
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
pub fn load(dir: &Path) -> anyhow::Result<StaticSource> {
    let cfg = crate::resume::stored_config(dir)?;
    let env = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?;
    let spec = env.spec();
    let root = crate::resume::snapshot_root(dir);
    let (from, manifest, mut state, skipped) =
        snapshot::load_latest(&root).with_context(|| format!("{} has no readable snapshot to serve", dir.display()))?;
    for why in &skipped {
        coadapt_log::logln!("serve: skipped snapshot {why}");
    }
    let mut fear = FearLearner::new(spec.obs_dim(), spec.act_dim(), cfg.learner.clone(), cfg.seed)?;
    fear.load_state(&mut state).map_err(|e| anyhow::anyhow!("snapshot {}: {e}", from.display()))?;
    let version = coadapt::population_version(&state).map_err(|e| anyhow::anyhow!("snapshot {}: {e}", from.display()))?;
    let n = cfg.schedule.start_state_batch.max(1);
    let starts = fear
        .sample_start_states(n)
        .ok_or_else(|| anyhow::anyhow!("snapshot {}: no start states yet (no episode finished)", from.display()))?;
    let pop = fear.agent(ActingPolicy::Population);
    let model = design_model(
        &cfg,
        spec,
        version,
        manifest.run_id.clone(),
        (pop.policy_params(), pop.critic_params(0).0, pop.critic_params(1).0),
        &starts,
    )?;
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

/// Serves until Ctrl-C or SIGTERM.
pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let addr: SocketAddr =
        args.listen.parse().with_context(|| format!("--listen: {:?} is not an address like 127.0.0.1:50061", args.listen))?;
    let security = crate::security::from_args(&args.security);
    coadapt_fleet::check_listen("--listen", addr, &security)?;
    let auth = security.server_auth()?;
    if args.max_score_batch == 0 {
        anyhow::bail!("--max-score-batch: 0 would refuse every request; at least 1");
    }
    let source = load(&args.run_dir)?;
    let cfg = ServeConfig { max_score_batch: args.max_score_batch, auth, ..ServeConfig::default() };
    let server = coadapt_design_service::serve(addr, cfg, Arc::new(source)).with_context(|| format!("listening on {addr}"))?;
    let at = server.local_addr();
    coadapt_log::logln!("serve: coadapt.v1.DesignService and design-critic (Open Inference Protocol) on {at} (Ctrl-C stops)");
    coadapt_log::print_stdout_line(&format!("grpc://{at}"));
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().context("starting the runtime")?;
    rt.block_on(crate::env_serve::wait_for_signal());
    coadapt_log::logln!("serve: stopping");
    drop(server);
    Ok(())
}
