//! `coadapt run`: a whole co-adaptation (FEAR or a baseline) on one robot, with the learner,
//! the design optimiser and the actors as separate roles talking through the in-process
//! transport (one thread each).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use coadapt_actors::{Actor, PolicyKind};
use coadapt_core::{Env, EnvSpec};
use coadapt_design_optimizer::landscape::{self, Pca2};
use coadapt_design_optimizer::role::{
    self as optimizer, ExploitMethod, ExploreMethod, Optimizer, OptimizerConfig, OptimizerSpec, RolloutEvaluator,
};
use coadapt_design_optimizer::{CriticObjective, DesignObjective, QMode, SwarmObjective};
use coadapt_learner::coadapt::{self, RunEvent, ScheduleConfig};
use coadapt_learner::fear::{ActingPolicy, FearLearner, FearLearnerConfig};
use coadapt_learner::networks;
use coadapt_transport::in_process;
use serde::{Deserialize, Serialize};

use crate::progress::{duration, print_stdout_line, shutdown_on_ctrl_c};

/// The reference protocol on HalfCheetah, used when no `--config` is given.
pub const DEFAULT_CONFIG: &str = include_str!("../../configs/half-cheetah-reference.toml");

/// Everything a co-adaptation run needs; the TOML file's layout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct RunConfig {
    /// The robot (pendulum, half-cheetah, walker, hopper, daisy).
    pub env: String,
    /// Seed of every random stream: the same seed and config give the same run.
    pub seed: u64,
    /// Actor threads running episodes (the lock-step schedule uses one at a time).
    pub actors: usize,
    /// Transitions per experience chunk an actor sends.
    pub chunk_len: usize,
    /// Threads running the simulation baselines' rollouts.
    pub sim_threads: usize,
    /// Points per side of the design-landscape grid drawn at the end (0: no landscape).
    pub landscape_grid: usize,
    pub schedule: ScheduleConfig,
    pub learner: FearLearnerConfig,
    pub optimizer: OptimizerConfig,
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
            schedule: ScheduleConfig::default(),
            learner: FearLearnerConfig::default(),
            optimizer: OptimizerConfig::default(),
        }
    }
}

/// Run a whole co-adaptation: design after design, train the controller and choose the next body.
///
/// The run directory gets the resolved `config.toml`, `designs.csv` (one row per design: kind,
/// design vector, episodes, best and last evaluation return, the design objective predicted for
/// it, design rollouts spent), `episodes.csv`, `checkpoints/` (population and individual
/// networks after each design), `landscape.csv` and `plots/*.svg` (learning curves, best return
/// over designs, design landscape). Rows are flushed as they are written: Ctrl-C stops after
/// the current episode and keeps everything.
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
    /// cmaes-es, random.
    #[arg(long)]
    pub exploit: Option<String>,
    /// Override the exploration method: random or novelty.
    #[arg(long)]
    pub explore: Option<String>,
    /// Override the number of designs.
    #[arg(long)]
    pub designs: Option<usize>,
}

fn parse_enum<T: serde::de::DeserializeOwned>(flag: &str, v: &str) -> anyhow::Result<T> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(v)).map_err(|e| anyhow::anyhow!("--{flag} {v}: {e}"))
}

