//! `coadapt run`: a whole co-adaptation (FEAR or a baseline) on one robot. The learner, the
//! design optimiser and the actors run as separate processes over shared memory (the default;
//! [`crate::fleet`] launches and supervises them), or as threads of this process over the
//! in-process transport (`--transport in-process`, [`run_config`]).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use coadapt_core::EnvSpec;
use coadapt_design_optimizer::landscape::{self, Pca2};
use coadapt_design_optimizer::role::{ExploitMethod, ExploreMethod, OptimizerConfig};
use coadapt_design_optimizer::{CriticObjective, DesignObjective, QMode, SwarmObjective};
use coadapt_learner::coadapt::{self, ScheduleConfig};
use coadapt_learner::fear::{ActingPolicy, FearLearner, FearLearnerConfig};
use coadapt_learner::flow::{FlowConfig, FlowMode};
use coadapt_transport::in_process;
use serde::{Deserialize, Serialize};

use crate::progress::shutdown_on_ctrl_c;
use crate::roles;
use coadapt_fleet::{FleetConfig, TransportKind};
use coadapt_log::print_stdout_line;

/// The reference protocol on HalfCheetah, used when no `--config` is given.
pub const DEFAULT_CONFIG: &str = include_str!("../../configs/half-cheetah-reference.toml");

/// Everything a co-adaptation run needs; the TOML file's layout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct RunConfig {
    /// The robot (pendulum, half-cheetah, walker, hopper, daisy), or a remote one served over
    /// dm_env_rpc: `dm-env-rpc://HOST:PORT` (dimensions and boxes come from its specs).
    pub env: String,
    /// Seed of every random stream: the same seed and config give the same run.
    pub seed: u64,
    /// Actors running episodes (processes, or threads in-process; lock-step uses one at a time).
    pub actors: usize,
    /// Transitions per experience chunk an actor sends.
    pub chunk_len: usize,
    /// Threads running the simulation baselines' rollouts.
    pub sim_threads: usize,
    /// Points per side of the design-landscape grid drawn at the end (0: no landscape).
    pub landscape_grid: usize,
    /// Start states of Eq. 5.6 for the landscape (the thesis's figures use 256).
    pub landscape_start_states: usize,
    pub schedule: ScheduleConfig,
    /// Collection against training: lock-step (the reference) or episodes in flight.
    pub flow: FlowConfig,
    /// How the roles talk and find each other.
    pub fleet: FleetConfig,
    pub learner: FearLearnerConfig,
    pub optimizer: OptimizerConfig,
    /// Deadlines and retries of a remote environment.
    pub remote: coadapt_fleet::RemoteEnvConfig,
    /// Snapshots of the whole run for `--resume` (`every-episodes`, `keep`).
    pub snapshot: coadapt_learner::snapshot::SnapshotConfig,
    /// Prometheus `/metrics` of the learner and the optimiser (`learner-listen`,
    /// `optimizer-listen`; empty: off).
    pub metrics: crate::metrics::MetricsConfig,
    /// The learner's DesignService and `design-critic` model during the run (`listen`; empty:
    /// off) and their bounds.
    pub design_service: crate::design_live::DesignServiceConfig,
    /// TLS and tokens of every gRPC endpoint (`tls-cert`, `tls-key`, `tls-ca`, `tokens-file`,
    /// `token-file`, `insecure`, ...).
    pub security: coadapt_fleet::SecurityConfig,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            env: "half-cheetah".into(),
            seed: 1,
            actors: 1,
            chunk_len: 250,
            sim_threads: 2,
            landscape_grid: 40,
            landscape_start_states: 256,
            schedule: ScheduleConfig::default(),
            flow: FlowConfig::default(),
            fleet: FleetConfig::default(),
            learner: FearLearnerConfig::default(),
            optimizer: OptimizerConfig::default(),
            remote: coadapt_fleet::RemoteEnvConfig::default(),
            snapshot: coadapt_learner::snapshot::SnapshotConfig::default(),
            metrics: crate::metrics::MetricsConfig::default(),
            design_service: crate::design_live::DesignServiceConfig::default(),
            security: coadapt_fleet::SecurityConfig::default(),
        }
    }
}

