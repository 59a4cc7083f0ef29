//! The files a co-adaptation run writes as it goes: `designs.csv` (one row per design) and
//! `episodes.csv` (one row per episode), each flushed row by row so an interrupted run keeps
//! everything it finished, and the checkpoints of both network pairs.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// The header of `designs.csv`. `design` is the design vector joined with `;`.
pub const DESIGNS_HEADER: &str = "index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts,method";
/// The header of `episodes.csv`; `eval_return` is empty for episodes without an evaluation.
pub const EPISODES_HEADER: &str = "design,episode,global_episode,steps,return,eval_return,weights_version,seconds,actor,policy_lag";

/// One finished (or interrupted) design.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignRow {
    pub index: usize,
    /// `initial`, `exploit` or `explore`.
    pub kind: String,
    pub design: Vec<f32>,
    pub episodes: usize,
    pub best_eval_return: Option<f32>,
    pub last_eval_return: Option<f32>,
    pub predicted_objective: Option<f32>,
    pub design_rollouts: u64,
    /// How the design was chosen (`fixed`, `pso-q`, `novelty`, `random`, `sim-pso`, ...).
    pub method: String,
}

/// One episode.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeRow {
    pub design: usize,
    pub episode: usize,
    pub global_episode: usize,
    /// Environment steps of training episodes so far, this one included.
    pub steps: u64,
    pub train_return: f32,
    pub eval_return: Option<f32>,
    pub weights_version: u64,
    /// Since the run started.
    pub seconds: f64,
    /// The actor that ran the training episode.
    pub actor: u64,
    /// Weights versions published between the one the episode acted with and the newest
    /// when it came back (0 in lock-step).
    pub policy_lag: u64,
}

fn opt(v: Option<f32>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// `a;b;c`.
pub fn join_design(d: &[f32]) -> String {
    d.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(";")
}

/// The run directory's CSV files, open for appending rows.
#[derive(Debug)]
pub struct RunWriter {
    dir: PathBuf,
    designs: BufWriter<File>,
    episodes: BufWriter<File>,
}

impl RunWriter {
    /// Creates `dir` (and `dir/checkpoints`) and both CSV files with their headers.
    pub fn create(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir.join("checkpoints"))?;
        let mut designs = BufWriter::new(File::create(dir.join("designs.csv"))?);
        writeln!(designs, "{DESIGNS_HEADER}")?;
        designs.flush()?;
        let mut episodes = BufWriter::new(File::create(dir.join("episodes.csv"))?);
        writeln!(episodes, "{EPISODES_HEADER}")?;
        episodes.flush()?;
        Ok(Self { dir: dir.to_path_buf(), designs, episodes })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn checkpoint_path(&self, name: &str) -> PathBuf {
        self.dir.join("checkpoints").join(format!("{name}.safetensors"))
    }

    pub fn design(&mut self, r: &DesignRow) -> io::Result<()> {
        writeln!(
            self.designs,
            "{},{},{},{},{},{},{},{},{}",
            r.index,
            r.kind,
            join_design(&r.design),
            r.episodes,
            opt(r.best_eval_return),
            opt(r.last_eval_return),
            opt(r.predicted_objective),
            r.design_rollouts,
            r.method
        )?;
        self.designs.flush()
    }

    pub fn episode(&mut self, r: &EpisodeRow) -> io::Result<()> {
        writeln!(
            self.episodes,
            "{},{},{},{},{},{},{},{:.3},{},{}",
            r.design,
            r.episode,
            r.global_episode,
            r.steps,
            r.train_return,
            opt(r.eval_return),
            r.weights_version,
            r.seconds,
            r.actor,
            r.policy_lag
        )?;
        self.episodes.flush()
    }
}
