//! Reinforcement learning on one environment and one fixed design: `coadapt train`.
//!
//! The schedule is Stable-Baselines3's off-policy loop: uniform random actions for the first
//! `learning-starts` steps, then one environment step and `updates-per-step` gradient steps.
//! With `update-schedule = "per-episode"` the same gradient steps are taken in one burst when
//! the episode ends, with the policy fixed during the episode: FEAR's schedule on one body
//! (its learner trains after each episode), to tell the burst apart from the rest of FEAR.
//! Every finished episode is appended (and flushed) to `episodes.csv` in the run directory and
//! to a TensorBoard event file beside it (`episode/*`, `loss/*`, `train/updates`, `time/seconds`
//! at step = the episode's number), and
//! the agent is checkpointed at the end and every `checkpoint-every` episodes, so a crash loses
//! at most the episodes since the last checkpoint.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use coadapt_core::{Batch, Env, EnvError, ReplayBuffer, ReplayError, Transition, rng};
use coadapt_nn::NnError;
use serde::{Deserialize, Serialize};

use crate::{Agent, Algo, Ddpg, DdpgConfig, Sac, SacConfig};

/// Settings of one training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct TrainConfig {
    /// Environment registry name.
    pub env: String,
    pub algo: Algo,
    /// Environment steps to run.
    pub steps: u64,
    pub seed: u64,
    /// The body to train on; the environment's original design when absent.
    pub design: Option<Vec<f32>>,
    /// `[world]`: the dynamics the robot meets (friction, actuator strength, torso mass; thesis
    /// 6.1), each the robot's own by default. The caller builds the environment in it.
    pub world: coadapt_robots::World,
    /// Steps of uniform random actions before learning starts.
    pub learning_starts: u64,
    /// Gradient steps per environment step once learning has started.
    pub updates_per_step: u32,
    /// When those gradient steps are taken: after every step, or all of an episode's at its end.
    pub update_schedule: UpdateSchedule,
    pub replay_capacity: usize,
    /// Save a checkpoint every this many episodes (0: only at the end).
    pub checkpoint_every: u64,
    /// Report the first step at which the mean return of the last 10 episodes exceeds this.
    pub target_return: Option<f32>,
    /// Stop as soon as `target-return` is reached.
    pub stop_at_target: bool,
    /// Start from the networks in this checkpoint (a `checkpoint.safetensors` of an earlier run
    /// with the same algorithm and shapes) instead of a fresh initialisation.
    pub init_weights: Option<PathBuf>,
    /// Episodes in a row that may fail in the environment (a remote robot that went away, a
    /// non-finite observation) before training stops; a failed episode's transitions are
    /// taken back out of the replay buffer and the episode is run again.
    pub env_retries: u32,
    /// SAC only: explore with correlated noise through a learned action space (thesis 6.2)
    /// instead of sampling the policy's Gaussian (absent: SAC's own exploration).
    pub latent_exploration: Option<LatentExploration>,
    pub sac: SacConfig,
    pub ddpg: DdpgConfig,
}

/// `[latent-exploration]`: act with the policy's mean action plus
/// `beta (d(z, o) - d(0, o))`, `z ~ N(0, I)` drawn at every step, `d` the decoder of an action
/// autoencoder written by `coadapt action-space` (its observation and action widths must be
/// this environment's).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct LatentExploration {
    /// The autoencoder's file (`action_space.safetensors`).
    pub action_space: PathBuf,
    /// The perturbation's scale.
    #[serde(default = "default_beta")]
    pub beta: f32,
}

fn default_beta() -> f32 {
    0.5
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            env: "pendulum".into(),
            algo: Algo::Sac,
            steps: 20_000,
            seed: 1,
            design: None,
            world: coadapt_robots::World::default(),
            learning_starts: 100,
            updates_per_step: 1,
            update_schedule: UpdateSchedule::PerStep,
            replay_capacity: 1_000_000,
            checkpoint_every: 50,
            target_return: None,
            stop_at_target: false,
            init_weights: None,
            env_retries: 5,
            latent_exploration: None,
            sac: SacConfig::default(),
            ddpg: DdpgConfig::default(),
        }
    }
}

/// When `coadapt train` takes its gradient steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum UpdateSchedule {
    /// `updates-per-step` after every environment step (SAC's and Stable-Baselines3's loop).
    #[default]
    PerStep,
    /// The episode's `updates-per-step` x steps after its last step, on the buffer as it is
    /// then (FEAR's learner trains this way between episodes).
    PerEpisode,
}

