//! `coadapt search`: episodic policy search from few rollouts (thesis ch. 2-3) on the bimanual
//! planar reaching benchmark: GrouPS or PoWER, several runs, a run directory like `coadapt
//! run`'s: the resolved `config.toml`, `iterations.csv` (one row per run and iteration: the
//! summed end-effector distance of the mean policy, the best and mean return of the
//! rollouts), `rollouts.csv` (one row per rollout), each run's final M (and W, the synergies) in
//! `run-<r>/policy.safetensors`, and `plots/learning_curve.svg` (mean and standard deviation
//! over runs). With synergies (GrouPS, PePPER): run 0's W and M after every iteration in
//! `run-0/history.safetensors`, `plots/synergies.svg` (W over the iterations, thesis Fig. 3.9)
//! and `plots/synergy_poses.svg` (the arms moved along the two strongest synergies, Fig. 3.10).
//!
//! The rollouts run in this process by default; with `actors = N` they go to N actors over
//! `[fleet] transport` (in-process threads, or `coadapt search-actor` processes over shared
//! memory or gRPC, started here or, with `start-actors = false`, by you on the robots' hosts).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use coadapt_policy_search::{
    EpisodicTask, Groups, GroupsConfig, LinearPolicy, Nac, NacConfig, PlanarReaching, Power, PowerConfig, RolloutRunner, TimeFeatures,
};
use serde::{Deserialize, Serialize};

use coadapt_fleet::{FleetConfig, TransportKind};

/// `coadapt search`'s config (TOML, kebab-case; every key has a default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct SearchConfig {
    /// The task: `planar` (the bimanual planar reaching benchmark, 12 actions x 25 steps).
    pub task: String,
    /// Degrees one unit of the planar task's actions turns a joint: 1 (degrees, the default:
    /// what makes the thesis's exploration variance sensible), 57.29578 (radians), or any scale
    /// between (a probe of the thesis's units).
    pub action_unit_degrees: f64,
    /// `groups` (GrouPS), `pepper` (PePPER: the factor model without priors or groups, resize
    /// sqrt(1.09)), `power` (PoWER) or `nac` (episodic Natural Actor-Critic).
    pub method: String,
    /// Independent runs (seeds seed, seed + 1, ...).
    pub runs: usize,
    /// Iterations per run.
    pub iterations: usize,
    pub seed: u64,
    /// GrouPS's groups of action indices (0-5 the left arm's joints, 6-11 the right's).
    /// Default: Eq. 2.32, joints 1-4 and 5-6 of each arm.
    pub groups: Vec<Vec<usize>>,
    /// GrouPS's settings.
    #[serde(rename = "groups-settings")]
    pub groups_settings: GroupsConfig,
    /// PoWER's settings.
    pub power: PowerConfig,
    /// eNAC's settings.
    pub nac: NacConfig,
    /// GrouPS with reuse of synergies (ch. 3): a `policy.safetensors` or `w-iter<N>.safetensors`
    /// of an earlier search whose W becomes the prior centre W-hat and the starting W (empty:
    /// none, chapter 2).
    pub w_hat: String,
    /// Also save each run's W after this iteration as `run-<r>/w-iter<N>.safetensors` (0: no).
    pub save_w_at: usize,
    /// `plots/synergy_poses.svg` shows the two strongest synergies of run 0 after this
    /// iteration (the thesis found the most useful ones at iterations 7-8).
    pub synergy_iteration: usize,
    /// Where the rollouts run: 0 in this process, one after the other; N > 0 on N actors over
    /// `fleet.transport` (each rollout's actions go out, its transitions and return come back).
    pub actors: usize,
    /// With actors over shm or gRPC: start them here as `coadapt search-actor` processes
    /// (true), or wait for actors started elsewhere, e.g. on robots' hosts (false).
    pub start_actors: bool,
    /// A rollout that sent nothing for this many seconds goes to another actor.
    pub rollout_lease_secs: f64,
    /// An iteration whose rollouts are not all back after this many seconds stops the search.
    pub iteration_deadline_secs: f64,
    /// How the search and its actors talk (`transport`, `name`, `listen`, `connect`, ...:
    /// the `[fleet]` table of a run config).
    pub fleet: FleetConfig,
    /// TLS and tokens of a gRPC fleet (the `[security]` table of a run config).
    pub security: coadapt_fleet::SecurityConfig,
    /// The robot the actors step: empty for the built-in planar robot, or
    /// `dm-env-rpc://HOST:PORT` for one served over dm_env_rpc (`coadapt env-serve --env
    /// planar`, or a real robot's server with the planar task's shape).
    pub robot: String,
    /// Deadlines and retries of a dm_env_rpc robot.
    pub remote: coadapt_fleet::RemoteEnvConfig,
}

