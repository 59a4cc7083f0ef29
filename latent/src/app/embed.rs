//! The embedding of `coadapt latent` (thesis §4, Eq. 4.1, 4.2), built once and frozen: state-based
//! DDPG learns on the robot for `episodes` episodes (OU noise, one update per step once a batch
//! fits) while every frame the camera sees is kept; the time-contrastive autoencoder then trains
//! on those episodes' frames and is saved to `path`. Every exploration method then loads the same
//! file, so only exploration differs between them.
//!
//! A served robot (dm_env_rpc) shows frames only, no state: its episodes are driven by the OU
//! process alone (sigma, theta of `[embedding.ddpg]`, around the middle of the action box), a
//! deviation from the thesis's state-based DDPG that the log states.

use std::io::Write;
use std::path::Path;

use std::sync::atomic::{AtomicBool, Ordering};

use coadapt_core::{Env, Pixels, ReplayBuffer, Transition};
use coadapt_learner::config::DdpgConfig;
use coadapt_learner::ddpg::Ddpg;
use coadapt_nn::Precision;
use serde::{Deserialize, Serialize};

use crate::{Embedding, EmbeddingConfig, EmbeddingTrainer, FrameSet};
use coadapt_fleet::app::AppError;

/// How the embedding is built (the `[embedding]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct EmbeddingSettings {
    /// The embedding file: loaded when it exists, else built and written there.
    pub path: String,
    /// Episodes of state-based DDPG whose frames train it (50 in the thesis).
    pub episodes: usize,
    /// The state-based DDPG that collects them (OU noise as the thesis's baseline).
    pub ddpg: DdpgConfig,
    /// Adam steps on the autoencoder.
    pub steps: usize,
    /// Triples (a frame, its successor, a random frame) per step.
    pub batch: usize,
    /// Adam's learning rate.
    pub lr: f32,
    /// Seed of the collection and the training.
    pub seed: u64,
    /// The networks' shapes and the contrastive margin (the thesis leaves them open: 3
    /// convolutions of 32 channels, 20-D codes, margin 1 on the unit sphere).
    pub shape: EmbeddingConfig,
    /// The products of the embedding's training and of the actors' encoding: `f32`, or
    /// `bf16` (bf16 operands, f32 accumulation; on CPUs with AVX-512 BF16 or AMX, f32
    /// elsewhere; BENCHMARKS.md "Convolutions"). The parameters are f32 either way.
    pub precision: Precision,
}

impl Default for EmbeddingSettings {
    fn default() -> Self {
        Self {
            path: String::new(),
            episodes: 50,
            ddpg: DdpgConfig { sigma: 0.5, theta: 0.15, ..DdpgConfig::default() },
            steps: 2000,
            batch: 32,
            lr: 1e-3,
            seed: 0,
            shape: EmbeddingConfig::default(),
            precision: Precision::F32,
        }
    }
}

/// Where frames come from: a built-in robot drawn by our camera (its state is known), or a
/// served robot whose observation is the frame.
pub enum FrameSource {
    Drawn(Box<Pixels<Box<dyn Env>>>),
    Served(Box<dyn Env>),
}

impl std::fmt::Debug for FrameSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FrameSource::Drawn(p) => f.debug_tuple("Drawn").field(p).finish(),
            FrameSource::Served(e) => f.debug_tuple("Served").field(&e.spec().name).finish(),
        }
    }
}

impl FrameSource {
    /// The environment the agent steps.
    pub fn env(&mut self) -> &mut dyn Env {
        match self {
            FrameSource::Drawn(p) => p.as_mut(),
            FrameSource::Served(e) => e.as_mut(),
        }
    }

    /// The robot's state behind the latest frame, when known.
    fn state(&self) -> Option<&[f32]> {
        match self {
            FrameSource::Drawn(p) => Some(p.state()),
            FrameSource::Served(_) => None,
        }
    }
}

