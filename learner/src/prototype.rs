//! The prototype step for real hardware: the files through which a run that waits for an
//! operator (`schedule.confirm-designs`, `schedule.reset-needs-confirmation`) and
//! `coadapt confirm` talk. Both sides' functions live here, so the command stays thin and the
//! tests play the operator with the very code the command runs.
//!
//! # Files in the run directory
//! The learner owns the run directory and the operator works on the same machine, so plain
//! files are the channel: they survive either side restarting, and `cat` shows the state.
//! - `prototype.json` ([`Prototype`]), written by the learner when a design needs building:
//!   index, proposal (1, then 2 after a rejection, ...), kind, method, the design, its named
//!   `dimensions`, the box `low`/`high`, `status` and `waiting_since_unix`. The status is
//!   `awaiting`, then `confirmed`, `as-built` (with `as_built`) or `rejected` once the learner
//!   has read a decision, or `interrupted` if the run stopped while it waited.
//! - `prototype-decision.json` ([`PrototypeDecision`]), written by `coadapt confirm`: the index
//!   and proposal it answers, `confirm` or `reject`, and the measured dimensions of what was
//!   built (`as_built`, or null). The learner polls for it, deletes it once read, and ignores
//!   (with a warning) one for another index or proposal than the one awaiting.
//! - `reset.json` ([`ResetRequest`]) and `reset-decision.json` ([`ResetDecision`]): the same
//!   for resetting the robot by hand before an episode (training or evaluation).
//!
//! Every file is written to `NAME.tmp` and renamed over `NAME`, so neither side ever reads
//! half of one.

use std::io;
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::run_dir::write_atomically;

/// The design awaiting a prototype, written by the learner.
pub const PROTOTYPE_FILE: &str = "prototype.json";
/// The operator's answer to [`PROTOTYPE_FILE`], written by `coadapt confirm`.
pub const PROTOTYPE_DECISION_FILE: &str = "prototype-decision.json";
/// The episode awaiting a reset by hand, written by the learner.
pub const RESET_FILE: &str = "reset.json";
/// The operator's answer to [`RESET_FILE`], written by `coadapt confirm --reset`.
pub const RESET_DECISION_FILE: &str = "reset-decision.json";

/// Where a prototype (or a reset) stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Status {
    Awaiting,
    Confirmed,
    AsBuilt,
    Rejected,
    /// The run stopped while it waited; nobody reads a decision any more.
    Interrupted,
}

/// `prototype.json`: a design the run waits to see built.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Prototype {
    /// The design's index (from 0, as in `designs.csv`).
    pub index: usize,
    /// 1 for the first proposal for this index, 2 after one rejection, ...
    pub proposal: usize,
    /// `initial`, `exploit` or `explore`.
    pub kind: String,
    /// How it was chosen (`fixed`, `pso-q`, `novelty`, ...).
    pub method: String,
    /// The requested design vector.
    pub design: Vec<f32>,
    /// The design by name, in the design vector's order.
    #[serde(with = "ordered_map")]
    pub dimensions: Vec<(String, f32)>,
    /// The design box: what was built must lie in it.
    pub low: Vec<f32>,
    pub high: Vec<f32>,
    pub status: Status,
    /// When the wait began (seconds since the Unix epoch).
    pub waiting_since_unix: f64,
    /// The measured design, once the status is `as-built`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub as_built: Option<Vec<f32>>,
}

impl Prototype {
    /// A fixed initial design: there is no optimiser proposal to replace it with.
    pub fn is_fixed(&self) -> bool {
        self.kind == "initial"
    }
}

/// The operator's verdict.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    Confirm,
    Reject,
}

/// `prototype-decision.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrototypeDecision {
    pub index: usize,
    pub proposal: usize,
    pub decision: Verdict,
    /// The measured dimensions of what was built (replacing the requested ones), or null.
    pub as_built: Option<Vec<f32>>,
}

/// What the learner makes of a valid decision.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Confirmed,
    AsBuilt(Vec<f32>),
    Rejected,
}

/// Which episode a reset comes before.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ResetMode {
    Train,
    /// The evaluation of the training episode of the same number.
    Eval,
}

/// `reset.json`: an episode waiting for the robot to be reset by hand.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResetRequest {
    pub design_index: usize,
    /// Episode within the design, from 0.
    pub episode: usize,
    pub mode: ResetMode,
    pub status: Status,
    pub waiting_since_unix: f64,
}

/// `reset-decision.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResetDecision {
    pub design_index: usize,
    pub episode: usize,
    pub mode: ResetMode,
    pub decision: Verdict,
}

/// What is said of a rejected fixed initial design, after `design N` (by `coadapt confirm`, and
/// by the learner when a decision file says it).
const FIXED_DESIGN: &str =
    "is a fixed initial design: there is no next-best design to build instead; build it, or give what was built with --as-built";