/// Run a whole co-adaptation: design after design, train the controller and choose the next body.
///
/// The run directory gets the resolved `config.toml`, `designs.csv` (one row per design: kind,
/// design vector, episodes, best and last evaluation return, the design objective predicted for
/// it, design rollouts spent, prototype), `episodes.csv`, `checkpoints/` (population and
/// individual networks after each design), `landscape.csv` and `plots/*.svg` (learning curves,
/// best return over designs, design landscape). Rows are flushed as they are written: Ctrl-C
/// stops after the current episode and keeps everything.
///
/// Real hardware: `schedule.confirm-designs = true` stops at each design until its prototype is
/// built (answer with `coadapt confirm RUN_DIR [--as-built V1,V2,...|--reject]`), and
/// `schedule.reset-needs-confirmation = true` before each episode until the robot is reset
/// (`coadapt confirm RUN_DIR --reset`).
///
/// Settings: the embedded reference protocol (`configs/half-cheetah-reference.toml`), replaced
/// by `--config`, then the flags. Example configs: `configs/*.toml` (the reference, a reduced
/// protocol of about 30 minutes, a tiny one, and each baseline).
#[derive(Debug, Args)]
pub struct RunArgs {
    /// TOML config (top-level env, seed, ... and [schedule], [learner], [learner.sac],
    /// [optimizer] tables); a run directory's config.toml is a valid one.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run directory (default: runs/<config name>-seed<seed>, with -2, -3, ... appended if
    /// taken); an explicit --out must not hold a run already.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override the seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override the exploitation method: pso-q (FEAR), cmaes-q, sim-pso, sim-cmaes, openai-es,
    /// cmaes-es, random, or screened (PSO over Q proposes a few designs, short rollouts choose;
    /// `[optimizer.screen]`).
    #[arg(long)]
    pub exploit: Option<String>,
    /// Override the exploration method: random or novelty.
    #[arg(long)]
    pub explore: Option<String>,
    /// Override the number of designs.
    #[arg(long)]
    pub designs: Option<usize>,
    /// Override how the roles talk: shm (separate processes over iceoryx2 shared memory, the
    /// default), grpc (separate processes over gRPC on this machine), in-process (threads).
    #[arg(long, value_enum)]
    pub transport: Option<TransportKind>,
    /// Override the number of actors.
    #[arg(long)]
    pub actors: Option<usize>,
    /// Override flow.mode: lock-step (the reference schedule, reproducible) or async
    /// (episodes in flight on every actor while the learner trains).
    #[arg(long)]
    pub flow: Option<String>,
    /// Continue the run in RUN_DIR (after a crash, a kill, a reboot or Ctrl-C) from its newest
    /// sound snapshot, with its config.toml (a --config given must agree with it except in
    /// schedule.designs, actors, fleet, snapshot, remote and deadlines). CSVs are cut back to
    /// the snapshot; the same seed gives the same rows as a run never stopped.
    #[arg(long, value_name = "RUN_DIR", conflicts_with = "out")]
    pub resume: Option<PathBuf>,
    /// Serve design queries during the run on ADDR (sets design-service.listen): the
    /// learner answers DesignService (Info, Score, Optimize, Landscape, History, Watch) and the
    /// Open Inference Protocol model `design-critic` with the networks of its latest design
    /// request. Loopback only unless [security] configures TLS or --insecure is given.
    #[arg(long, value_name = "ADDR")]
    pub serve: Option<String>,
    /// Allow plaintext (no TLS) on addresses other than loopback (sets security.insecure):
    /// only on a network you trust.
    #[arg(long)]
    pub insecure: bool,
}

fn parse_enum<T: serde::de::DeserializeOwned>(flag: &str, v: &str) -> anyhow::Result<T> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(v)).map_err(|e| anyhow::anyhow!("--{flag} {v}: {e}"))
}