impl SearchConfig {
    /// The planar benchmark in the config's units.
    pub fn planar(&self) -> PlanarReaching {
        let mut t = PlanarReaching::default();
        t.geometry.unit_degrees = self.action_unit_degrees;
        t
    }
}

impl Default for SearchConfig {
    fn default() -> Self {
        Self {
            task: "planar".into(),
            action_unit_degrees: 1.0,
            method: "groups".into(),
            runs: 10,
            iterations: 100,
            seed: 1,
            groups: vec![vec![0, 1, 2, 3], vec![4, 5], vec![6, 7, 8, 9], vec![10, 11]],
            groups_settings: GroupsConfig::default(),
            power: PowerConfig::default(),
            nac: NacConfig::default(),
            w_hat: String::new(),
            save_w_at: 0,
            synergy_iteration: 8,
            actors: 0,
            start_actors: true,
            rollout_lease_secs: 60.0,
            iteration_deadline_secs: 3600.0,
            fleet: FleetConfig { transport: TransportKind::InProcess, listen: "127.0.0.1:0".into(), ..FleetConfig::default() },
            security: coadapt_fleet::SecurityConfig::default(),
            robot: String::new(),
            remote: coadapt_fleet::RemoteEnvConfig::default(),
        }
    }
}

/// Policy search from few rollouts on the bimanual planar reaching benchmark.
#[derive(Debug, Args)]
pub struct SearchArgs {
    /// The TOML config (default: GrouPS with 4 groups, 10 runs of 100 iterations).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override `method`: groups, pepper, power or nac.
    #[arg(long)]
    pub method: Option<String>,
    /// Override `runs`.
    #[arg(long)]
    pub runs: Option<usize>,
    /// Override `iterations`.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Override `seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// The run directory (default runs/search-<method>-seed<seed>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override `actors`: run the rollouts on N actors (0: in this process).
    #[arg(long)]
    pub actors: Option<usize>,
    /// Override fleet.transport: in-process (threads), shm or grpc.
    #[arg(long, value_enum)]
    pub transport: Option<TransportKind>,
    /// TLS and tokens of a gRPC fleet (over [security]).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

enum Learner {
    Groups(Box<Groups>),
    Power(Box<Power>),
    Nac(Box<Nac>),
}

impl Learner {
    fn mean(&self) -> &[f64] {
        match self {
            Learner::Groups(g) => &g.m,
            Learner::Power(p) => &p.policy.m,
            Learner::Nac(n) => &n.policy.m,
        }
    }

