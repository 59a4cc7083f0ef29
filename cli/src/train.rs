//! `coadapt train`: RL on one environment and one fixed design.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use coadapt_learner::train::{self, LatentExploration, TrainConfig, UpdateSchedule};
use coadapt_learner::{Algo, Exploration};

use crate::progress::shutdown_on_ctrl_c;
use coadapt_log::duration;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ExplorationArg {
    Ou,
    Gaussian,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum UpdateScheduleArg {
    PerStep,
    PerEpisode,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum AlgoArg {
    Sac,
    Ddpg,
}

/// Train a controller with SAC or DDPG on one environment and one fixed design.
///
/// Writes a run directory with the resolved `config.toml`, `episodes.csv` (one row per episode,
/// flushed as it goes) and `checkpoint.safetensors`; prints progress to stderr and one JSON
/// summary line to stdout. Settings come from the defaults, then `--config`, then the flags.
/// `--friction`, `--actuator-scale` and `--torso-mass-scale` (the config's `[world]`) put the
/// robot in another world (thesis 6.1), e.g. to train plain SAC on the floor a transfer run
/// targets.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// TOML settings file: top-level keys (steps, seed, learning-starts, ...) plus [sac] and
    /// [ddpg] tables; the resolved config.toml of a run directory is a valid example.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Environment to train on: pendulum, half-cheetah, walker, hopper, daisy, or a remote one
    /// served over dm_env_rpc, dm-env-rpc://HOST:PORT (e.g. `coadapt-gym-serve --env
    /// Pendulum-v1` or `coadapt env-serve`).
    #[arg(long)]
    pub env: Option<String>,
    /// TLS and the actor's token for a remote environment across machines (--tls-ca,
    /// --token-file or COADAPT_TOKEN, --client-cert/--client-key).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
    /// Learning algorithm.
    #[arg(long, value_enum)]
    pub algo: Option<AlgoArg>,
    /// Environment steps to run.
    #[arg(long)]
    pub steps: Option<u64>,
    /// Seed of every random stream (same seed, same run).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Design vector, comma-separated (default: the environment's original design).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub design: Option<Vec<f32>>,
    /// Hidden layer widths of every network, comma-separated (e.g. 256,256).
    #[arg(long, value_delimiter = ',')]
    pub hidden: Option<Vec<usize>>,
    /// SAC entropy coefficient: a positive number, or `auto` for automatic tuning.
    #[arg(long, allow_hyphen_values = true)]
    pub alpha: Option<String>,
    /// DDPG exploration noise: Ornstein-Uhlenbeck (the thesis's default, sigma 0.5, theta 0.15)
    /// or Gaussian. OU at sigma 0.5 is nearly random on Pendulum: there use
    /// `--exploration gaussian --sigma 0.1`.
    #[arg(long, value_enum)]
    pub exploration: Option<ExplorationArg>,
    /// DDPG noise scale (OU sigma or Gaussian standard deviation).
    #[arg(long)]
    pub sigma: Option<f32>,
    /// Steps of uniform random actions before learning starts.
    #[arg(long)]
    pub learning_starts: Option<u64>,
    /// When to take the gradient steps: `per-step` (SAC's loop, the default) or `per-episode`
    /// (the same number, all at the episode's end, as FEAR's learner does).
    #[arg(long, value_enum)]
    pub update_schedule: Option<UpdateScheduleArg>,
    /// Report the first step at which the mean return of the last 10 episodes exceeds this.
    #[arg(long, allow_negative_numbers = true)]
    pub target_return: Option<f32>,
    /// Stop once `--target-return` is reached.
    #[arg(long)]
    pub stop_at_target: bool,
    /// Start from the networks of this checkpoint (e.g. runs/.../checkpoint.safetensors).
    #[arg(long)]
    pub init_weights: Option<PathBuf>,
    /// SAC: explore with correlated noise through this learned action space (an
    /// action_space.safetensors of `coadapt action-space`, thesis 6.2): the policy's mean action
    /// plus beta (d(z, s, xi) - d(0, s, xi)), z ~ N(0, I) at every step, instead of sampling the
    /// policy's Gaussian (sets latent-exploration.action-space).
    #[arg(long, value_name = "FILE")]
    pub latent_exploration: Option<PathBuf>,
    /// The latent perturbation's scale beta (sets latent-exploration.beta; default 0.5).
    #[arg(long, requires = "latent_exploration")]
    pub latent_beta: Option<f32>,
    /// SAC's matrix products (sets sac.precision): f32 (the default), or bf16 (bfloat16
    /// operands with f32 accumulation where the CPU has AVX-512 BF16 or AMX).
    #[arg(long, value_name = "f32|bf16")]
    pub precision: Option<coadapt_nn::Precision>,
    /// The world the robot trains in (sets world.friction, world.actuator-scale,
    /// world.torso-mass-scale; thesis 6.1): plain RL on a body in another world.
    #[command(flatten)]
    pub world: crate::world_args::WorldArgs,
    /// Run directory (default: runs/<env>-<algo>-seed<seed>-<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print no per-episode progress.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Defaults, then the config file, then the flags.
pub fn resolve(args: &TrainArgs) -> anyhow::Result<TrainConfig> {
    let mut cfg = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path).with_context(|| format!("reading config {}", path.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing config {}", path.display()))?
        }
        None => TrainConfig::default(),
    };
    if let Some(env) = &args.env {
        cfg.env = env.clone();
    }
    if let Some(a) = args.algo {
        cfg.algo = match a {
            AlgoArg::Sac => Algo::Sac,
            AlgoArg::Ddpg => Algo::Ddpg,
        };
    }
    if let Some(s) = args.steps {
        cfg.steps = s;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    if let Some(d) = &args.design {
        cfg.design = Some(d.clone());
    }
    if let Some(h) = &args.hidden {
        cfg.sac.hidden = h.clone();
        cfg.ddpg.hidden = h.clone();
    }
    if let Some(a) = &args.alpha {
        if a == "auto" {
            cfg.sac.auto_alpha = true;
        } else {
            let v: f32 = a.parse().map_err(|_| anyhow::anyhow!("--alpha: `{a}` is neither a number nor `auto`"))?;
            if !(v.is_finite() && v > 0.0) {
                bail!("--alpha: {v} must be positive");
            }
            cfg.sac.alpha = v;
            cfg.sac.auto_alpha = false;
        }
    }
    if let Some(e) = args.exploration {
        cfg.ddpg.exploration = match e {
            ExplorationArg::Ou => Exploration::OrnsteinUhlenbeck,
            ExplorationArg::Gaussian => Exploration::Gaussian,
        };
    }
    if let Some(s) = args.sigma {
        if !(s.is_finite() && s >= 0.0) {
            bail!("--sigma: {s} must be a non-negative number");
        }
        cfg.ddpg.sigma = s;
    }
    if let Some(l) = args.learning_starts {
        cfg.learning_starts = l;
    }
    if let Some(p) = args.precision {
        cfg.sac.precision = p;
    }
    if let Some(u) = args.update_schedule {
        cfg.update_schedule = match u {
            UpdateScheduleArg::PerStep => UpdateSchedule::PerStep,
            UpdateScheduleArg::PerEpisode => UpdateSchedule::PerEpisode,
        };
    }
    args.world.apply(&mut cfg.world);
    if let Some(t) = args.target_return {
        cfg.target_return = Some(t);
    }
    if let Some(w) = &args.init_weights {
        cfg.init_weights = Some(w.clone());
    }
    if let Some(file) = &args.latent_exploration {
        let beta = cfg.latent_exploration.as_ref().map_or(0.5, |l| l.beta);
        cfg.latent_exploration = Some(LatentExploration { action_space: file.clone(), beta });
    }
    if let (Some(b), Some(l)) = (args.latent_beta, cfg.latent_exploration.as_mut()) {
        l.beta = b;
    }
    if args.stop_at_target {
        if cfg.target_return.is_none() {
            bail!("--stop-at-target needs --target-return");
        }
        cfg.stop_at_target = true;
    }
    cfg.validate()?;
    Ok(cfg)
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let cfg = resolve(&args)?;
    let security = crate::security::from_args(&args.security);
    let mut env = coadapt_fleet::make_env_with(&cfg.env, &cfg.world, &coadapt_fleet::RemoteEnvConfig::default(), &security)?;
    // Refuse what the run would refuse (a bad design, network sizes, weights) before anything
    // is written: a refused command leaves no run directory behind.
    train::check(&cfg, env.spec()).with_context(|| format!("training {} on {}", cfg.algo, cfg.env))?;
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => {
            let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
            // A remote env's name is an address: keep only what is safe in a file name.
            let env: String = cfg.env.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '-' }).collect();
            PathBuf::from("runs").join(format!("{env}-{}-seed{}-{t}", cfg.algo, cfg.seed))
        }
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating run directory {}", dir.display()))?;
    let resolved = toml::to_string_pretty(&cfg).context("serialising the resolved config")?;
    std::fs::write(dir.join("config.toml"), resolved).with_context(|| format!("writing {}/config.toml", dir.display()))?;
    if !args.quiet {
        coadapt_log::logln!("training {} on {} for {} steps (seed {}) into {}", cfg.algo, cfg.env, cfg.steps, cfg.seed, dir.display());
    }
    let shutdown = shutdown_on_ctrl_c();
    let quiet = args.quiet;
    let total = cfg.steps;
    let summary = train::run(&cfg, env.as_mut(), &dir, &shutdown, &mut |r| {
        if quiet {
            return;
        }
        let rate = r.step as f64 / r.wall_s.max(1e-9);
        coadapt_log::logln!(
            "episode {:>4} | step {:>7}/{total} | return {:>9.1} | mean10 {:>9.1} | {:>6.0} steps/s | ETA {}",
            r.episode,
            r.step,
            r.episode_return,
            r.mean_return_last_10,
            rate,
            duration((total - r.step.min(total)) as f64 / rate.max(1e-9)),
        );
    })
    .with_context(|| format!("training {} on {}", cfg.algo, cfg.env))?;
    coadapt_log::print_stdout_line(&serde_json::to_string(&summary).context("serialising the summary")?);
    Ok(())
}