/// Reads the config: embedded default, or `--config`, then the flags.
pub fn resolve(args: &RunArgs) -> anyhow::Result<(RunConfig, String)> {
    let resumed_config = match (&args.resume, &args.config) {
        (Some(dir), None) => Some(dir.join("config.toml")),
        _ => None,
    };
    let (text, name) = match resumed_config.as_ref().or(args.config.as_ref()) {
        Some(p) => (
            std::fs::read_to_string(p).with_context(|| format!("reading config {}", p.display()))?,
            p.file_stem().map_or("run".into(), |s| s.to_string_lossy().into_owned()),
        ),
        None => (DEFAULT_CONFIG.to_string(), "half-cheetah-reference".into()),
    };
    let mut cfg: RunConfig = toml::from_str(&text).with_context(|| format!("parsing config {name}"))?;
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    if let Some(m) = &args.exploit {
        cfg.optimizer.exploit = parse_enum::<ExploitMethod>("exploit", m)?;
    }
    if let Some(m) = &args.explore {
        cfg.optimizer.explore = parse_enum::<ExploreMethod>("explore", m)?;
    }
    if let Some(d) = args.designs {
        cfg.schedule.designs = d;
    }
    if let Some(t) = args.transport {
        cfg.fleet.transport = t;
    }
    if let Some(n) = args.actors {
        cfg.actors = n;
    }
    if let Some(f) = &args.flow {
        cfg.flow.mode = parse_enum::<FlowMode>("flow", f)?;
    }
    if let Some(a) = &args.serve {
        cfg.design_service.listen = a.clone();
    }
    if args.insecure {
        cfg.security.insecure = true;
    }
    Ok((cfg, name))
}

/// Fills in what the config leaves to the robot: the initial designs.
pub fn resolve_initial_designs(cfg: &mut RunConfig, spec: &EnvSpec) {
    if !cfg.schedule.initial_designs.is_empty() {
        return;
    }
    cfg.schedule.initial_designs = coadapt_robots::reference_initial_designs(&cfg.env).unwrap_or_else(|| {
        let mut rng = coadapt_core::rng(cfg.seed, 0x494e_4954);
        let mut v = vec![spec.default_design.clone()];
        for _ in 0..4 {
            let mut d = vec![0.0; spec.design_dim()];
            spec.design.sample(&mut rng, &mut d);
            v.push(d);
        }
        v
    });
}

pub fn check(cfg: &RunConfig, spec: &EnvSpec) -> anyhow::Result<()> {
    if cfg.schedule.designs == 0 {
        bail!("schedule.designs: must be at least 1");
    }
    if cfg.actors == 0 {
        bail!("actors: must be at least 1");
    }
    if cfg.schedule.designs > cfg.schedule.initial_designs.len() && spec.design_dim() == 0 {
        bail!("env {}: has no design parameters to optimise", cfg.env);
    }
    for (i, d) in cfg.schedule.initial_designs.iter().enumerate() {
        spec.design.check("design", d).map_err(|e| anyhow::anyhow!("schedule.initial-designs[{i}]: {e}"))?;
    }
    cfg.flow.lease().map_err(anyhow::Error::msg)?;
    cfg.schedule.poll_interval().map_err(anyhow::Error::msg)?;
    cfg.remote.options(&cfg.security)?;
    if cfg.fleet.transport == TransportKind::Shm && cfg.actors > cfg.fleet.max_actors {
        bail!("actors: {} is more than fleet.max-actors ({}); raise fleet.max-actors", cfg.actors, cfg.fleet.max_actors);
    }
    Ok(())
}