    /// One iteration; (return, cost) of each rollout.
    fn iterate(&mut self, task: &dyn RolloutRunner, phi: &TimeFeatures) -> anyhow::Result<Vec<(f64, f64)>> {
        Ok(match self {
            Learner::Groups(g) => g.iterate(task, phi)?.into_iter().map(|s| (s.ret, s.cost)).collect(),
            Learner::Power(p) => p.iterate(task, phi)?.into_iter().map(|r| (r.ret, r.cost)).collect(),
            Learner::Nac(n) => n.iterate(task, phi)?.into_iter().map(|r| (r.ret, r.cost)).collect(),
        })
    }
}

fn resolve(a: &SearchArgs) -> anyhow::Result<SearchConfig> {
    let mut cfg: SearchConfig = match &a.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => SearchConfig::default(),
    };
    if let Some(m) = &a.method {
        cfg.method = m.clone();
    }
    if let Some(r) = a.runs {
        cfg.runs = r;
    }
    if let Some(i) = a.iterations {
        cfg.iterations = i;
    }
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    if let Some(n) = a.actors {
        cfg.actors = n;
    }
    if let Some(t) = a.transport {
        cfg.fleet.transport = t;
    }
    cfg.security = crate::security::with_args(cfg.security.clone(), &a.security);
    for (key, v) in [("rollout-lease-secs", cfg.rollout_lease_secs), ("iteration-deadline-secs", cfg.iteration_deadline_secs)] {
        if !(v > 0.0 && v.is_finite()) {
            anyhow::bail!("{key} = {v}: a positive number of seconds");
        }
    }
    if cfg.task != "planar" {
        anyhow::bail!("task: {:?}; only \"planar\" (the bimanual planar reaching benchmark) so far", cfg.task);
    }
    if !(cfg.action_unit_degrees > 0.0 && cfg.action_unit_degrees.is_finite()) {
        anyhow::bail!("action-unit-degrees = {}: a positive number of degrees", cfg.action_unit_degrees);
    }
    if !["groups", "pepper", "power", "nac"].contains(&cfg.method.as_str()) {
        anyhow::bail!("method: {:?}; groups, pepper, power or nac", cfg.method);
    }
    // Settings that would degrade silently (a sampler falling back to another variance, a
    // selection clipped to what exists) are refused, naming the key.
    let p = &cfg.power;
    if cfg.method == "power" {
        if !(p.variance > 0.0 && p.variance.is_finite()) {
            anyhow::bail!("power.variance = {}: must be positive", p.variance);
        }
        if p.best == 0 || p.best > p.rollouts {
            anyhow::bail!("power.best = {}: between 1 and power.rollouts ({})", p.best, p.rollouts);
        }
    }
    if cfg.method == "nac" {
        cfg.nac.check().map_err(|e| anyhow::anyhow!(e))?;
    }
    if cfg.runs == 0 || cfg.iterations == 0 {
        anyhow::bail!("runs and iterations: at least 1 each");
    }
    Ok(cfg)
}

