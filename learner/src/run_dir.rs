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

use serde::{Deserialize, Serialize};

/// The header of `designs.csv`. `design` is the design vector joined with `;`.
pub const DESIGNS_HEADER: &str =
    "index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts,method,prototype";
/// The header of `episodes.csv`; `eval_return` is empty for episodes without an evaluation.
pub const EPISODES_HEADER: &str = "design,episode,global_episode,steps,return,eval_return,weights_version,seconds,actor,policy_lag";

/// One finished (or interrupted) design. Snapshots store its numbers by their bits, so a
/// resumed run trains on exactly the design it chose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DesignRow {
    pub index: usize,
    /// `initial`, `exploit` or `explore`.
    pub kind: String,
    #[serde(with = "crate::snapshot::bits::vec")]
    pub design: Vec<f32>,
    pub episodes: usize,
    #[serde(with = "crate::snapshot::bits::opt")]
    pub best_eval_return: Option<f32>,
    #[serde(with = "crate::snapshot::bits::opt")]
    pub last_eval_return: Option<f32>,
    #[serde(with = "crate::snapshot::bits::opt")]
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
    /// Bytes of `episodes.csv` written so far (a snapshot records it; a resume cuts back to it).
    episodes_bytes: u64,
}

/// Writes `text` to `path` through `path.tmp` (fsynced) and a rename, so a reader sees the old
/// file or the new one, never a part.
pub fn write_atomically(path: &Path, text: &str) -> io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let mut f = File::create(&tmp)?;
    f.write_all(text.as_bytes())?;
    // On the disk before the rename: after a power cut the name holds the old or the new text.
    f.sync_all()?;
    std::fs::rename(&tmp, path)
}

impl RunWriter {
    /// Creates `dir` (and `dir/checkpoints`) and both CSV files with their headers.
    pub fn create(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir.join("checkpoints"))?;
        let mut episodes = BufWriter::new(File::create(dir.join("episodes.csv"))?);
        let header = format!("{EPISODES_HEADER}\n");
        episodes.write_all(header.as_bytes())?;
        episodes.flush()?;
        let w = Self { dir: dir.to_path_buf(), designs: Vec::new(), episodes, episodes_bytes: header.len() as u64 };
        w.write_designs()?;
        Ok(w)
    }

    /// Opens the run directory `dir` of a run resumed from a snapshot: `episodes.csv` is cut
    /// back to its first `episodes_bytes` bytes and `designs.csv` rewritten with `designs`, so
    /// the rows after the snapshot, which the resumed run writes again, appear once.
    pub fn resume(dir: &Path, designs: Vec<DesignRow>, episodes_bytes: u64) -> io::Result<Self> {
        std::fs::create_dir_all(dir.join("checkpoints"))?;
        let path = dir.join("episodes.csv");
        let f = File::options().write(true).open(&path)?;
        let len = f.metadata()?.len();
        if len < episodes_bytes {
            return Err(io::Error::other(format!(
                "{} has {len} bytes, fewer than the {episodes_bytes} the snapshot recorded: it was changed after the snapshot",
                path.display()
            )));
        }
        f.set_len(episodes_bytes)?;
        f.sync_all()?;
        drop(f);
        let episodes = BufWriter::new(File::options().append(true).open(&path)?);
        let w = Self { dir: dir.to_path_buf(), designs, episodes, episodes_bytes };
        w.write_designs()?;
        Ok(w)
    }

    /// Bytes of `episodes.csv` so far.
    pub fn episodes_bytes(&self) -> u64 {
        self.episodes_bytes
    }

    /// Flushes `episodes.csv` to the disk (before a snapshot that records its length).
    pub fn sync(&mut self) -> io::Result<()> {
        self.episodes.flush()?;
        self.episodes.get_ref().sync_all()
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn checkpoint_path(&self, name: &str) -> PathBuf {
        self.dir.join("checkpoints").join(format!("{name}.safetensors"))
    }

    /// The networks at the end of design `index`, as one directory
    /// `checkpoints/design-NNN/{population,individual}.safetensors` (written under a temporary
    /// name, fsynced and renamed: both files or neither), and the newest pair again as
    /// `checkpoints/{population,individual}.safetensors`.
    pub fn checkpoint(&self, index: usize, fear: &crate::fear::FearLearner) -> Result<(), coadapt_nn::NnError> {
        use crate::fear::ActingPolicy::{Individual, Population};
        let root = self.dir.join("checkpoints");
        let tmp = root.join(format!(".tmp-design-{index:03}"));
        let dir = root.join(format!("design-{index:03}"));
        let io = |source: io::Error| coadapt_nn::NnError::Write { path: root.display().to_string(), source };
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(io)?;
        }
        std::fs::create_dir_all(&tmp).map_err(io)?;
        for (name, which) in [("population", Population), ("individual", Individual)] {
            let path = tmp.join(format!("{name}.safetensors"));
            fear.agent(which).save(&path)?;
            File::open(&path).and_then(|f| f.sync_all()).map_err(io)?;
        }
        File::open(&tmp).and_then(|f| f.sync_all()).map_err(io)?;
        if dir.exists() {
            // Written before a resume went back past this design.
            std::fs::remove_dir_all(&dir).map_err(io)?;
        }
        std::fs::rename(&tmp, &dir).map_err(io)?;
        for name in ["population", "individual"] {
            let latest = self.checkpoint_path(name);
            let mut part = latest.clone().into_os_string();
            part.push(".tmp");
            std::fs::copy(dir.join(format!("{name}.safetensors")), &part).map_err(io)?;
            std::fs::rename(&part, &latest).map_err(io)?;
        }
        File::open(&root).and_then(|f| f.sync_all()).map_err(io)
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
        // A real CSV writer: a text field with a comma, a quote or a newline is quoted, so no
        // value can forge a row (plain fields are written as they are).
        let mut w = csv::WriterBuilder::new().terminator(csv::Terminator::Any(b'\n')).from_writer(Vec::new());
        w.write_record(DESIGNS_HEADER.split(',')).map_err(io::Error::other)?;
        for r in &self.designs {
            w.write_record([
                r.index.to_string(),
                r.kind.clone(),
                join_design(&r.design),
                r.episodes.to_string(),
                opt(r.best_eval_return),
                opt(r.last_eval_return),
                opt(r.predicted_objective),
                r.design_rollouts.to_string(),
                r.method.clone(),
                r.prototype.clone(),
            ])
            .map_err(io::Error::other)?;
        }
        let bytes = w.into_inner().map_err(|e| io::Error::other(e.to_string()))?;
        write_atomically(&self.dir.join("designs.csv"), &String::from_utf8_lossy(&bytes))
    }

    pub fn episode(&mut self, r: &EpisodeRow) -> io::Result<()> {
        let line = format!(
            "{},{},{},{},{},{},{},{:.3},{},{}\n",
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
        );
        self.episodes.write_all(line.as_bytes())?;
        self.episodes_bytes += line.len() as u64;
        self.episodes.flush()
    }
}
