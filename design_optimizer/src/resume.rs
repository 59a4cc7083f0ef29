//! The optimiser's state across restarts: everything that decides its future answers (the
//! generator behind random designs and simulation seeds, the request count that seeds each
//! search, the ES baselines' distributions and best design seen) and every reply so far.
//!
//! A restarted optimiser that reads this file answers the learner's next request exactly as
//! the one that died would have; a request it answered already (the learner sends a request
//! again after a deadline, and a resumed learner asks again for designs after its snapshot)
//! gets the stored reply. The file is a log: a line per reply with the state after it,
//! appended and fsynced before the reply is sent (see [`StateFile`]).

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

/// What decides the optimiser's future answers (its replies are kept beside it, one per line of
/// the log).
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
}

/// The replies so far, by request.
pub type Replies = BTreeMap<RequestKey, StoredReply>;

/// What a log holds: the newest state and every reply (`None`: no state, a fresh start), and
/// what was wrong on the way.
pub type Loaded = (Option<(OptimizerState, Replies)>, Vec<String>);

/// Why a state cannot be continued from.
#[derive(Debug, thiserror::Error)]
pub enum ResumeError {
    /// The state is another run's (another seed or exploitation method).
    #[error("the state is of seed {state_seed} and exploit {state_exploit}, this optimiser runs seed {seed} and exploit {exploit}")]
    OtherRun { state_seed: u64, state_exploit: String, seed: u64, exploit: &'static str },
    /// The ES baseline's state does not load (the cause is in the message, not a `source`).
    #[error("es: {0}")]
    Es(serde_json::Error),
    #[error("es: the state and this optimiser disagree on whether an ES runs")]
    EsDisagrees,
}

impl Optimizer<'_> {
    /// The state to write (it fails only if the ES baseline's state cannot be written as JSON).
    pub fn state(&self) -> Result<OptimizerState, serde_json::Error> {
        Ok(OptimizerState {
            seed: self.seed,
            exploit: self.cfg.exploit.name().into(),
            requests: self.requests,
            rng: self.rng.clone(),
            es: self.es.as_ref().map(|e| e.save()).transpose()?,
            es_best: self.es_best.as_ref().map(|b| (b.design.iter().map(|&v| f64::from(v)).collect(), f64::from(b.score), b.evaluations)),
        })
    }

    /// Continues from `s` and its `replies`, refusing a state of another seed or method.
    pub fn restore(&mut self, s: OptimizerState, replies: Replies) -> Result<(), ResumeError> {
        if s.seed != self.seed || s.exploit != self.cfg.exploit.name() {
            return Err(ResumeError::OtherRun {
                state_seed: s.seed,
                state_exploit: s.exploit,
                seed: self.seed,
                exploit: self.cfg.exploit.name(),
            });
        }
        match (&mut self.es, s.es) {
            (Some(es), Some(v)) => es.load(&v).map_err(ResumeError::Es)?,
            (None, None) => {}
            _ => return Err(ResumeError::EsDisagrees),
        }
        self.requests = s.requests;
        self.rng = s.rng;
        self.es_best = s.es_best.map(|(d, score, evaluations)| SearchResult {
            design: d.into_iter().map(|v| v as f32).collect(),
            score: score as f32,
            history: vec![score as f32],
            evaluations,
        });
        self.replies = replies;
        Ok(())
    }
}

/// One line of the log: a reply and the state after it.
#[derive(Serialize, Deserialize)]
struct Entry {
    key: RequestKey,
    reply: StoredReply,
    state: OptimizerState,
}

/// The optimiser's log, `DIR/optimizer-state.jsonl`: one JSON line per reply, holding the reply
/// and the state after it, appended and fsynced before the reply is sent.
///
/// Appending keeps the cost of a reply constant (a whole-state file rewritten after every reply
/// costs O(replies) each, O(n^2) over a run: the soak's 3,343 designs made it 781 KB per
/// write). A crash mid-append leaves a torn last line, which `load` cuts off: the state is then
/// the one before that reply, from which the same request gets the same answer again.
#[derive(Clone, Debug)]
pub struct StateFile {
    path: PathBuf,
}