pub fn run(a: SearchArgs) -> anyhow::Result<()> {
    let cfg = resolve(&a)?;
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("runs/search-{}-seed{}", cfg.method, cfg.seed)));
    if out.join("iterations.csv").exists() {
        anyhow::bail!("{} already holds a search (iterations.csv); choose another --out", out.display());
    }
    std::fs::create_dir_all(out.join("plots")).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("config.toml"), toml::to_string(&cfg)?).context("writing config.toml")?;
    let task = cfg.planar();
    let phi = TimeFeatures::thesis(task.steps());
    let d = task.action_dim();
    let fleet = if cfg.actors > 0 { Some(crate::search_fleet::Fleet::start(&cfg, &out)?) } else { None };
    let runner: &dyn RolloutRunner = match &fleet {
        Some(f) => &f.runner,
        None => &task,
    };
    let mut iters = std::io::BufWriter::new(std::fs::File::create(out.join("iterations.csv"))?);
    writeln!(iters, "run,iteration,rollouts,mean_policy_cost,best_return,mean_return,best_cost")?;
    let mut rolls = std::io::BufWriter::new(std::fs::File::create(out.join("rollouts.csv"))?);
    writeln!(rolls, "run,iteration,rollout,return,cost")?;
    let w_hat = if cfg.w_hat.trim().is_empty() {
        None
    } else {
        let k = cfg.groups_settings.latent;
        Some(load_w(Path::new(cfg.w_hat.trim()), d, k).with_context(|| format!("w-hat = {}", cfg.w_hat))?)
    };
    let mut curves: Vec<Vec<f64>> = Vec::new();
    let mut actions = Vec::new();
    for r in 0..cfg.runs {
        let seed = cfg.seed + r as u64;
        let mut learner = match cfg.method.as_str() {
            "groups" => {
                let mut g = Groups::new(cfg.groups_settings.clone(), cfg.groups.clone(), d, phi.len(), seed)
                    .map_err(|e| anyhow::anyhow!("groups: {e}"))?;
                if let Some(w) = &w_hat {
                    // Reuse: the earlier synergies are both the prior's centre and the start.
                    g.w_hat = w.clone();
                    g.w = w.clone();
                }
                Learner::Groups(Box::new(g))
            }
            "pepper" => {
                let all: Vec<usize> = (0..d).collect();
                let settings = GroupsConfig {
                    latent: cfg.groups_settings.latent,
                    inner: cfg.groups_settings.inner,
                    rollouts: cfg.groups_settings.rollouts,
                    best: cfg.groups_settings.best,
                    initial_variance: cfg.groups_settings.initial_variance,
                    ..GroupsConfig::pepper()
                };
                Learner::Groups(Box::new(Groups::new(settings, vec![all], d, phi.len(), seed).map_err(|e| anyhow::anyhow!("pepper: {e}"))?))
            }
            "nac" => {
                Learner::Nac(Box::new(Nac::new(LinearPolicy::zeros(d, phi.len()), cfg.nac.clone(), seed).map_err(|e| anyhow::anyhow!(e))?))
            }
            _ => Learner::Power(Box::new(Power::new(LinearPolicy::zeros(d, phi.len()), cfg.power.clone(), seed))),
        };
        let mut curve = Vec::with_capacity(cfg.iterations + 1);
        let cost_of = |m: &[f64], actions: &mut Vec<f32>| {
            LinearPolicy::actions_of(m, d, &phi, actions);
            task.evaluate(actions).1
        };
        curve.push(cost_of(learner.mean(), &mut actions));
        // Run 0's synergies and mean after every iteration (from the start), for the plots.
        let mut history = crate::search_plot::History::default();
        if r == 0 {
            history.record(&learner_w(&learner), learner.mean());
        }
        let mut total_rollouts = 0;
        for it in 1..=cfg.iterations {
            let got = learner.iterate(runner, &phi).with_context(|| format!("run {r} iteration {it}"))?;
            total_rollouts += got.len();
            for (k, (ret, cost)) in got.iter().enumerate() {
                writeln!(rolls, "{r},{it},{k},{ret},{cost}")?;
            }
            let cost = cost_of(learner.mean(), &mut actions);
            curve.push(cost);
            if r == 0 {
                history.record(&learner_w(&learner), learner.mean());
            }
            let best = got.iter().map(|x| x.0).fold(f64::NEG_INFINITY, f64::max);
            let best_cost = got.iter().map(|x| x.1).fold(f64::INFINITY, f64::min);
            let mean = got.iter().map(|x| x.0).sum::<f64>() / got.len().max(1) as f64;
            writeln!(iters, "{r},{it},{total_rollouts},{cost},{best},{mean},{best_cost}")?;
            if it == cfg.save_w_at
                && let Learner::Groups(g) = &learner
            {
                let dir = out.join(format!("run-{r}"));
                std::fs::create_dir_all(&dir)?;
                save_tensors(&dir.join(format!("w-iter{it}.safetensors")), &[("W".to_string(), vec![d, g.cfg.latent], g.w.clone())])?;
            }
            // Progress every iteration: on a robot an iteration takes minutes.
            coadapt_log::logln!(
                "search: {} run {}/{} iteration {it}/{} ({total_rollouts} rollouts): mean policy's summed distance {cost:.2}, best rollout's return {best:.3}",
                cfg.method,
                r + 1,
                cfg.runs,
                cfg.iterations
            );
        }
        iters.flush()?;
        rolls.flush()?;
        let dir = out.join(format!("run-{r}"));
        std::fs::create_dir_all(&dir)?;
        let mut tensors = vec![("M".to_string(), vec![d, phi.len()], learner.mean().to_vec())];
        if let Learner::Groups(g) = &learner {
            tensors.push(("W".to_string(), vec![d, g.cfg.latent], g.w.clone()));
        }
        save_tensors(&dir.join("policy.safetensors"), &tensors)?;
        if let (0, Learner::Groups(g)) = (r, &learner) {
            let (n, k) = (history.m.len(), g.cfg.latent);
            save_tensors(
                &dir.join("history.safetensors"),
                &[("W".to_string(), vec![n, d, k], history.w.concat()), ("M".to_string(), vec![n, d, phi.len()], history.m.concat())],
            )?;
            crate::search_plot::synergies(&out.join("plots/synergies.svg"), &history, d, k)?;
            let at = cfg.synergy_iteration.min(cfg.iterations);
            crate::search_plot::synergy_poses(&out.join("plots/synergy_poses.svg"), &history, at, d, k, &phi, &task)?;
        }
        curves.push(curve);
    }
    if let Some(f) = fleet {
        f.finish();
    }
    crate::search_plot::draw(&out.join("plots/learning_curve.svg"), &cfg, &curves)?;
    let last: Vec<f64> = curves.iter().map(|c| c[c.len() - 1]).collect();
    let mean = last.iter().sum::<f64>() / last.len() as f64;
    let sd = (last.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (last.len().max(2) - 1) as f64).sqrt();
    let summary = serde_json::json!({"method": cfg.method, "runs": cfg.runs, "iterations": cfg.iterations,
        "final_mean_policy_cost_mean": mean, "final_mean_policy_cost_sd": sd, "out": out.display().to_string()});
    coadapt_log::print_stdout_line(&summary.to_string());
    Ok(())
}

