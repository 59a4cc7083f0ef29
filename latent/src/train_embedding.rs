//! Training the time-contrastive embedding once, on a fixed set of episodes' frames, before any
//! exploration method runs (thesis 4.2: 50 episodes of a state-based DDPG in simulation), so
//! every method sees the same embedding.

use coadapt_nn::{Adam, AdamConfig};
use rand::Rng;

use crate::{Embedding, EmbeddingWork, LossParts};

/// An episode that is not at least two whole frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("an episode of {values} values is not at least two frames of {image_len}")]
pub struct NotFrames {
    pub values: usize,
    pub image_len: usize,
}

/// Single frames (`image_len` values each) of whole episodes, in order.
#[derive(Clone, Debug, Default)]
pub struct FrameSet {
    image_len: usize,
    frames: Vec<f32>,
    /// Start of each episode (in frames) and its length.
    episodes: Vec<(usize, usize)>,
}

impl FrameSet {
    pub fn new(image_len: usize) -> Self {
        Self { image_len, ..Self::default() }
    }

    /// Adds an episode of `frames.len() / image_len` consecutive frames (two at least, for a
    /// consecutive pair).
    pub fn push_episode(&mut self, frames: &[f32]) -> Result<(), NotFrames> {
        if self.image_len == 0 || !frames.len().is_multiple_of(self.image_len) || frames.len() < 2 * self.image_len {
            return Err(NotFrames { values: frames.len(), image_len: self.image_len });
        }
        let start = self.frames.len() / self.image_len;
        self.frames.extend_from_slice(frames);
        self.episodes.push((start, frames.len() / self.image_len));
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.frames.len() / self.image_len.max(1)
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    fn frame(&self, i: usize) -> &[f32] {
        &self.frames[i * self.image_len..(i + 1) * self.image_len]
    }

    /// `n` triples (a frame, the next one in its episode, any frame) into `out` as the loss
    /// expects them: the anchors, then the next frames, then the random ones.
    pub fn sample<R: Rng + ?Sized>(&self, n: usize, rng: &mut R, out: &mut Vec<f32>) {
        out.clear();
        let total = self.len();
        let mut picks = Vec::with_capacity(3 * n);
        for _ in 0..n {
            let (start, len) = self.episodes[rng.random_range(0..self.episodes.len())];
            let t = start + rng.random_range(0..len - 1);
            picks.push((t, t + 1, rng.random_range(0..total)));
        }
        for k in 0..3 {
            for p in &picks {
                let i = [p.0, p.1, p.2][k];
                out.extend_from_slice(self.frame(i));
            }
        }
    }
}

/// The embedding's parameters and their optimisers.
#[derive(Debug)]
pub struct EmbeddingTrainer {
    pub emb: Embedding,
    pub enc: Vec<f32>,
    pub dec: Vec<f32>,
    adam_e: Adam,
    adam_d: Adam,
    ge: Vec<f32>,
    gd: Vec<f32>,
    work: EmbeddingWork,
    batch: Vec<f32>,
}

impl EmbeddingTrainer {
    /// Fresh networks (PyTorch's default initialisation) and Adam at `lr`.
    pub fn new<R: Rng + ?Sized>(emb: Embedding, lr: f32, rng: &mut R) -> Self {
        let (mut enc, mut dec) = (vec![0.0; emb.encoder_params()], vec![0.0; emb.decoder_params()]);
        emb.init(&mut enc, &mut dec, rng);
        let cfg = AdamConfig { lr, ..AdamConfig::default() };
        Self {
            adam_e: Adam::new(enc.len(), cfg),
            adam_d: Adam::new(dec.len(), cfg),
            ge: vec![0.0; enc.len()],
            gd: vec![0.0; dec.len()],
            enc,
            dec,
            emb,
            work: EmbeddingWork::default(),
            batch: Vec::new(),
        }
    }

    /// One Adam step on `n` triples drawn from `frames`; the batch's loss parts.
    pub fn step<R: Rng + ?Sized>(&mut self, frames: &FrameSet, n: usize, rng: &mut R) -> LossParts {
        frames.sample(n, rng, &mut self.batch);
        self.ge.fill(0.0);
        self.gd.fill(0.0);
        let parts = self.emb.loss_and_grad(&self.enc, &self.dec, &self.batch, n, &mut self.ge, &mut self.gd, &mut self.work);
        self.adam_e.step(&mut self.enc, &self.ge);
        self.adam_d.step(&mut self.dec, &self.gd);
        parts
    }

    /// The loss's parts on `n` triples without a step (for held-out checks).
    pub fn evaluate<R: Rng + ?Sized>(&mut self, frames: &FrameSet, n: usize, rng: &mut R) -> LossParts {
        frames.sample(n, rng, &mut self.batch);
        let (mut ge, mut gd) = (std::mem::take(&mut self.ge), std::mem::take(&mut self.gd));
        let parts = self.emb.loss_and_grad(&self.enc, &self.dec, &self.batch, n, &mut ge, &mut gd, &mut self.work);
        (self.ge, self.gd) = (ge, gd);
        parts
    }
}
