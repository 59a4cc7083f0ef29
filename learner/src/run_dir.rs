//! The files a co-adaptation run writes as it goes: `designs.csv` (one row per design) and
//! `episodes.csv` (one row per episode), so an interrupted run keeps everything it finished,
//! and the checkpoints of both network pairs.
//!
//! `episodes.csv` is appended to and flushed row by row. `designs.csv` is held in memory and
//! written whole (to a `.tmp` file, then renamed over it) whenever a row is added or
//! replaced: a design waiting for its prototype (`schedule.confirm-designs`) shows as a row with
//! `prototype = awaiting` and no episodes, which its final row replaces when the design ends,
//! and a reader never sees half a file.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// The header of `designs.csv`. `design` is the design vector joined with `;`.
pub const DESIGNS_HEADER: &str =
    "index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts,method,prototype";
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
    /// The prototype step (`schedule.confirm-designs`): empty when off; [`PROTOTYPE_AWAITING`]
    /// while the run waits, then [`PROTOTYPE_CONFIRMED`], [`prototype_as_built`] (`design` is
    /// then the measured one) or [`PROTOTYPE_REJECTED`] (a row of its own, no episodes).
    pub prototype: String,
}

/// The `prototype` column of a design waiting for its prototype.
pub const PROTOTYPE_AWAITING: &str = "awaiting";
/// The `prototype` column of a design built as requested.
pub const PROTOTYPE_CONFIRMED: &str = "confirmed";
/// The `prototype` column of a design the operator would not build.
pub const PROTOTYPE_REJECTED: &str = "rejected";

/// The `prototype` column of a design built with other dimensions than `requested`:
/// `as-built (requested a;b;c)`.
pub fn prototype_as_built(requested: &[f32]) -> String {
    format!("as-built (requested {})", join_design(requested))
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

/// The run directory's CSV files.
#[derive(Debug)]
pub struct RunWriter {
    dir: PathBuf,
    /// Every row of `designs.csv`, in order.
    designs: Vec<DesignRow>,
    episodes: BufWriter<File>,
}

/// Writes `text` to `path` through `path.tmp` and a rename, so a reader sees the old file or
/// the new one, never a part.
pub fn write_atomically(path: &Path, text: &str) -> io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, path)
}

impl RunWriter {
    /// Creates `dir` (and `dir/checkpoints`) and both CSV files with their headers.
    pub fn create(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir.join("checkpoints"))?;
        let mut episodes = BufWriter::new(File::create(dir.join("episodes.csv"))?);
        writeln!(episodes, "{EPISODES_HEADER}")?;
        episodes.flush()?;
        let w = Self { dir: dir.to_path_buf(), designs: Vec::new(), episodes };
        w.write_designs()?;
        Ok(w)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn checkpoint_path(&self, name: &str) -> PathBuf {
        self.dir.join("checkpoints").join(format!("{name}.safetensors"))
    }

    /// The rows of `designs.csv` so far.
    pub fn designs(&self) -> &[DesignRow] {
        &self.designs
    }

    /// Adds `r` to `designs.csv`, or replaces the row of the same design that is still open
    /// (any but a rejected one: a rejected proposal keeps its row, and the next proposal for
    /// the same index gets a new one), and writes the file again.
    pub fn design(&mut self, r: &DesignRow) -> io::Result<()> {
        match self.designs.iter().rposition(|d| d.index == r.index && d.prototype != PROTOTYPE_REJECTED) {
            Some(i) => self.designs[i] = r.clone(),
            None => self.designs.push(r.clone()),
        }
        self.write_designs()
    }

    fn write_designs(&self) -> io::Result<()> {
        let mut text = format!("{DESIGNS_HEADER}\n");
        for r in &self.designs {
            text += &format!(
                "{},{},{},{},{},{},{},{},{},{}\n",
                r.index,
                r.kind,
                join_design(&r.design),
                r.episodes,
                opt(r.best_eval_return),
                opt(r.last_eval_return),
                opt(r.predicted_objective),
                r.design_rollouts,
                r.method,
                r.prototype
            );
        }
        write_atomically(&self.dir.join("designs.csv"), &text)
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
