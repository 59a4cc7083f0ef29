//! The files a co-adaptation run writes as it goes: `designs.csv` (one row per design) and
//! `episodes.csv` (one row per episode), so an interrupted run keeps everything it finished,
//! and the checkpoints of both network pairs.
//!
//! `episodes.csv` is appended to and flushed row by row. `designs.csv` is appended to as well:
//! only the rows of the newest design index are still open (a design waiting for its prototype,
//! `schedule.confirm-designs`, shows as a row with `prototype = awaiting` and no episodes, which
//! its final row replaces when the design ends), so an update cuts the file back to the end of
//! the closed rows and writes the open ones again. The cost of a row stays constant however long
//! the run (a file rewritten whole grows O(designs) per update), and memory holds the open rows
//! only; a resumed run reads the closed rows back once ([`read_designs`]).

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::snapshot::named;

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
    /// Bytes of `designs.csv` that hold its header and the closed rows (of designs before the
    /// newest index): never written again.
    designs_closed: u64,
    /// The rows of the newest design index, in order, written after the closed bytes.
    designs_open: Vec<DesignRow>,
    episodes: BufWriter<File>,
    /// Bytes of `episodes.csv` written so far (a snapshot records it; a resume cuts back to it).
    episodes_bytes: u64,
    /// Told each design row written (a running learner's design service).
    on_designs: Option<DesignsObserver>,
    /// The TensorBoard event file (`crate::run_events`).
    events: crate::run_events::RunEvents,
}

/// A callback given each row written to `designs.csv` (after it is written).
pub struct DesignsObserver(pub Box<dyn Fn(&DesignRow) + Send>);

impl std::fmt::Debug for DesignsObserver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("DesignsObserver")
    }
}

/// Where the run directory's files stood at a snapshot.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WrittenSoFar {
    /// Bytes of `designs.csv` holding its header and the closed rows.
    pub designs_closed: u64,
    /// The open rows, written after them.
    pub designs_open: Vec<DesignRow>,
    /// Bytes of `episodes.csv`.
    pub episodes_bytes: u64,
    /// The TensorBoard event file (absent in snapshots from before event files).
    #[serde(default)]
    pub events: Option<crate::run_events::EventsAt>,
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