/// Reads the config: embedded default, or `--config`, then the flags.
pub fn resolve(args: &RunArgs) -> anyhow::Result<(RunConfig, String)> {
    let (text, name) = match &args.config {
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

fn check(cfg: &RunConfig, spec: &EnvSpec) -> anyhow::Result<()> {
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
        spec.design.check_finite("design", d).map_err(|e| anyhow::anyhow!("schedule.initial-designs[{i}]: {e}"))?;
    }
    Ok(())
}

/// Simulation rollouts for the baselines: one deterministic episode of the population policy
/// per design, fitness the mean per-step reward; designs are shared out over the threads.
struct SimEvaluator {
    actors: Vec<Actor<Box<dyn Env>>>,
    version: u64,
    seed: u64,
}

impl RolloutEvaluator for SimEvaluator {
    fn evaluate(&mut self, policy: &[f32], designs: &[f32], fitness: &mut [f32]) -> Result<(), String> {
        self.version += 1;
        let dim = designs.len() / fitness.len().max(1);
        let per = fitness.len().div_ceil(self.actors.len());
        let (version, seed) = (self.version, self.seed);
        std::thread::scope(|s| {
            let jobs: Vec<_> = self
                .actors
                .iter_mut()
                .zip(fitness.chunks_mut(per.max(1)))
                .zip(designs.chunks(per.max(1) * dim))
                .map(|((actor, fit), des)| {
                    s.spawn(move || -> Result<(), String> {
                        actor.set_weights(version, policy).map_err(|e| e.to_string())?;
                        for (f, d) in fit.iter_mut().zip(des.chunks_exact(dim)) {
                            let st = actor
                                .run_episode(seed, d, false, &mut |_| std::ops::ControlFlow::Continue(()))
                                .map_err(|e| e.to_string())?;
                            *f = st.episode_return / st.length.max(1) as f32;
                        }
                        Ok(())
                    })
                })
                .collect();
            jobs.into_iter().try_for_each(|j| j.join().map_err(|_| "a rollout thread panicked".to_string())?)
        })
    }
}

fn make_env(name: &str) -> anyhow::Result<Box<dyn Env>> {
    Ok(coadapt_robots::make(name)?)
}

/// Runs the co-adaptation described by `cfg` into `dir`.
pub fn run_config(cfg: &RunConfig, dir: &Path, shutdown: &AtomicBool) -> anyhow::Result<coadapt::RunOutcome> {
    let spec = make_env(&cfg.env)?.spec().clone();
    check(cfg, &spec)?;
    let hidden = &cfg.learner.sac.hidden;
    let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), hidden)?;
    let critic = networks::critic(spec.obs_dim(), spec.act_dim(), hidden)?;
    let mut writer =
        coadapt_learner::run_dir::RunWriter::create(dir).with_context(|| format!("creating run directory {}", dir.display()))?;
    std::fs::write(dir.join("config.toml"), toml::to_string(cfg)?).context("writing config.toml")?;
    let (mut learner_links, actor_links, mut optimizer_links) = in_process::fleet(cfg.actors);
    let total_episodes = cfg.schedule.total_episodes();
    let start = Instant::now();
    let mut done_episodes = 0usize;
    let designs_total = cfg.schedule.designs;
    let mut on_event = |e: &RunEvent<'_>| match e {
        RunEvent::DesignStart { index, row } => {
            let pred = row.predicted_objective.map(|p| format!(", predicted objective {p:.3}")).unwrap_or_default();
            let rollouts = if row.design_rollouts > 0 { format!(", {} design rollouts", row.design_rollouts) } else { String::new() };
            eprintln!(
                "design {}/{designs_total} [{} {}] {:?}{pred}{rollouts}",
                index + 1,
                row.kind,
                row.method,
                row.design.iter().map(|v| (v * 1000.0).round() / 1000.0).collect::<Vec<_>>()
            );
        }
        RunEvent::Episode { row, episodes_in_design } => {
            done_episodes += 1;
            let el = start.elapsed().as_secs_f64();
            let eta = el / done_episodes as f64 * (total_episodes.saturating_sub(done_episodes)) as f64;
            let eval = row.eval_return.map(|r| format!(" eval {r:8.2}")).unwrap_or_default();
            eprintln!(
                "  design {}/{designs_total} episode {:>4}/{episodes_in_design} return {:8.2}{eval}  [{} elapsed, ETA {}]",
                row.design + 1,
                row.episode + 1,
                row.train_return,
                duration(el),
                duration(eta)
            );
        }
        RunEvent::DesignEnd { row } => {
            let f = |v: Option<f32>| v.map_or("-".into(), |v| format!("{v:.2}"));
            eprintln!("design {} done: best eval {}, last eval {}", row.index + 1, f(row.best_eval_return), f(row.last_eval_return));
        }
    };
    let outcome = std::thread::scope(|s| -> anyhow::Result<coadapt::RunOutcome> {
        let mut actor_threads = Vec::new();
        for (i, mut links) in actor_links.into_iter().enumerate() {
            let (policy, name, seed, chunk) = (policy.clone(), cfg.env.clone(), cfg.seed, cfg.chunk_len);
            actor_threads.push(s.spawn(move || -> anyhow::Result<()> {
                let mut actor = Actor::new(make_env(&name)?, policy, PolicyKind::SquashedGaussian, seed.wrapping_add(i as u64))?;
                coadapt_actors::role::run(&mut actor, &mut links, chunk, shutdown).with_context(|| format!("actor {i}"))?;
                Ok(())
            }));
        }
        let ospec = OptimizerSpec {
            policy: policy.clone(),
            critic: critic.clone(),
            bounds: spec.design.clone(),
            design_at: spec.state_dim,
            obs_dim: spec.obs_dim(),
            act_dim: spec.act_dim(),
        };
        let ocfg = cfg.optimizer.clone();
        let (name, seed, threads) = (cfg.env.clone(), cfg.seed, cfg.sim_threads.max(1));
        let pol = policy.clone();
        let opt_thread = s.spawn(move || -> anyhow::Result<()> {
            let mut sim = if ocfg.exploit.needs_rollouts() {
                let actors = (0..threads)
                    .map(|i| Ok(Actor::new(make_env(&name)?, pol.clone(), PolicyKind::SquashedGaussian, seed ^ (0x5349_4d00 + i as u64))?))
                    .collect::<anyhow::Result<Vec<_>>>()?;
                Some(SimEvaluator { actors, version: 0, seed })
            } else {
                None
            };
            let mut opt = Optimizer::new(ocfg, ospec, sim.as_mut().map(|s| s as &mut dyn RolloutEvaluator), seed)?;
            optimizer::run(&mut opt, &mut optimizer_links, shutdown).context("design optimiser")?;
            Ok(())
        });
        let result = coadapt::run(&cfg.schedule, &cfg.learner, &spec, cfg.seed, &mut learner_links, &mut writer, shutdown, &mut on_event);
        // Closing the learner's channels lets the other roles finish.
        drop(learner_links);
        let mut errors = Vec::new();
        for t in actor_threads.into_iter().map(|t| t.join()).chain(std::iter::once(opt_thread.join())) {
            match t {
                Ok(Ok(())) => {}
                Ok(Err(e)) => errors.push(format!("{e:#}")),
                Err(_) => errors.push("a role thread panicked".into()),
            }
        }
        match result {
            Ok(o) => {
                if let Some(e) = errors.first() {
                    eprintln!("warning: {e}");
                }
                Ok(o)
            }
            Err(e) => match errors.first() {
                Some(first) => Err(anyhow::anyhow!("{e} (first role failure: {first})")),
                None => Err(e.into()),
            },
        }
    })?;
    Ok(outcome)
}