/// The learner's W (empty for methods without synergies).
fn learner_w(l: &Learner) -> Vec<f64> {
    match l {
        Learner::Groups(g) => g.w.clone(),
        _ => Vec::new(),
    }
}

/// The tensor `W` (`d x k`, F64) of a file written by `coadapt search`.
fn load_w(path: &Path, d: usize, k: usize) -> anyhow::Result<Vec<f64>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let st = safetensors::SafeTensors::deserialize(&bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let t = st.tensor("W").map_err(|e| anyhow::anyhow!("{}: no tensor W ({e})", path.display()))?;
    if t.dtype() != safetensors::Dtype::F64 || t.shape() != [d, k] {
        anyhow::bail!("{}: W is {:?} {:?}; expected F64 [{d}, {k}] (the same latent dimension)", path.display(), t.dtype(), t.shape());
    }
    let w: Vec<f64> = t.data().chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8]))).collect();
    if let Some(i) = w.iter().position(|v| !v.is_finite()) {
        anyhow::bail!("{}: W[{}, {}] is not finite", path.display(), i / k, i % k);
    }
    Ok(w)
}

/// `(name, shape, values)` as F64 tensors in one safetensors file.
fn save_tensors(path: &Path, tensors: &[(String, Vec<usize>, Vec<f64>)]) -> anyhow::Result<()> {
    let bytes: Vec<Vec<u8>> = tensors.iter().map(|(_, _, v)| v.iter().flat_map(|x| x.to_le_bytes()).collect()).collect();
    let views = tensors
        .iter()
        .zip(&bytes)
        .map(|((name, shape, _), b)| {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F64, shape.clone(), b).map(|v| (name.clone(), v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let buf = safetensors::serialize(views, None).map_err(|e| anyhow::anyhow!("{e}"))?;
    std::fs::write(path, buf).with_context(|| format!("writing {}", path.display()))
}