/// `rows` as lines of `designs.csv`. A real CSV writer: a text field with a comma, a quote or a
/// newline is quoted, so no value can forge a row (plain fields are written as they are).
pub fn design_lines(rows: &[DesignRow]) -> io::Result<Vec<u8>> {
    let mut w = csv::WriterBuilder::new().terminator(csv::Terminator::Any(b'\n')).from_writer(Vec::new());
    for r in rows {
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
    w.into_inner().map_err(|e| io::Error::other(e.to_string()))
}

/// The rows in the first `bytes` bytes of the `designs.csv` at `path` (the closed rows of a
/// snapshot), every number as written (Rust's shortest round-trip form, so exact).
pub fn read_designs(path: &Path, bytes: u64) -> io::Result<Vec<DesignRow>> {
    let text = std::fs::read(path)?;
    let Some(text) = usize::try_from(bytes).ok().and_then(|b| text.get(..b)) else {
        return Err(io::Error::other(format!(
            "{} has {} bytes, fewer than the {bytes} the snapshot recorded: it was changed after the snapshot",
            path.display(),
            text.len()
        )));
    };
    let bad = |line: u64, field: &str, why: &dyn std::fmt::Display| {
        io::Error::other(format!("{} line {line}: column {field}: {why}", path.display()))
    };
    let mut rows = Vec::new();
    let mut rd = csv::ReaderBuilder::new().has_headers(true).from_reader(text);
    for rec in rd.records() {
        let rec = rec.map_err(|e| io::Error::other(format!("{}: {e}", path.display())))?;
        let line = rec.position().map_or(0, |p| p.line());
        let field = |i: usize| rec.get(i).unwrap_or("");
        let num = |i: usize, name: &str| field(i).parse::<u64>().map_err(|e| bad(line, name, &e));
        let real = |i: usize, name: &str| -> io::Result<Option<f32>> {
            match field(i) {
                "" => Ok(None),
                v => v.parse::<f32>().map(Some).map_err(|e| bad(line, name, &e)),
            }
        };
        let design = if field(2).is_empty() {
            Vec::new()
        } else {
            field(2).split(';').map(|v| v.parse::<f32>().map_err(|e| bad(line, "design", &e))).collect::<io::Result<_>>()?
        };
        rows.push(DesignRow {
            index: num(0, "index")? as usize,
            kind: field(1).into(),
            design,
            episodes: num(3, "episodes")? as usize,
            best_eval_return: real(4, "best_eval_return")?,
            last_eval_return: real(5, "last_eval_return")?,
            predicted_objective: real(6, "predicted_objective")?,
            design_rollouts: num(7, "design_rollouts")?,
            method: field(8).into(),
            prototype: field(9).into(),
        });
    }
    Ok(rows)
}

/// Cuts the file at `path` back to `len` bytes, refusing one that is shorter.
fn cut(path: &Path, len: u64) -> io::Result<()> {
    let f = File::options().write(true).open(path)?;
    let have = f.metadata()?.len();
    if have < len {
        return Err(io::Error::other(format!(
            "{} has {have} bytes, fewer than the {len} the snapshot recorded: it was changed after the snapshot",
            path.display()
        )));
    }
    f.set_len(len)?;
    f.sync_all()
}

impl RunWriter {
    /// Creates `dir` (and `dir/checkpoints`) and both CSV files with their headers.
    pub fn create(dir: &Path) -> io::Result<Self> {
        let checkpoints = dir.join("checkpoints");
        std::fs::create_dir_all(&checkpoints).map_err(|e| named(e, "creating", &checkpoints))?;
        let path = dir.join("episodes.csv");
        let mut episodes = BufWriter::new(File::create(&path).map_err(|e| named(e, "creating", &path))?);
        let header = format!("{EPISODES_HEADER}\n");
        episodes.write_all(header.as_bytes()).and_then(|()| episodes.flush()).map_err(|e| named(e, "writing", &path))?;
        let designs_header = format!("{DESIGNS_HEADER}\n");
        let path = dir.join("designs.csv");
        write_atomically(&path, &designs_header).map_err(|e| named(e, "writing", &path))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            designs_closed: designs_header.len() as u64,
            designs_open: Vec::new(),
            episodes,
            episodes_bytes: header.len() as u64,
            on_designs: None,
            events: crate::run_events::RunEvents::create(dir)?,
        })
    }

    /// Opens the run directory `dir` of a run resumed from a snapshot: both CSV files are cut
    /// back to where they stood (`at`), so the rows after the snapshot, which the resumed run
    /// writes again, appear once.
    pub fn resume(dir: &Path, at: WrittenSoFar) -> io::Result<Self> {
        std::fs::create_dir_all(dir.join("checkpoints"))?;
        let path = dir.join("episodes.csv");
        cut(&path, at.episodes_bytes)?;
        let episodes = BufWriter::new(File::options().append(true).open(&path)?);
        cut(&dir.join("designs.csv"), at.designs_closed)?;
        let events = crate::run_events::RunEvents::resume(dir, at.events.as_ref())?;
        let w = Self {
            dir: dir.to_path_buf(),
            designs_closed: at.designs_closed,
            designs_open: at.designs_open,
            episodes,
            episodes_bytes: at.episodes_bytes,
            on_designs: None,
            events,
        };
        w.write_open_designs().map_err(|e| named(e, "writing", &dir.join("designs.csv")))?;
        Ok(w)
    }

    /// Calls `f` with every row [`RunWriter::design`] writes from now on.
    pub fn observe_designs(&mut self, f: DesignsObserver) {
        self.on_designs = Some(f);
    }

    /// Where the files stand (for a snapshot; call [`RunWriter::sync`] first).
    pub fn written_so_far(&self) -> WrittenSoFar {
        WrittenSoFar {
            designs_closed: self.designs_closed,
            designs_open: self.designs_open.clone(),
            episodes_bytes: self.episodes_bytes,
            events: Some(self.events.at()),
        }
    }

    /// Every row of `designs.csv`, read back from the file (a resume does this once).
    pub fn read_designs(&self) -> io::Result<Vec<DesignRow>> {
        let mut rows = read_designs(&self.dir.join("designs.csv"), self.designs_closed)?;
        rows.extend(self.designs_open.iter().cloned());
        Ok(rows)
    }

    /// Bytes of `episodes.csv` so far.
    pub fn episodes_bytes(&self) -> u64 {
        self.episodes_bytes
    }

    /// Flushes `episodes.csv` to the disk (before a snapshot that records its length).
    pub fn sync(&mut self) -> io::Result<()> {
        let path = self.dir.join("episodes.csv");
        self.episodes.flush().map_err(|e| named(e, "writing", &path))?;
        self.episodes.get_ref().sync_all().map_err(|e| named(e, "syncing", &path))?;
        self.events.sync()
    }

    /// The run's TensorBoard event file.
    pub fn events(&mut self) -> &mut crate::run_events::RunEvents {
        &mut self.events
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
        let root = self.dir.join("checkpoints");
        let tmp = root.join(format!(".tmp-design-{index:03}"));
        let r = self.checkpoint_via(&root, &tmp, index, fear);
        if r.is_err() {
            // A failure (a full disk) leaves no half-written directory to eat what space is left.
            let _ = std::fs::remove_dir_all(&tmp);
            for name in ["population", "individual"] {
                let _ = std::fs::remove_file(root.join(format!("{name}.safetensors.tmp")));
            }
        }
        r
    }

    fn checkpoint_via(&self, root: &Path, tmp: &Path, index: usize, fear: &crate::fear::FearLearner) -> Result<(), coadapt_nn::NnError> {
        use crate::fear::ActingPolicy::{Individual, Population};
        let dir = root.join(format!("design-{index:03}"));
        let io = |path: &Path| {
            let path = path.display().to_string();
            move |cause: io::Error| coadapt_nn::NnError::Write { path, cause }
        };
        if tmp.exists() {
            std::fs::remove_dir_all(tmp).map_err(io(tmp))?;
        }
        std::fs::create_dir_all(tmp).map_err(io(tmp))?;
        for (name, which) in [("population", Population), ("individual", Individual)] {
            let path = tmp.join(format!("{name}.safetensors"));
            fear.agent(which).save(&path)?;
            File::open(&path).and_then(|f| f.sync_all()).map_err(io(&path))?;
        }
        File::open(tmp).and_then(|f| f.sync_all()).map_err(io(tmp))?;
        if dir.exists() {
            // Written before a resume went back past this design.
            std::fs::remove_dir_all(&dir).map_err(io(&dir))?;
        }
        std::fs::rename(tmp, &dir).map_err(io(&dir))?;
        for name in ["population", "individual"] {
            let latest = self.checkpoint_path(name);
            let mut part = latest.clone().into_os_string();
            part.push(".tmp");
            let part = PathBuf::from(part);
            std::fs::copy(dir.join(format!("{name}.safetensors")), &part).map_err(io(&part))?;
            std::fs::rename(&part, &latest).map_err(io(&latest))?;
        }
        File::open(root).and_then(|f| f.sync_all()).map_err(io(root))
    }

    /// Adds `r` to `designs.csv`, or replaces the row of the same design that is still open
    /// (any but a rejected one: a rejected proposal keeps its row, and the next proposal for
    /// the same index gets a new one). A row of a newer index closes the rows before it.
    pub fn design(&mut self, r: &DesignRow) -> io::Result<()> {
        if self.designs_open.last().is_some_and(|d| d.index != r.index) {
            self.designs_closed += design_lines(&self.designs_open)?.len() as u64;
            self.designs_open.clear();
        }
        match self.designs_open.iter().rposition(|d| d.prototype != PROTOTYPE_REJECTED) {
            Some(i) => self.designs_open[i] = r.clone(),
            None => self.designs_open.push(r.clone()),
        }
        self.write_open_designs().map_err(|e| named(e, "writing", &self.dir.join("designs.csv")))?;
        if let Some(on) = &self.on_designs {
            (on.0)(r);
        }
        Ok(())
    }

    /// Cuts `designs.csv` back to its closed rows and writes the open ones after them, fsynced.
    fn write_open_designs(&self) -> io::Result<()> {
        let f = File::options().write(true).open(self.dir.join("designs.csv"))?;
        f.set_len(self.designs_closed)?;
        let mut f = File::options().append(true).open(self.dir.join("designs.csv"))?;
        f.write_all(&design_lines(&self.designs_open)?)?;
        f.sync_all()
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
        let named = |e| named(e, "appending a row to", &self.dir.join("episodes.csv"));
        self.episodes.write_all(line.as_bytes()).map_err(named)?;
        self.episodes_bytes += line.len() as u64;
        self.episodes.flush().map_err(named)?;
        let mut values = vec![
            ("episode/return", f64::from(r.train_return)),
            ("episode/policy_lag", r.policy_lag as f64),
            ("episode/design", r.design as f64),
            ("episode/env_steps", r.steps as f64),
        ];
        if let Some(e) = r.eval_return {
            values.push(("episode/eval_return", f64::from(e)));
        }
        self.events.scalars(r.global_episode as i64, &values)
    }
}

#[cfg(test)]
mod tests;