/// Collects the frames and trains the embedding; writes it to `path` and its training log
/// next to it (`<path>.csv`: step, reconstruction, pull, push of each logged step). Stops,
/// writing nothing, when `shutdown` is set.
pub fn build(
    settings: &EmbeddingSettings,
    mut source: FrameSource,
    episode_steps: usize,
    path: &Path,
    shutdown: &AtomicBool,
) -> Result<(Embedding, Vec<f32>), AppError> {
    let stopped = || AppError::Interrupted(format!("interrupted while building the embedding; {} not written", path.display()));
    let px_len = 3 * settings.shape.image * settings.shape.image;
    let spec = source.env().spec().clone();
    let (design, act) = (spec.default_design.clone(), spec.act_dim());
    source.env().reset(0, &design)?;
    let state_len = source.state().map_or(0, <[f32]>::len);
    if source.state().is_none() {
        coadapt_log::logln!(
            "embedding: a served robot shows no state: its {} episodes follow OU noise alone (no state-based DDPG)",
            settings.episodes
        );
    }
    let (mid, half): (Vec<f32>, Vec<f32>) =
        spec.action.low.iter().zip(&spec.action.high).map(|(l, h)| (0.5 * (l + h), 0.5 * (h - l))).unzip();
    let mut ou = vec![0.0f32; act];
    let mut ddpg = Ddpg::new(state_len.max(1), act, settings.ddpg.clone(), settings.seed)?;
    let mut replay = ReplayBuffer::new(state_len.max(1), act, episode_steps * settings.episodes + 1);
    let mut batch = coadapt_core::Batch::new(settings.ddpg.batch_size, state_len.max(1), act);
    let mut rng = coadapt_core::rng(settings.seed, 7);
    let mut frames = FrameSet::new(px_len);
    let mut a = vec![0.0; act];
    let t0 = std::time::Instant::now();
    for ep in 0..settings.episodes {
        if shutdown.load(Ordering::Relaxed) {
            return Err(stopped());
        }
        let mut episode = source.env().reset(settings.seed * 1_000_003 + ep as u64, &design)?.to_vec();
        if episode.len() < px_len {
            return Err(AppError::Config(format!(
                "the robot's observation has {} values, fewer than one {px_len}-value frame",
                episode.len()
            )));
        }
        episode.truncate(px_len);
        let mut s = source.state().map(<[f32]>::to_vec);
        ddpg.reset_noise();
        ou.fill(0.0);
        let mut ret = 0.0;
        for _ in 0..episode_steps {
            match &s {
                Some(s) => ddpg.act(s, false, &mut a),
                None => {
                    let (sigma, theta) = (settings.ddpg.sigma, settings.ddpg.theta);
                    for (k, x) in ou.iter_mut().enumerate() {
                        let n: f32 = rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng);
                        *x += -theta * *x + sigma * n;
                        a[k] = mid[k] + half[k] * x.clamp(-1.0, 1.0);
                    }
                }
            }
            let st = source.env().step(&a)?;
            let (r, term, trunc) = (st.reward, st.terminated, st.truncated);
            episode.extend_from_slice(&st.observation[..px_len]);
            if let Some(prev) = s.as_mut() {
                let next = source.state().map(<[f32]>::to_vec).unwrap_or_default();
                replay.push(&Transition { obs: prev, action: &a, reward: r, next_obs: &next, terminated: term })?;
                *prev = next;
                if replay.len() >= settings.ddpg.batch_size && replay.sample(&mut rng, &mut batch).is_ok() {
                    ddpg.update(&batch);
                }
            }
            ret += r;
            if term || trunc {
                break;
            }
        }
        frames.push_episode(&episode).map_err(|e| AppError::Config(format!("frames of episode {ep}: {e}")))?;
        coadapt_log::logln!(
            "embedding: collection episode {}/{} return {ret:.1} ({} frames, {:.0} s)",
            ep + 1,
            settings.episodes,
            frames.len(),
            t0.elapsed().as_secs_f64()
        );
    }
    let emb = Embedding::new(settings.shape)?.with_precision(settings.precision);
    if emb.image_len() != px_len {
        return Err(AppError::Config(format!(
            "embedding.shape: {}x{} images of {} channels, but the camera gives {px_len} values",
            settings.shape.image, settings.shape.image, settings.shape.in_channels
        )));
    }
    let mut trainer = EmbeddingTrainer::new(emb, settings.lr, &mut rng);
    let log_path = path.with_extension("csv");
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(AppError::io(format!("creating {}", dir.display())))?;
    }
    let writing = || AppError::io(format!("writing {}", log_path.display()));
    let mut log =
        std::io::BufWriter::new(std::fs::File::create(&log_path).map_err(AppError::io(format!("creating {}", log_path.display())))?);
    writeln!(log, "step,reconstruction,pull,push").map_err(writing())?;
    for step in 1..=settings.steps {
        if shutdown.load(Ordering::Relaxed) {
            return Err(stopped());
        }
        let p = trainer.step(&frames, settings.batch, &mut rng);
        if step % 50 == 0 || step == settings.steps {
            writeln!(log, "{step},{},{},{}", p.reconstruction, p.pull, p.push).and_then(|()| log.flush()).map_err(writing())?;
        }
        if step % 200 == 0 || step == settings.steps {
            coadapt_log::logln!(
                "embedding: step {step}/{}: reconstruction {:.4} pull {:.4} push {:.4} ({:.0} s)",
                settings.steps,
                p.reconstruction,
                p.pull,
                p.push,
                t0.elapsed().as_secs_f64()
            );
        }
    }
    crate::save_embedding(path, &trainer.emb, &trainer.enc, &trainer.dec)?;
    coadapt_log::logln!("embedding: saved {}", path.display());
    Ok((trainer.emb, trainer.enc))
}

/// The embedding at `path`, or a fresh one built there (see [`build`]).
pub fn load_or_build(
    settings: &EmbeddingSettings,
    make_env: impl FnOnce() -> Result<FrameSource, AppError>,
    episode_steps: usize,
    shutdown: &AtomicBool,
) -> Result<(Embedding, Vec<f32>), AppError> {
    let path = Path::new(&settings.path);
    if path.exists() {
        let (emb, enc, _) = crate::load_embedding(path)?;
        coadapt_log::logln!("embedding: loaded {}", path.display());
        return Ok((emb.with_precision(settings.precision), enc));
    }
    coadapt_log::logln!(
        "embedding: {} does not exist; building it ({} collection episodes, {} training steps)",
        path.display(),
        settings.episodes,
        settings.steps
    );
    build(settings, make_env()?, episode_steps, path, shutdown)
}