impl StateFile {
    pub fn in_dir(dir: &Path) -> io::Result<Self> {
        fs::create_dir_all(dir)?;
        Ok(Self { path: dir.join("optimizer-state.jsonl") })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends `reply` to `key` and the state `s` after it, fsynced (and the directory, when
    /// the file is new).
    pub fn append(&self, key: RequestKey, reply: &StoredReply, s: &OptimizerState) -> io::Result<()> {
        let mut line = serde_json::to_vec(&Entry { key, reply: reply.clone(), state: s.clone() }).map_err(io::Error::other)?;
        line.push(b'\n');
        let new = !self.path.exists();
        let mut f = File::options().create(true).append(true).open(&self.path)?;
        f.write_all(&line)?;
        f.sync_all()?;
        if new && let Some(dir) = self.path.parent() {
            File::open(dir)?.sync_all()?;
        }
        Ok(())
    }

    /// The newest state and every reply, with what was wrong on the way (a torn last line is
    /// cut off the file; a damaged line elsewhere is skipped, its reply computed again if it
    /// is asked for); `None` when there is no state at all (a fresh start).
    pub fn load(&self) -> io::Result<Loaded> {
        let mut why = Vec::new();
        let bytes = match fs::read(&self.path) {
            Ok(b) => b,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok((None, why)),
            Err(e) => return Err(e),
        };
        let whole = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        if whole < bytes.len() {
            why.push(format!("{}: a torn last line ({} bytes) cut off", self.path.display(), bytes.len() - whole));
            let f = File::options().write(true).open(&self.path)?;
            f.set_len(whole as u64)?;
            f.sync_all()?;
        }
        let (mut state, mut replies) = (None, Replies::new());
        for (n, line) in bytes[..whole].split(|&b| b == b'\n').enumerate().filter(|(_, l)| !l.is_empty()) {
            match serde_json::from_slice::<Entry>(line) {
                Ok(e) => {
                    replies.insert(e.key, e.reply);
                    state = Some(e.state);
                }
                Err(e) => why.push(format!("{} line {}: {e}", self.path.display(), n + 1)),
            }
        }
        Ok((state.map(|s| (s, replies)), why))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(requests: u64) -> OptimizerState {
        OptimizerState { seed: 7, exploit: "pso-q".into(), requests, rng: coadapt_core::rng(requests, 0), es: None, es_best: None }
    }

    fn reply(v: f64) -> StoredReply {
        StoredReply {
            design: vec![v, 1.0],
            method: "pso-q, a \"quoted\" one,\nwith a newline".into(),
            predicted_objective: Some(v),
            design_rollouts: 0,
        }
    }

    /// A fresh directory under the system's temporary directory.
    fn tempdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("coadapt-optimizer-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        d
    }

    fn key(index: u32) -> RequestKey {
        RequestKey { index, rejected: 0 }
    }

    #[test]
    fn the_log_gives_the_newest_state_and_every_reply() {
        let f = StateFile::in_dir(&tempdir("newest")).unwrap();
        assert!(f.load().unwrap().0.is_none(), "no file: a fresh start");
        for i in 0..4 {
            f.append(key(i), &reply(f64::from(i) + 0.5), &state(u64::from(i) + 1)).unwrap();
        }
        let (got, why) = f.load().unwrap();
        let (s, replies) = got.unwrap();
        assert!(why.is_empty(), "{why:?}");
        assert_eq!(s.requests, 4);
        assert_eq!(replies.len(), 4);
        assert_eq!(replies[&key(2)], reply(2.5));
    }

    #[test]
    fn a_torn_last_line_is_cut_off_and_the_state_before_it_used() {
        let f = StateFile::in_dir(&tempdir("torn")).unwrap();
        for i in 0..3 {
            f.append(key(i), &reply(f64::from(i)), &state(u64::from(i) + 1)).unwrap();
        }
        let len = fs::metadata(f.path()).unwrap().len();
        // A crash in the middle of the fourth append.
        let mut torn = File::options().append(true).open(f.path()).unwrap();
        torn.write_all(b"{\"key\":{\"index\":3,\"rej").unwrap();
        let (got, why) = f.load().unwrap();
        let (s, replies) = got.unwrap();
        assert_eq!((s.requests, replies.len()), (3, 3));
        assert!(why[0].contains("torn last line (22 bytes)"), "{why:?}");
        assert_eq!(fs::metadata(f.path()).unwrap().len(), len, "the torn line is cut off the file");
        // The next append starts on a line of its own.
        f.append(key(3), &reply(3.0), &state(4)).unwrap();
        let (got, why) = f.load().unwrap();
        assert!(why.is_empty(), "{why:?}");
        assert_eq!(got.unwrap().0.requests, 4);
    }

    #[test]
    fn a_damaged_line_is_skipped_and_named() {
        let f = StateFile::in_dir(&tempdir("damaged")).unwrap();
        for i in 0..3 {
            f.append(key(i), &reply(f64::from(i)), &state(u64::from(i) + 1)).unwrap();
        }
        let text = fs::read_to_string(f.path()).unwrap();
        let second = text.find('\n').unwrap() + 1;
        let mut bytes = text.into_bytes();
        bytes[second] = b'#';
        fs::write(f.path(), bytes).unwrap();
        let (got, why) = f.load().unwrap();
        let (s, replies) = got.unwrap();
        assert_eq!(s.requests, 3, "the newest good line");
        assert!(!replies.contains_key(&key(1)) && replies.len() == 2);
        assert!(why.len() == 1 && why[0].contains("line 2"), "{why:?}");
    }
}