/// Why `coadapt confirm` refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfirmError {
    #[error("nothing in {} awaits {what} ({why})", .dir.display())]
    NothingAwaits { dir: PathBuf, what: &'static str, why: String },
    #[error("{}: {why}", .path.display())]
    Unreadable { path: PathBuf, why: String },
    #[error("--as-built: {0}")]
    AsBuilt(AsBuiltError),
    #[error("design {} {}", .index + 1, FIXED_DESIGN)]
    FixedDesign { index: usize },
    #[error("writing {}: {source}", .path.display())]
    Write { path: PathBuf, source: io::Error },
    /// The answer was given to another proposal than the one awaiting now (the page showed an
    /// older one): nothing was written. Indices from 0, said from 1.
    #[error(
        "this answer is to design {} (proposal {seen_proposal}), but design {} (proposal {awaiting_proposal}) awaits now: nothing was written; look at the new proposal first",
        .seen_index + 1,
        .awaiting_index + 1
    )]
    Stale { seen_index: usize, seen_proposal: usize, awaiting_index: usize, awaiting_proposal: usize },
    /// The same for a reset; both as [`reset_name`] says them.
    #[error("this answer is to {seen}, but {awaiting} awaits a reset now: nothing was written")]
    StaleReset { seen: String, awaiting: String },
}

/// Why measured dimensions do not fit a prototype: the first bad entry (`entry` counts from 0,
/// the message from 1, as an operator counts).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum AsBuiltError {
    /// Not one value per design entry; `names` lists the entries.
    #[error("{got} values, but the design has {expected} ({names})")]
    Count { got: usize, expected: usize, names: String },
    #[error("entry {} ({name}) is {value}, not a finite number", .entry + 1)]
    NotFinite { entry: usize, name: String, value: f32 },
    #[error("entry {} ({name}) = {value} is outside the design box [{low}, {high}]", .entry + 1)]
    OutsideBox { entry: usize, name: String, value: f32, low: f32, high: f32 },
}

/// Why the learner ignored an operator's decision file (it says so and keeps waiting).
#[derive(Debug, thiserror::Error)]
pub enum DecisionError {
    /// The file is not a decision; `file` is its name.
    #[error("{file}: {error}")]
    Unreadable { file: String, error: serde_json::Error },
    /// It answers another design or proposal than the one awaiting (indices from 0).
    #[error(
        "it answers design {} (proposal {proposal}), but design {} (proposal {awaiting_proposal}) awaits its prototype",
        .index + 1,
        .awaiting_index + 1
    )]
    OtherPrototype { index: usize, proposal: usize, awaiting_index: usize, awaiting_proposal: usize },
    #[error("a rejection with as-built dimensions")]
    RejectionAsBuilt,
    /// A rejection of a fixed initial design (said as [`ConfirmError::FixedDesign`] says it).
    #[error("design {} {}", .index + 1, FIXED_DESIGN)]
    FixedDesign { index: usize },
    #[error("as_built: {0}")]
    AsBuilt(AsBuiltError),
    /// It answers another reset than the one awaiting; both as [`reset_name`] says them.
    #[error("it answers {answers}, but {awaiting} awaits a reset")]
    OtherReset { answers: String, awaiting: String },
    #[error("a reset cannot be rejected")]
    ResetRejected,
}

/// What `coadapt confirm` answered.
#[derive(Clone, Debug, PartialEq)]
pub enum Answer {
    Confirm,
    AsBuilt(Vec<f32>),
    Reject,
}

/// What `coadapt confirm` did: the prototype it answered and the decision it wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct Confirmation {
    pub prototype: Prototype,
    pub decision: PrototypeDecision,
    /// An earlier decision the learner had not read yet was replaced.
    pub replaced: bool,
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// `design` by name: `names[i]` for entry `i`, or `design[i]` where the names do not fit.
pub fn named_dimensions(names: &[String], design: &[f32]) -> Vec<(String, f32)> {
    let fit = names.len() == design.len();
    design.iter().enumerate().map(|(i, &v)| (if fit { names[i].clone() } else { format!("design[{i}]") }, v)).collect()
}

/// `back thigh 1.270, back shin 0.870, ...`
pub fn describe(dimensions: &[(String, f32)]) -> String {
    dimensions.iter().map(|(n, v)| format!("{n} {v:.3}")).collect::<Vec<_>>().join(", ")
}

