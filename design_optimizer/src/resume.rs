//! The optimiser's state across restarts: everything that decides its future answers (the
//! generator behind random designs and simulation seeds, the request count that seeds each
//! search, the ES baselines' distributions and best design seen) and every reply so far.
//!
//! A restarted optimiser that reads this file answers the learner's next request exactly as
//! the one that died would have; a request it answered already (the learner sends a request
//! again after a deadline, and a resumed learner asks again for designs after its snapshot)
//! gets the stored reply. The file is written through a temporary file, fsynced and renamed,
//! and the previous version is kept as `.prev`, read when the newest is damaged.

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use coadapt_core::Rng64;
use coadapt_transport::{DesignReply, DesignRequest};
use serde::{Deserialize, Serialize};

use crate::SearchResult;
use crate::role::Optimizer;

/// What identifies a request: its design index and how many rejected designs it lists (an
/// operator's rejection makes the learner ask for the same index again, wanting another
/// answer).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct RequestKey {
    pub index: u32,
    pub rejected: u32,
}

impl RequestKey {
    pub fn of(req: &DesignRequest, design_dim: usize) -> Self {
        Self { index: req.index, rejected: (req.rejected.len() / design_dim.max(1)) as u32 }
    }
}

/// A reply, its numbers as `f64` (exact for `f32`, and exact through JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StoredReply {
    pub design: Vec<f64>,
    pub method: String,
    pub predicted_objective: Option<f64>,
    pub design_rollouts: u64,
}

impl StoredReply {
    pub fn of(r: &DesignReply) -> Self {
        Self {
            design: r.design.iter().map(|&v| f64::from(v)).collect(),
            method: r.method.clone(),
            predicted_objective: r.predicted_objective.map(f64::from),
            design_rollouts: r.design_rollouts,
        }
    }

    pub fn reply(&self, index: u32) -> DesignReply {
        DesignReply {
            index,
            design: self.design.iter().map(|&v| v as f32).collect(),
            method: self.method.clone(),
            predicted_objective: self.predicted_objective.map(|v| v as f32),
            design_rollouts: self.design_rollouts,
        }
    }
}

/// The state file's contents.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OptimizerState {
    /// The run's seed and methods: a state of another run is refused.
    pub seed: u64,
    pub exploit: String,
    pub requests: u64,
    pub rng: Rng64,
    /// The ES baseline's state (JSON text).
    pub es: Option<String>,
    /// The best ES candidate seen: design and score as `f64`.
    pub es_best: Option<(Vec<f64>, f64, usize)>,
    pub replies: Vec<(RequestKey, StoredReply)>,
}

impl Optimizer<'_> {
    /// The state to write.
    pub fn state(&self) -> Result<OptimizerState, String> {
        Ok(OptimizerState {
            seed: self.seed,
            exploit: self.cfg.exploit.name().into(),
            requests: self.requests,
            rng: self.rng.clone(),
            es: self.es.as_ref().map(|e| e.save()).transpose()?,
            es_best: self.es_best.as_ref().map(|b| (b.design.iter().map(|&v| f64::from(v)).collect(), f64::from(b.score), b.evaluations)),
            replies: self.replies.iter().map(|(k, r)| (*k, r.clone())).collect(),
        })
    }

    /// Continues from `s`, refusing a state of another seed or method.
    pub fn restore(&mut self, s: OptimizerState) -> Result<(), String> {
        if s.seed != self.seed || s.exploit != self.cfg.exploit.name() {
            return Err(format!(
                "the state is of seed {} and exploit {}, this optimiser runs seed {} and exploit {}",
                s.seed,
                s.exploit,
                self.seed,
                self.cfg.exploit.name()
            ));
        }
        match (&mut self.es, s.es) {
            (Some(es), Some(v)) => es.load(&v).map_err(|e| format!("es: {e}"))?,
            (None, None) => {}
            _ => return Err("es: the state and this optimiser disagree on whether an ES runs".into()),
        }
        self.requests = s.requests;
        self.rng = s.rng;
        self.es_best = s.es_best.map(|(d, score, evaluations)| SearchResult {
            design: d.into_iter().map(|v| v as f32).collect(),
            score: score as f32,
            history: vec![score as f32],
            evaluations,
        });
        self.replies = s.replies.into_iter().collect::<BTreeMap<_, _>>();
        Ok(())
    }
}

/// The state file (`DIR/optimizer-state.json`, and `.prev` beside it).
#[derive(Clone, Debug)]
pub struct StateFile {
    path: PathBuf,
}

impl StateFile {
    pub fn in_dir(dir: &Path) -> io::Result<Self> {
        fs::create_dir_all(dir)?;
        Ok(Self { path: dir.join("optimizer-state.json") })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn prev(&self) -> PathBuf {
        self.path.with_extension("json.prev")
    }

    /// Writes `s`: to a temporary file, fsynced; the current file becomes `.prev`; the new one
    /// is renamed into place and the directory fsynced.
    pub fn save(&self, s: &OptimizerState) -> io::Result<()> {
        let text = serde_json::to_vec(s).map_err(io::Error::other)?;
        let tmp = self.path.with_extension("json.tmp");
        let mut f = File::create(&tmp)?;
        f.write_all(&text)?;
        f.sync_all()?;
        if self.path.exists() {
            fs::rename(&self.path, self.prev())?;
        }
        fs::rename(&tmp, &self.path)?;
        if let Some(dir) = self.path.parent() {
            File::open(dir)?.sync_all()?;
        }
        Ok(())
    }

    /// The newest readable state, with what was wrong with a newer one; `None` when there is
    /// none at all (a fresh start).
    pub fn load(&self) -> (Option<OptimizerState>, Vec<String>) {
        let mut why = Vec::new();
        for p in [self.path.clone(), self.prev()] {
            match fs::read(&p) {
                Ok(bytes) => match serde_json::from_slice::<OptimizerState>(&bytes) {
                    Ok(s) => return (Some(s), why),
                    Err(e) => why.push(format!("{}: {e}", p.display())),
                },
                Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                Err(e) => why.push(format!("{}: {e}", p.display())),
            }
        }
        (None, why)
    }
}