/// Scores the design objective on a grid over the first two principal components of the
/// designs tried (thesis Fig. 5.9) with the final population networks, and writes
/// `landscape.csv` (pc1, pc2, objective) and `landscape_designs.csv` (the designs, projected).
pub fn write_landscape(cfg: &RunConfig, dir: &Path, outcome: &mut coadapt::RunOutcome) -> anyhow::Result<()> {
    let n = cfg.landscape_grid;
    if n == 0 || outcome.designs.is_empty() {
        return Ok(());
    }
    let spec = make_env(&cfg.env)?.spec().clone();
    let dim = spec.design_dim();
    let designs: Vec<f32> = outcome.designs.iter().flat_map(|d| d.design.clone()).collect();
    let pca = Pca2::fit(&designs, dim)?;
    let grid = landscape::grid(&pca, &designs, &spec.design, n)?;
    let learner: &mut FearLearner = &mut outcome.learner;
    let Some(states) = learner.sample_start_states(cfg.schedule.start_state_batch.max(1)) else { return Ok(()) };
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
fn default_out(name: &str, seed: u64) -> PathBuf {
    let base = PathBuf::from("runs").join(format!("{name}-seed{seed}"));
    let mut dir = base.clone();
    let mut i = 2;
    while dir.join("designs.csv").exists() {
        dir = PathBuf::from(format!("{}-{i}", base.display()));
        i += 1;
    }
    dir
}

/// `coadapt run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let (mut cfg, name) = resolve(&args)?;
    let spec = make_env(&cfg.env)?.spec().clone();
    resolve_initial_designs(&mut cfg, &spec);
    let dir = args.out.clone().unwrap_or_else(|| default_out(&name, cfg.seed));
    if dir.join("designs.csv").exists() {
        bail!("{} already holds a run (designs.csv exists); choose another --out", dir.display());
    }
    let shutdown = shutdown_on_ctrl_c();
    eprintln!(
        "coadapt run: {} on {}, {} designs ({} episodes), exploit {}, explore {}, into {}",
        name,
        cfg.env,
        cfg.schedule.designs,
        cfg.schedule.total_episodes(),
        cfg.optimizer.exploit.name(),
        if cfg.schedule.alternate { format!("{:?}", cfg.optimizer.explore).to_lowercase() } else { "none".into() },
        dir.display()
    );
    let start = Instant::now();
    let mut outcome = run_config(&cfg, &dir, &shutdown)?;
    if let Err(e) = write_landscape(&cfg, &dir, &mut outcome) {
        eprintln!("warning: design landscape not written: {e:#}");
    }
    let plots = crate::plot::draw_run(&dir).context("drawing the plots")?;
    for p in &plots {
        eprintln!("wrote {}", p.display());
    }
    let best = outcome.designs.iter().filter_map(|d| d.best_eval_return.map(|r| (r, d))).max_by(|a, b| a.0.total_cmp(&b.0));
    let summary = serde_json::json!({
        "run_dir": dir.display().to_string(),
        "env": cfg.env,
        "exploit": cfg.optimizer.exploit.name(),
        "designs": outcome.designs.len(),
        "interrupted": outcome.interrupted || shutdown.load(Ordering::Relaxed),
        "best_eval_return": best.map(|b| b.0),
        "best_design": best.map(|b| b.1.design.clone()),
        "design_rollouts": outcome.designs.iter().map(|d| d.design_rollouts).sum::<u64>(),
        "seconds": start.elapsed().as_secs_f64(),
    });
    print_stdout_line(&summary.to_string());
    Ok(())
}
