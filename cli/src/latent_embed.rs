//! The embedding of `coadapt latent` (thesis §4, Eq. 4.1, 4.2), built once and frozen: state-based
//! DDPG learns on the robot for `episodes` episodes (OU noise, one update per step once a batch
//! fits) while every frame the camera sees is kept; the time-contrastive autoencoder then trains
//! on those episodes' frames and is saved to `path`. Every exploration method then loads the same
//! file, so only exploration differs between them.

use std::io::Write;
use std::path::Path;

use anyhow::Context;
use coadapt_core::{Env, Pixels, ReplayBuffer, Transition};
use coadapt_latent::{Embedding, EmbeddingConfig, EmbeddingTrainer, FrameSet};
use coadapt_learner::config::DdpgConfig;
use coadapt_learner::ddpg::Ddpg;
use serde::{Deserialize, Serialize};

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
        }
    }
}

/// Collects the frames and trains the embedding; writes it to `path` and its training log
/// next to it (`<path>.csv`: step, reconstruction, pull, push of each logged step).
pub fn build(
    settings: &EmbeddingSettings,
    mut env: Pixels<Box<dyn Env>>,
    episode_steps: usize,
    path: &Path,
) -> anyhow::Result<(Embedding, Vec<f32>)> {
    let px_len = env.spec().state_dim;
    let design = env.spec().default_design.clone();
    let act = env.spec().act_dim();
    env.reset(0, &design)?;
    let state_len = env.state().len();
    let mut ddpg = Ddpg::new(state_len, act, settings.ddpg.clone(), settings.seed)?;
    let mut replay = ReplayBuffer::new(state_len, act, episode_steps * settings.episodes + 1);
    let mut batch = coadapt_core::Batch::new(settings.ddpg.batch_size, state_len, act);
    let mut rng = coadapt_core::rng(settings.seed, 7);
    let mut frames = FrameSet::new(px_len);
    let mut a = vec![0.0; act];
    let t0 = std::time::Instant::now();
    for ep in 0..settings.episodes {
        let mut episode = env.reset(settings.seed * 1_000_003 + ep as u64, &design)?.to_vec();
        episode.truncate(px_len);
        let mut s = env.state().to_vec();
        ddpg.reset_noise();
        let mut ret = 0.0;
        for _ in 0..episode_steps {
            ddpg.act(&s, false, &mut a);
            let st = env.step(&a)?;
            let (r, term, trunc) = (st.reward, st.terminated, st.truncated);
            episode.extend_from_slice(&st.observation[..px_len]);
            let next = env.state().to_vec();
            replay.push(&Transition { obs: &s, action: &a, reward: r, next_obs: &next, terminated: term })?;
            ret += r;
            s = next;
            if replay.len() >= settings.ddpg.batch_size && replay.sample(&mut rng, &mut batch).is_ok() {
                ddpg.update(&batch);
            }
            if term || trunc {
                break;
            }
        }
        frames.push_episode(&episode).map_err(|e| anyhow::anyhow!("frames of episode {ep}: {e}"))?;
        eprintln!(
            "embedding: state-based DDPG episode {}/{} return {ret:.1} ({} frames, {:.0} s)",
            ep + 1,
            settings.episodes,
            frames.len(),
            t0.elapsed().as_secs_f64()
        );
    }
    let emb = Embedding::new(settings.shape)?;
    if emb.image_len() != px_len {
        anyhow::bail!(
            "embedding.shape: {}x{} images of {} channels, but the camera gives {px_len} values",
            settings.shape.image,
            settings.shape.image,
            settings.shape.in_channels
        );
    }
    let mut trainer = EmbeddingTrainer::new(emb, settings.lr, &mut rng);
    let log_path = path.with_extension("csv");
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut log = std::io::BufWriter::new(std::fs::File::create(&log_path).with_context(|| format!("creating {}", log_path.display()))?);
    writeln!(log, "step,reconstruction,pull,push")?;
    for step in 1..=settings.steps {
        let p = trainer.step(&frames, settings.batch, &mut rng);
        if step % 50 == 0 || step == settings.steps {
            writeln!(log, "{step},{},{},{}", p.reconstruction, p.pull, p.push)?;
            log.flush()?;
        }
        if step % 200 == 0 || step == settings.steps {
            eprintln!(
                "embedding: step {step}/{}: reconstruction {:.4} pull {:.4} push {:.4} ({:.0} s)",
                settings.steps,
                p.reconstruction,
                p.pull,
                p.push,
                t0.elapsed().as_secs_f64()
            );
        }
    }
    coadapt_latent::save_embedding(path, &trainer.emb, &trainer.enc, &trainer.dec)?;
    eprintln!("embedding: saved {}", path.display());
    Ok((trainer.emb, trainer.enc))
}

/// The embedding at `path`, or a fresh one built there (see [`build`]).
pub fn load_or_build(
    settings: &EmbeddingSettings,
    make_env: impl FnOnce() -> anyhow::Result<Pixels<Box<dyn Env>>>,
    episode_steps: usize,
) -> anyhow::Result<(Embedding, Vec<f32>)> {
    let path = Path::new(&settings.path);
    if path.exists() {
        let (emb, enc, _) = coadapt_latent::load_embedding(path)?;
        eprintln!("embedding: loaded {}", path.display());
        return Ok((emb, enc));
    }
    eprintln!(
        "embedding: {} does not exist; building it ({} episodes of state-based DDPG, {} training steps)",
        path.display(),
        settings.episodes,
        settings.steps
    );
    build(settings, make_env()?, episode_steps, path)
}