impl TrainConfig {
    /// Rejects impossible values, naming the field.
    pub fn validate(&self) -> Result<(), TrainError> {
        let bad = |field: &'static str, why: String| Err(TrainError::Config { field, why });
        if self.steps == 0 {
            return bad("steps", "must be at least 1".into());
        }
        if self.replay_capacity == 0 {
            return bad("replay-capacity", "must be at least 1".into());
        }
        if self.updates_per_step == 0 {
            return bad("updates-per-step", "must be at least 1".into());
        }
        let (hidden, batch, gamma, tau, lrs) = match self.algo {
            Algo::Sac => (&self.sac.hidden, self.sac.batch_size, self.sac.gamma, self.sac.tau, [self.sac.policy_lr, self.sac.critic_lr]),
            Algo::Ddpg => {
                (&self.ddpg.hidden, self.ddpg.batch_size, self.ddpg.gamma, self.ddpg.tau, [self.ddpg.actor_lr, self.ddpg.critic_lr])
            }
        };
        if hidden.is_empty() || hidden.contains(&0) {
            return bad("hidden", format!("{hidden:?}: needs at least one layer, all widths positive"));
        }
        if batch == 0 {
            return bad("batch-size", "must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&gamma) {
            return bad("gamma", format!("{gamma} is outside [0, 1]"));
        }
        if !(0.0..=1.0).contains(&tau) {
            return bad("tau", format!("{tau} is outside [0, 1]"));
        }
        if lrs.iter().any(|lr| !(lr.is_finite() && *lr > 0.0)) {
            return bad("learning rate", format!("{lrs:?}: learning rates must be positive"));
        }
        if self.algo == Algo::Sac && !(self.sac.alpha.is_finite() && self.sac.alpha > 0.0) {
            return bad("alpha", format!("{} must be positive", self.sac.alpha));
        }
        if let Some(l) = &self.latent_exploration {
            if self.algo != Algo::Sac {
                return bad("latent-exploration", "is SAC's exploration (DDPG explores with its own noise)".into());
            }
            if !(l.beta.is_finite() && l.beta >= 0.0) {
                return bad("latent-exploration.beta", format!("{} is not a finite number >= 0", l.beta));
            }
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("invalid config `{field}`: {why}")]
    Config { field: &'static str, why: String },
    #[error(transparent)]
    Env(#[from] EnvError),
    #[error("environment produced an invalid transition: {0}")]
    Replay(#[from] ReplayError),
    #[error(transparent)]
    Nn(#[from] NnError),
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// A setting, or a full disk, fails the same way after a restart.
impl coadapt_fleet::supervise::exit::ExitCode for TrainError {
    fn exit_code(&self) -> Option<u8> {
        match self {
            Self::Config { .. } => Some(coadapt_fleet::supervise::exit::CONFIG),
            Self::Nn(e) => e.exit_code(),
            Self::Io { source, .. } => source.exit_code(),
            Self::Env(_) | Self::Replay(_) => None,
        }
    }
}

/// One finished episode.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EpisodeRecord {
    pub episode: u64,
    /// Environment steps taken so far, this episode included.
    pub step: u64,
    pub episode_return: f32,
    pub length: u64,
    /// Mean return of the last (up to) 10 episodes.
    pub mean_return_last_10: f32,
    pub wall_s: f64,
}

/// The outcome of a run, printed by `coadapt train` as one JSON line.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrainSummary {
    pub env: String,
    pub algo: Algo,
    pub seed: u64,
    pub steps: u64,
    pub episodes: u64,
    pub mean_return_last_10: f32,
    /// The world trained in, only when it is not the robot's own (as `coadapt run`'s summary).
    #[serde(skip_serializing_if = "coadapt_robots::World::is_default")]
    pub world: coadapt_robots::World,
    /// First step at which the mean of the last 10 returns exceeded `target-return`.
    pub first_step_reaching_target: Option<u64>,
    pub updates: u64,
    pub wall_s: f64,
    pub run_dir: PathBuf,
    /// Stopped by the shutdown signal (Ctrl-C) before `steps` and before the target: the run is
    /// not finished, whatever the exit status (a campaign must not take it as done).
    pub interrupted: bool,
}

/// Builds the agent `cfg.algo` for the environment's dimensions.
pub fn make_agent(cfg: &TrainConfig, obs_dim: usize, act_dim: usize) -> Result<Box<dyn Agent>, TrainError> {
    Ok(match cfg.algo {
        Algo::Sac => Box::new(Sac::new(obs_dim, act_dim, cfg.sac.clone(), cfg.seed)?),
        Algo::Ddpg => Box::new(Ddpg::new(obs_dim, act_dim, cfg.ddpg.clone(), cfg.seed)?),
    })
}

/// Everything [`run`] refuses before its first step, checked without writing anything: the
/// config, the design against `spec`'s box, the networks (their sizes), the weights to start
/// from, the action space to explore through. A command checks this before it makes a run
/// directory, so that a refused run leaves nothing behind.
pub fn check(cfg: &TrainConfig, spec: &coadapt_core::EnvSpec) -> Result<(), TrainError> {
    prepare(cfg, spec).map(|_| ())
}

/// What [`check`] refuses, and what [`run`] starts from: the design, the agent (with its
/// starting weights), the action space to explore through.
type Prepared = (Vec<f32>, Box<dyn Agent>, Option<crate::action_space::ActionAutoencoder>);

fn prepare(cfg: &TrainConfig, spec: &coadapt_core::EnvSpec) -> Result<Prepared, TrainError> {
    cfg.validate()?;
    let design = cfg.design.clone().unwrap_or_else(|| spec.default_design.clone());
    spec.design.check("design", &design).map_err(EnvError::Design)?;
    let (obs_dim, act_dim) = (spec.obs_dim(), spec.act_dim());
    let mut agent = make_agent(cfg, obs_dim, act_dim)?;
    if let Some(path) = &cfg.init_weights {
        agent.load(path)?;
    }
    let latent = match &cfg.latent_exploration {
        Some(l) => Some(
            crate::action_space::ActionAutoencoder::from_file(&l.action_space, obs_dim, act_dim)
                .map_err(|e| TrainError::Config { field: "latent-exploration.action-space", why: e.to_string() })?,
        ),
        None => None,
    };
    Ok((design, agent, latent))
}

/// Trains on `env` until `cfg.steps` steps, the target, or `shutdown`; writes `episodes.csv` and
/// `checkpoint.safetensors` into `run_dir` and calls `on_episode` after every episode.
pub fn run(
    cfg: &TrainConfig,
    env: &mut dyn Env,
    run_dir: &Path,
    shutdown: &AtomicBool,
    on_episode: &mut dyn FnMut(&EpisodeRecord),
) -> Result<TrainSummary, TrainError> {
    let spec = env.spec().clone();
    let (design, mut agent, ae) = prepare(cfg, &spec)?;
    let (obs_dim, act_dim) = (spec.obs_dim(), spec.act_dim());
    let mut replay = ReplayBuffer::new(obs_dim, act_dim, cfg.replay_capacity);
    let mut batch = Batch::new(agent.batch_size(), obs_dim, act_dim);
    let mut rng = rng(cfg.seed, 2);
    let mut latent = match (ae, &cfg.latent_exploration) {
        (Some(ae), Some(l)) => {
            let z = vec![0.0f32; ae.latent_dim()];
            Some((ae, l.beta, z, vec![0.0f32; act_dim]))
        }
        _ => None,
    };

    let csv_path = run_dir.join("episodes.csv");
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| TrainError::Io { path: path.clone(), source }
    };
    let mut csv = BufWriter::new(File::create(&csv_path).map_err(io(&csv_path))?);
    writeln!(csv, "episode,step,return,length,mean_return_last_10,wall_s").map_err(io(&csv_path))?;
    let ckpt = run_dir.join("checkpoint.safetensors");
    // TensorBoard's view of the same rows (README, "TensorBoard"), flushed every episode.
    let mut events = coadapt_tensorboard::EventWriter::create(run_dir, "coadapt")
        .map_err(|source| TrainError::Io { path: run_dir.to_path_buf(), source })?;
    let mut last_loss: Option<(f32, f32)> = None;

    let start = Instant::now();
    let mut obs = vec![0.0; obs_dim];
    let mut action = vec![0.0; act_dim];
    let mut returns: Vec<f32> = Vec::new();
    let (mut step, mut updates, mut episode) = (0u64, 0u64, 0u64);
    let mut reached = None;
    let mut failures = 0u32;
    // Gradient steps owed to this episode under `UpdateSchedule::PerEpisode`.
    let mut owed = 0u64;
    while step < cfg.steps && !shutdown.load(Ordering::Relaxed) {
        let (mut ret, mut len) = (0.0f32, 0u64);
        let mut failed = None;
        match env.reset(cfg.seed.wrapping_mul(1_000_003).wrapping_add(episode), &design) {
            Ok(first) => obs.copy_from_slice(first),
            Err(e) => failed = Some(e),
        }
        agent.begin_episode();
        while failed.is_none() {
            if step < cfg.learning_starts {
                spec.action.sample(&mut rng, &mut action);
            } else if let Some((ae, beta, z, mean)) = latent.as_mut() {
                agent.act(&obs, false, mean);
                for v in z.iter_mut() {
                    *v = rand::Rng::sample(&mut rng, rand_distr::StandardNormal);
                }
                ae.explore_into(&obs, mean, z, *beta, &mut action);
            } else {
                agent.act(&obs, true, &mut action);
            }
            let s = match env.step(&action) {
                Ok(s) => s,
                Err(e) => {
                    failed = Some(e);
                    break;
                }
            };
            replay.push(&Transition { obs: &obs, action: &action, reward: s.reward, next_obs: s.observation, terminated: s.terminated })?;
            obs.copy_from_slice(s.observation);
            let done = s.terminated || s.truncated;
            ret += s.reward;
            len += 1;
            step += 1;
            if step >= cfg.learning_starts {
                match cfg.update_schedule {
                    UpdateSchedule::PerStep => {
                        for _ in 0..cfg.updates_per_step {
                            replay.sample(&mut rng, &mut batch)?;
                            last_loss = Some(agent.update(&batch));
                            updates += 1;
                        }
                    }
                    UpdateSchedule::PerEpisode => owed += u64::from(cfg.updates_per_step),
                }
            }
            if done || step >= cfg.steps {
                break;
            }
        }
        if failed.is_none() {
            for _ in 0..owed {
                replay.sample(&mut rng, &mut batch)?;
                last_loss = Some(agent.update(&batch));
                updates += 1;
            }
        }
        owed = 0;
        if let Some(e) = failed {
            // Never half an episode in the replay buffer: take it back and run it again.
            replay.pop_newest(len as usize);
            step -= len;
            failures += 1;
            coadapt_log::logln!("episode {} failed after {len} steps and was dropped ({failures} in a row): {e}", episode + 1);
            if failures > cfg.env_retries {
                return Err(TrainError::Env(e));
            }
            continue;
        }
        failures = 0;
        episode += 1;
        returns.push(ret);
        let last = &returns[returns.len().saturating_sub(10)..];
        let mean10 = last.iter().sum::<f32>() / last.len() as f32;
        let rec = EpisodeRecord {
            episode,
            step,
            episode_return: ret,
            length: len,
            mean_return_last_10: mean10,
            wall_s: start.elapsed().as_secs_f64(),
        };
        writeln!(csv, "{},{},{},{},{},{:.3}", rec.episode, rec.step, rec.episode_return, rec.length, rec.mean_return_last_10, rec.wall_s)
            .and_then(|_| csv.flush())
            .map_err(io(&csv_path))?;
        let mut values = vec![
            ("episode/return", f64::from(rec.episode_return)),
            ("episode/length", rec.length as f64),
            ("episode/mean_return_last_10", f64::from(rec.mean_return_last_10)),
            ("episode/env_steps", rec.step as f64),
            ("train/updates", updates as f64),
            ("time/seconds", rec.wall_s),
        ];
        if let Some((critic, policy)) = last_loss {
            values.extend([("loss/critic", f64::from(critic)), ("loss/policy", f64::from(policy))]);
        }
        events
            .scalars(rec.episode as i64, &values)
            .and_then(|()| events.flush())
            .map_err(|source| TrainError::Io { path: events.path().to_path_buf(), source })?;
        on_episode(&rec);
        if reached.is_none() && returns.len() >= 10 && cfg.target_return.is_some_and(|t| mean10 > t) {
            reached = Some(step);
            if cfg.stop_at_target {
                break;
            }
        }
        if cfg.checkpoint_every > 0 && episode.is_multiple_of(cfg.checkpoint_every) {
            agent.save(&ckpt)?;
        }
    }
    agent.save(&ckpt)?;
    let last = &returns[returns.len().saturating_sub(10)..];
    Ok(TrainSummary {
        env: spec.name.clone(),
        algo: cfg.algo,
        seed: cfg.seed,
        steps: step,
        episodes: episode,
        mean_return_last_10: if last.is_empty() { f32::NAN } else { last.iter().sum::<f32>() / last.len() as f32 },
        world: cfg.world.clone(),
        first_step_reaching_target: reached,
        updates,
        wall_s: start.elapsed().as_secs_f64(),
        run_dir: run_dir.to_path_buf(),
        interrupted: step < cfg.steps && shutdown.load(Ordering::Relaxed) && !(cfg.stop_at_target && reached.is_some()),
    })
}