/// Checks measured dimensions against the prototype: one per design entry, finite, inside the
/// box; the message names the first bad entry.
pub fn check_as_built(p: &Prototype, v: &[f32]) -> Result<(), AsBuiltError> {
    if v.len() != p.design.len() {
        return Err(AsBuiltError::Count { got: v.len(), expected: p.design.len(), names: names(p) });
    }
    for (i, &x) in v.iter().enumerate() {
        let name = p.dimensions.get(i).map_or_else(|| format!("design[{i}]"), |d| d.0.clone());
        if !x.is_finite() {
            return Err(AsBuiltError::NotFinite { entry: i, name, value: x });
        }
        let (lo, hi) = (p.low.get(i).copied().unwrap_or(f32::NEG_INFINITY), p.high.get(i).copied().unwrap_or(f32::INFINITY));
        if !(lo..=hi).contains(&x) {
            return Err(AsBuiltError::OutsideBox { entry: i, name, value: x, low: lo, high: hi });
        }
    }
    Ok(())
}

fn names(p: &Prototype) -> String {
    p.dimensions.iter().map(|d| d.0.as_str()).collect::<Vec<_>>().join(", ")
}

/// Writes `value` as JSON to `path`, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> io::Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(io::Error::other)?;
    write_atomically(path, &(text + "\n"))
}

/// Reads JSON from `path`; `Ok(None)` when there is no such file.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<Option<T>, ConfirmError> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(ConfirmError::Unreadable { path: path.to_path_buf(), why: e.to_string() }),
    };
    serde_json::from_str(&text).map(Some).map_err(|e| ConfirmError::Unreadable { path: path.to_path_buf(), why: e.to_string() })
}

// ---------------------------------------------------------------------------------------------
// The learner's side.

/// Reads and deletes the decision file `name` in `dir`: `None` while there is none, else the
/// decision or why it could not be read.
pub fn take_decision<T: DeserializeOwned>(dir: &Path, name: &str) -> io::Result<Option<Result<T, DecisionError>>> {
    let path = dir.join(name);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e),
    };
    std::fs::remove_file(&path)?;
    Ok(Some(serde_json::from_str(&text).map_err(|error| DecisionError::Unreadable { file: name.to_string(), error })))
}

/// What `decision` means for the awaiting prototype `p`, or why it does not apply to it.
pub fn accept(p: &Prototype, decision: &PrototypeDecision) -> Result<Outcome, DecisionError> {
    if (decision.index, decision.proposal) != (p.index, p.proposal) {
        return Err(DecisionError::OtherPrototype {
            index: decision.index,
            proposal: decision.proposal,
            awaiting_index: p.index,
            awaiting_proposal: p.proposal,
        });
    }
    match (decision.decision, &decision.as_built) {
        (Verdict::Reject, Some(_)) => Err(DecisionError::RejectionAsBuilt),
        (Verdict::Reject, None) if p.is_fixed() => Err(DecisionError::FixedDesign { index: p.index }),
        (Verdict::Reject, None) => Ok(Outcome::Rejected),
        (Verdict::Confirm, None) => Ok(Outcome::Confirmed),
        (Verdict::Confirm, Some(v)) => {
            check_as_built(p, v).map_err(DecisionError::AsBuilt)?;
            Ok(Outcome::AsBuilt(v.clone()))
        }
    }
}

/// Whether `decision` answers the awaiting reset `r`, or why not.
pub fn accept_reset(r: &ResetRequest, decision: &ResetDecision) -> Result<(), DecisionError> {
    if (decision.design_index, decision.episode, decision.mode) != (r.design_index, r.episode, r.mode) {
        return Err(DecisionError::OtherReset {
            answers: reset_name(decision.mode, decision.episode, decision.design_index),
            awaiting: reset_name(r.mode, r.episode, r.design_index),
        });
    }
    match decision.decision {
        Verdict::Confirm => Ok(()),
        Verdict::Reject => Err(DecisionError::ResetRejected),
    }
}

// ---------------------------------------------------------------------------------------------
// The operator's side: `coadapt confirm`.

/// Answers the prototype awaiting in `dir`: writes `prototype-decision.json`. Refuses when
/// nothing awaits, a fixed initial design is rejected, or the measured dimensions do not fit.
pub fn confirm_prototype(dir: &Path, answer: &Answer) -> Result<Confirmation, ConfirmError> {
    confirm_prototype_of(dir, None, answer)
}

