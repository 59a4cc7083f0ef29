//! A co-adaptation run's TensorBoard event file, beside its CSV files (issue 32): written as
//! the run goes and flushed every episode, so `tensorboard --logdir RUN_DIR` shows a live run.
//!
//! Tags, named so that runs compare in one view (README, "TensorBoard"):
//! - `episode/*` at step = the run's episode number (`global_episode` of episodes.csv):
//!   `return`, `eval_return`, `policy_lag`, `design`, `env_steps`; the learner's `loss/*`,
//!   `train/*` and `time/*` at the same step;
//! - `design/*` at step = the design's index, when the design ends: `best_eval_return`,
//!   `last_eval_return`, `predicted_objective`, `episodes`, `design_rollouts`, each coordinate
//!   as `design/xi/<name>` (spaces as `_`), and `design/kind` as text (`exploit (pso-q)`);
//! - `run/config` (text, step 0) and `run/landscape` (image, written when the run ends).
//!
//! A snapshot records the file's name and length ([`EventsAt`]); a resumed run cuts the file
//! back to that length and appends, as it does with the CSV files, so no step appears twice.

use std::io;
use std::path::Path;

use coadapt_tensorboard::EventWriter;
use serde::{Deserialize, Serialize};

use crate::run_dir::DesignRow;

/// Where the event file stood at a snapshot.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EventsAt {
    /// The file's name in the run directory.
    pub file: String,
    pub bytes: u64,
}

/// The run's event file and the names of the design's coordinates.
#[derive(Debug)]
pub struct RunEvents {
    w: EventWriter,
    design_names: Vec<String>,
}

impl RunEvents {
    /// A new event file in `dir`.
    pub fn create(dir: &Path) -> io::Result<Self> {
        Ok(Self { w: EventWriter::create(dir, "coadapt")?, design_names: Vec::new() })
    }

    /// The file a snapshot recorded, cut back to its length; a new file when the snapshot
    /// predates event files (or the file is gone).
    pub fn resume(dir: &Path, at: Option<&EventsAt>) -> io::Result<Self> {
        match at {
            Some(at) if dir.join(&at.file).exists() && !at.file.contains('/') => {
                Ok(Self { w: EventWriter::reopen(&dir.join(&at.file), at.bytes)?, design_names: Vec::new() })
            }
            _ => Self::create(dir),
        }
    }

    pub fn at(&self) -> EventsAt {
        let file = self.w.path().file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
        EventsAt { file, bytes: self.w.bytes() }
    }

    /// Names `design/xi/<name>` after the robot's design dimensions.
    pub fn set_design_names(&mut self, names: Vec<String>) {
        self.design_names = names;
    }

    pub fn sync(&mut self) -> io::Result<()> {
        self.w.sync()
    }

    /// Scalars at step `step`, flushed.
    pub fn scalars(&mut self, step: i64, values: &[(&str, f64)]) -> io::Result<()> {
        self.w.scalars(step, values)?;
        self.w.flush()
    }

    pub fn text(&mut self, tag: &str, step: i64, text: &str) -> io::Result<()> {
        self.w.text(tag, step, text)?;
        self.w.flush()
    }

    /// The `design/*` summaries of a design that ended.
    pub fn design_ended(&mut self, r: &DesignRow) -> io::Result<()> {
        let step = r.index as i64;
        let opt = |v: Option<f32>| v.map_or(f64::NAN, f64::from);
        let mut values: Vec<(String, f64)> = vec![
            ("design/best_eval_return".into(), opt(r.best_eval_return)),
            ("design/last_eval_return".into(), opt(r.last_eval_return)),
            ("design/predicted_objective".into(), opt(r.predicted_objective)),
            ("design/episodes".into(), r.episodes as f64),
            ("design/design_rollouts".into(), r.design_rollouts as f64),
        ];
        for (i, x) in r.design.iter().enumerate() {
            // `back thigh` -> `back_thigh`: tags without spaces filter and sort well.
            let name = self.design_names.get(i).map_or_else(|| format!("{i}"), |n| n.replace(' ', "_"));
            values.push((format!("design/xi/{name}"), f64::from(*x)));
        }
        let borrowed: Vec<(&str, f64)> = values.iter().map(|(t, v)| (t.as_str(), *v)).collect();
        self.w.scalars(step, &borrowed)?;
        self.w.text("design/kind", step, &format!("{} ({})", r.kind, r.method))?;
        self.w.flush()
    }
}