/// Runs the co-adaptation described by `cfg` into `dir`, every role a thread of this process
/// over the in-process transport.
pub fn run_config(cfg: &RunConfig, dir: &Path, shutdown: &AtomicBool, resume: bool) -> anyhow::Result<coadapt::RunOutcome> {
    let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
    check(cfg, &spec)?;
    let (mut learner_links, actor_links, mut optimizer_links) = in_process::fleet(cfg.actors);
    std::thread::scope(|s| -> anyhow::Result<coadapt::RunOutcome> {
        let spec = &spec;
        // A role that fails stops the run: in one process nothing would restart it.
        let stop_on_error = |r: anyhow::Result<()>| {
            if r.is_err() {
                shutdown.store(true, Ordering::Relaxed);
            }
            r
        };
        let actors: Vec<_> = actor_links
            .into_iter()
            .enumerate()
            .map(|(i, mut links)| s.spawn(move || stop_on_error(roles::actor(cfg, spec, i as u64, &mut links, shutdown))))
            .collect();
        let state = crate::resume::optimizer_state_dir(dir);
        let opt = s.spawn(move || stop_on_error(roles::optimizer(cfg, spec, &mut optimizer_links, shutdown, Some(&state))));
        let result = roles::learner(cfg, spec, dir, &mut learner_links, shutdown, resume);
        // Closing the learner's channels lets the other roles finish.
        drop(learner_links);
        let mut errors = Vec::new();
        for t in actors.into_iter().map(|t| t.join()).chain(std::iter::once(opt.join())) {
            match t {
                Ok(Ok(())) => {}
                Ok(Err(e)) => errors.push(format!("{e:#}")),
                Err(_) => errors.push("a role thread panicked".into()),
            }
        }
        match (result, errors.first()) {
            (Ok(o), Some(first)) if o.interrupted => Err(anyhow::anyhow!("{first}")),
            (Ok(o), first) => {
                if let Some(e) = first {
                    coadapt_log::logln!("warning: {e}");
                }
                Ok(o)
            }
            (Err(e), Some(first)) => Err(e.context(format!("first role failure: {first}"))),
            (Err(e), None) => Err(e),
        }
    })
}

/// Scores the design objective on a grid over the first two principal components of the
/// designs tried (thesis Fig. 5.9) with the final population networks, and writes
/// `landscape.csv` (pc1, pc2, objective) and `landscape_designs.csv` (the designs, projected).
pub fn write_landscape(cfg: &RunConfig, dir: &Path, outcome: &mut coadapt::RunOutcome) -> anyhow::Result<()> {
    let n = cfg.landscape_grid;
    if n == 0 || outcome.designs.is_empty() {
        return Ok(());
    }
    let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
    let dim = spec.design_dim();
    let designs: Vec<f32> = outcome.designs.iter().flat_map(|d| d.design.clone()).collect();
    let pca = Pca2::fit(&designs, dim)?;
    let grid = landscape::grid(&pca, &designs, &spec.design, n)?;
    let learner: &mut FearLearner = &mut outcome.learner;
    let Some(states) = learner.sample_start_states(cfg.landscape_start_states.max(1)) else { return Ok(()) };
    let pop = learner.agent(ActingPolicy::Population);
    let objective =
        DesignObjective::new(pop.policy(), pop.policy_params(), pop.critic(), &[pop.critic_params(0).0], &states, spec.state_dim, dim)?;
    let mut scores = vec![0.0; n * n];
    CriticObjective::new(&objective, QMode::First, 2).evaluate(&grid.designs, &mut scores);
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("landscape.csv"))?);
    writeln!(f, "pc1,pc2,objective")?;
    for (pc, s) in grid.pc.iter().zip(&scores) {
        writeln!(f, "{},{},{}", pc[0], pc[1], s)?;
    }
    f.flush()?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("landscape_designs.csv"))?);
    writeln!(f, "index,kind,pc1,pc2")?;
    for d in &outcome.designs {
        let p = pca.project(&d.design);
        writeln!(f, "{},{},{},{}", d.index, d.kind, p[0], p[1])?;
    }
    f.flush()?;
    Ok(())
}

/// `runs/<name>-seed<seed>`, or with `-2`, `-3`, ... appended when that already holds a run, so
/// running the same command again never overwrites or refuses.
pub fn default_out(name: &str, seed: u64) -> PathBuf {
    let base = PathBuf::from("runs").join(format!("{name}-seed{seed}"));
    let mut dir = base.clone();
    let mut i = 2;
    while dir.join("designs.csv").exists() {
        dir = PathBuf::from(format!("{}-{i}", base.display()));
        i += 1;
    }
    dir
}