/// [`confirm_prototype`], refused with [`ConfirmError::Stale`] unless the awaiting prototype is
/// `seen` (index, proposal): the operator page answers the proposal it showed, never a newer
/// one that replaced it meanwhile. `None`: whatever awaits (`coadapt confirm`).
pub fn confirm_prototype_of(dir: &Path, seen: Option<(usize, usize)>, answer: &Answer) -> Result<Confirmation, ConfirmError> {
    let path = dir.join(PROTOTYPE_FILE);
    let nothing = |why: String| ConfirmError::NothingAwaits { dir: dir.to_path_buf(), what: "a prototype", why };
    let Some(p) = read_json::<Prototype>(&path)? else {
        return Err(nothing(format!("no {PROTOTYPE_FILE}: the run does not confirm designs, or has not chosen one yet")));
    };
    if p.status != Status::Awaiting {
        return Err(nothing(format!("design {}'s prototype is {}", p.index + 1, status_word(p.status))));
    }
    if let Some((seen_index, seen_proposal)) = seen
        && (seen_index, seen_proposal) != (p.index, p.proposal)
    {
        return Err(ConfirmError::Stale { seen_index, seen_proposal, awaiting_index: p.index, awaiting_proposal: p.proposal });
    }
    let (decision, as_built) = match answer {
        Answer::Confirm => (Verdict::Confirm, None),
        Answer::AsBuilt(v) => {
            check_as_built(&p, v).map_err(ConfirmError::AsBuilt)?;
            (Verdict::Confirm, Some(v.clone()))
        }
        Answer::Reject if p.is_fixed() => return Err(ConfirmError::FixedDesign { index: p.index }),
        Answer::Reject => (Verdict::Reject, None),
    };
    let decision = PrototypeDecision { index: p.index, proposal: p.proposal, decision, as_built };
    let out = dir.join(PROTOTYPE_DECISION_FILE);
    let replaced = out.exists();
    write_json(&out, &decision).map_err(|source| ConfirmError::Write { path: out, source })?;
    Ok(Confirmation { prototype: p, decision, replaced })
}

/// Confirms the reset awaiting in `dir`: writes `reset-decision.json`. Returns the request
/// answered and whether an unread earlier answer was replaced.
pub fn confirm_reset(dir: &Path) -> Result<(ResetRequest, bool), ConfirmError> {
    confirm_reset_of(dir, None)
}

/// [`confirm_reset`], refused with [`ConfirmError::StaleReset`] unless the awaiting reset is
/// `seen` (design index, episode, mode), as [`confirm_prototype_of`].
pub fn confirm_reset_of(dir: &Path, seen: Option<(usize, usize, ResetMode)>) -> Result<(ResetRequest, bool), ConfirmError> {
    let nothing = |why: String| ConfirmError::NothingAwaits { dir: dir.to_path_buf(), what: "a reset", why };
    let Some(r) = read_json::<ResetRequest>(&dir.join(RESET_FILE))? else {
        return Err(nothing(format!("no {RESET_FILE}: the run does not confirm resets, or has not reached an episode yet")));
    };
    if r.status != Status::Awaiting {
        return Err(nothing(format!("the reset before {} is {}", reset_name(r.mode, r.episode, r.design_index), status_word(r.status))));
    }
    if let Some((design_index, episode, mode)) = seen
        && (design_index, episode, mode) != (r.design_index, r.episode, r.mode)
    {
        return Err(ConfirmError::StaleReset {
            seen: reset_name(mode, episode, design_index),
            awaiting: reset_name(r.mode, r.episode, r.design_index),
        });
    }
    let decision = ResetDecision { design_index: r.design_index, episode: r.episode, mode: r.mode, decision: Verdict::Confirm };
    let out = dir.join(RESET_DECISION_FILE);
    let replaced = out.exists();
    write_json(&out, &decision).map_err(|source| ConfirmError::Write { path: out, source })?;
    Ok((r, replaced))
}

/// `episode 4 of design 3`, or `the evaluation after episode 4 of design 3` (numbered from 1,
/// as the progress lines number them).
pub fn reset_name(mode: ResetMode, episode: usize, design_index: usize) -> String {
    match mode {
        ResetMode::Train => format!("episode {} of design {}", episode + 1, design_index + 1),
        ResetMode::Eval => format!("the evaluation after episode {} of design {}", episode + 1, design_index + 1),
    }
}

fn status_word(s: Status) -> &'static str {
    match s {
        Status::Awaiting => "awaiting",
        Status::Confirmed => "confirmed already",
        Status::AsBuilt => "confirmed as built already",
        Status::Rejected => "rejected already",
        Status::Interrupted => "moot: the run stopped while it waited",
    }
}

/// `[(name, value)]` as a JSON object in that order (a map type would sort the names).
mod ordered_map {
    use serde::de::{MapAccess, Visitor};
    use serde::ser::SerializeMap;
    use serde::{Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[(String, f32)], s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(v.len()))?;
        for (k, x) in v {
            m.serialize_entry(k, x)?;
        }
        m.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<(String, f32)>, D::Error> {
        struct Entries;
        impl<'de> Visitor<'de> for Entries {
            type Value = Vec<(String, f32)>;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("an object of design dimensions by name")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut a: A) -> Result<Self::Value, A::Error> {
                let mut out = Vec::new();
                while let Some(e) = a.next_entry::<String, f32>()? {
                    out.push(e);
                }
                Ok(out)
            }
        }
        d.deserialize_map(Entries)
    }
}