/// What a finished learner leaves besides its rows: the design landscape, the plots, and the
/// one JSON summary line on stdout.
pub fn finish(cfg: &RunConfig, dir: &Path, outcome: &mut coadapt::RunOutcome, shutdown: &AtomicBool, start: Instant) -> anyhow::Result<()> {
    if let Err(e) = write_landscape(cfg, dir, outcome) {
        coadapt_log::logln!("warning: design landscape not written: {e:#}");
    }
    let interrupted = outcome.interrupted || shutdown.load(Ordering::Relaxed);
    let plots = match crate::plot::draw_run(dir) {
        Ok(p) => p,
        // Stopped before anything was learned (say, Ctrl-C while the first prototype was
        // awaited): the summary still says where the run got to.
        Err(e) if interrupted => {
            coadapt_log::logln!("warning: no plots: {e:#}");
            Vec::new()
        }
        Err(e) => return Err(e.context("drawing the plots")),
    };
    for p in &plots {
        coadapt_log::logln!("wrote {}", p.display());
    }
    let best = outcome.designs.iter().filter_map(|d| d.best_eval_return.map(|r| (r, d))).max_by(|a, b| a.0.total_cmp(&b.0));
    let t = outcome.time;
    let summary = serde_json::json!({
        "run_dir": dir.display().to_string(),
        "env": cfg.env,
        "exploit": cfg.optimizer.exploit.name(),
        "transport": cfg.fleet.transport.name(),
        "designs": outcome.designs.len(),
        "interrupted": interrupted,
        "best_eval_return": best.map(|b| b.0),
        "best_design": best.map(|b| b.1.design.clone()),
        "design_rollouts": outcome.designs.iter().map(|d| d.design_rollouts).sum::<u64>(),
        "seconds": start.elapsed().as_secs_f64(),
        "learner_waiting_seconds": t.waiting,
        "learner_sending_seconds": t.sending,
        "learner_training_seconds": t.training,
        "episodes_reissued": t.reissued,
        "episodes_restarted": t.restarted,
        "design_requests_resent": t.design_requests_resent,
        "design_replies_refused": t.design_replies_refused,
        "episodes_rejected": t.episodes_rejected,
        "rollbacks": t.rollbacks,
        "max_policy_lag": t.max_policy_lag,
        // The prototype step (schedule.confirm-designs, schedule.reset-needs-confirmation).
        "prototype_waiting_seconds": t.waiting_for_prototype,
        "reset_waiting_seconds": t.waiting_for_reset,
        "prototypes_rejected": outcome.rejected.len(),
        "population_updates_while_waiting": t.updates_while_waiting,
        // Every transition in the replay, and every episode start: only whole episodes get in.
        "replay_transitions": outcome.learner.population_transitions(),
        "start_states": outcome.learner.start_states(),
    });
    print_stdout_line(&summary.to_string());
    Ok(())
}

/// `coadapt run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let (mut cfg, name) = resolve(&args)?;
    let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
    resolve_initial_designs(&mut cfg, &spec);
    check(&cfg, &spec)?;
    let resume = args.resume.is_some();
    let dir = match &args.resume {
        Some(d) => {
            crate::resume::check_compatible(&crate::resume::stored_config(d)?, &cfg)?;
            d.clone()
        }
        None => args.out.clone().unwrap_or_else(|| default_out(&name, cfg.seed)),
    };
    if !resume && dir.join("designs.csv").exists() {
        bail!("{} already holds a run (designs.csv exists); choose another --out, or --resume it", dir.display());
    }
    let shutdown = shutdown_on_ctrl_c();
    coadapt_log::logln!(
        "coadapt run: {} on {}, {} designs ({} episodes), exploit {}, explore {}, {} actor(s) over {}, into {}",
        name,
        cfg.env,
        cfg.schedule.designs,
        cfg.schedule.total_episodes(),
        cfg.optimizer.exploit.name(),
        if cfg.schedule.alternate { format!("{:?}", cfg.optimizer.explore).to_lowercase() } else { "none".into() },
        cfg.actors,
        cfg.fleet.transport.name(),
        dir.display()
    );
    if cfg.fleet.transport != TransportKind::InProcess {
        return crate::launch::launch(&cfg, &dir, &shutdown, resume);
    }
    let start = Instant::now();
    let mut outcome = run_config(&cfg, &dir, &shutdown, resume)?;
    finish(&cfg, &dir, &mut outcome, &shutdown, start)
}
