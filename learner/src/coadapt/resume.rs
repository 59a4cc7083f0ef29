//! Snapshots of the run loop and resuming from one: what the schedule needs besides the
//! learner's networks and buffers ([`crate::fear::FearLearner::save_state`]) to continue as if
//! nothing had happened: the design in progress and its episodes, the rows written, the
//! counters that number weights and assignments, and the time spent.
//!
//! Snapshots are taken only where no episode is out with an actor (in lock-step, after every
//! episode's row; in async flow at least at the end of each design), so a resumed run issues
//! exactly the episodes the interrupted one would have issued next, with the same seeds.

use std::path::PathBuf;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::CoadaptError;
use super::driver::Learner;
use crate::fear::ActingPolicy;
use crate::flow::LearnerTime;
use crate::run_dir::{DesignRow, RunWriter, WrittenSoFar};
use crate::snapshot::{self, SnapshotConfig, StateIn};

/// Where a fresh run's population networks come from, other than a random start: a checkpoint
/// of another run (`policy`, `q1`, `q2`, `q1_target`, `q2_target`), and optionally that run's
/// newest snapshot for its population replay. Adam's moments, alpha and every other buffer
/// start fresh: the thesis copies the networks only.
#[derive(Debug)]
pub struct Transfer {
    pub networks: PathBuf,
    pub replay: Option<StateIn>,
}

/// The snapshots of one learner start.
#[derive(Debug, Default)]
pub struct Snapshots {
    pub cfg: SnapshotConfig,
    /// `RUN_DIR/snapshots`; `None`: no snapshots.
    pub root: Option<PathBuf>,
    /// This learner start's id (new at every start).
    pub run_id: String,
    /// A fresh run's population networks (and replay) from another run: transfer (thesis
    /// section 6.1). Not used when the run continues from a snapshot, which holds them already.
    pub transfer: Option<Transfer>,
    /// The checked contents of the snapshot to continue from.
    pub resume: Option<StateIn>,
    /// Sequence number of the next snapshot.
    pub next_sequence: u64,
    /// Snapshots this start took, and the seconds they took.
    pub taken: u64,
    pub seconds: f64,
    /// Size of the newest snapshot (bytes) and when it was taken.
    pub last_bytes: u64,
    pub last_at: Option<Instant>,
    /// How long the newest snapshot took to write (seconds).
    pub last_write_seconds: f64,
    /// The newest snapshot's time, seconds since the Unix epoch (0: none yet).
    pub last_unix: f64,
}

impl Snapshots {
    /// No snapshots at all.
    pub fn off() -> Self {
        Self { cfg: SnapshotConfig { every_episodes: 0, ..SnapshotConfig::default() }, ..Self::default() }
    }
}

/// A design whose episodes were under way at the snapshot.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct InDesign {
    pub row: DesignRow,
    /// Episodes finished (and written) of the design.
    pub episodes: usize,
}

/// Where the schedule stands.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct Progress {
    /// The design in progress, or the next one to choose.
    pub design: usize,
    pub in_design: Option<InDesign>,
    /// Finished designs (not in the snapshot: read back from `designs.csv`, see
    /// [`Progress::rebuild`]).
    #[serde(skip)]
    pub rows: Vec<DesignRow>,
    /// The designs chosen so far, concatenated (sent with every design request; rebuilt).
    #[serde(skip)]
    pub chosen: Vec<f32>,
    /// Where the CSV files stood: a snapshot's size does not grow with the number of designs.
    pub written: WrittenSoFar,
    pub global: u64,
    pub steps: u64,
    pub acting_version: u64,
    pub acting_which: Option<ActingPolicy>,
    pub acting_dirty: bool,
    pub population_version: u64,
    pub next_assignment: u64,
    pub time: LearnerTime,
    /// Seconds since the run started (episodes.csv's `seconds` goes on from it).
    pub seconds: f64,
    /// Learner starts that resumed the run.
    #[serde(default)]
    pub resumes: u64,
}

impl Progress {
    pub fn start() -> Self {
        Self {
            design: 0,
            in_design: None,
            rows: Vec::new(),
            chosen: Vec::new(),
            written: WrittenSoFar::default(),
            global: 0,
            steps: 0,
            acting_version: 0,
            acting_which: None,
            acting_dirty: true,
            population_version: 0,
            next_assignment: 0,
            time: LearnerTime::default(),
            seconds: 0.0,
            resumes: 0,
        }
    }
}

impl Progress {
    /// Rebuilds what the snapshot leaves out from `written`, every row of `designs.csv` at the
    /// snapshot: the finished designs, the designs chosen (and the one in progress), and the
    /// operator's rejections (returned).
    pub fn rebuild(&mut self, written: Vec<DesignRow>) -> Vec<DesignRow> {
        let mut rejected = Vec::new();
        for r in written {
            if r.prototype == crate::run_dir::PROTOTYPE_REJECTED {
                rejected.push(r);
            } else if r.index < self.design {
                self.chosen.extend_from_slice(&r.design);
                self.rows.push(r);
            }
        }
        if let Some(d) = &self.in_design {
            self.chosen.extend_from_slice(&d.row.design);
        }
        rejected
    }
}

/// The counters that handing out an episode moves, as they were when nothing was out (see
/// `snapshot_at_quiet` in the schedule's loop).
#[derive(Clone, Debug)]
pub(super) struct QuietPoint {
    acting_version: u64,
    acting_which: Option<ActingPolicy>,
    acting_dirty: bool,
    next_assignment: u64,
    /// Population updates made while waiting for an operator, by then: the one way the
    /// networks change with nothing out (`train-while-waiting` during a reset wait).
    updates_while_waiting: u64,
}

impl Learner<'_> {
    /// The counters now, to go back to with [`Learner::back_to`].
    pub(super) fn quiet_point(&self) -> QuietPoint {
        QuietPoint {
            acting_version: self.acting_version,
            acting_which: self.acting_which,
            acting_dirty: self.acting_dirty,
            next_assignment: self.fleet.last_id(),
            updates_while_waiting: self.time.updates_while_waiting,
        }
    }

    /// Puts back the counters of `at` and forgets the episodes handed out since. Population
    /// networks trained while waiting for an operator since `at` (a reset wait with
    /// `train-while-waiting`) stay trained, so the acting weights stay marked stale, as the
    /// wait marked them (the population policy may be the acting one): the resumed run
    /// publishes them under a new version instead of handing out changed weights under the
    /// version of the ones before.
    pub(super) fn back_to(&mut self, at: &QuietPoint) {
        self.fleet.forget_all();
        self.acting_version = at.acting_version;
        self.acting_which = at.acting_which;
        self.acting_dirty = at.acting_dirty || self.time.updates_while_waiting > at.updates_while_waiting;
        self.fleet.set_last_id(at.next_assignment);
    }

    /// Fills in the counters this side keeps.
    pub(super) fn progress(&self, p: &mut Progress) {
        p.acting_version = self.acting_version;
        p.acting_which = self.acting_which;
        p.acting_dirty = self.acting_dirty;
        p.population_version = self.population_version;
        p.next_assignment = self.fleet.last_id();
        p.time = self.time();
    }

    /// Restores the counters of `p` (the acting weights are published again under their
    /// version before the next episode: new actors have none).
    pub(super) fn restore(&mut self, p: &Progress) {
        self.acting_version = p.acting_version;
        self.acting_which = p.acting_which;
        self.acting_dirty = p.acting_dirty;
        self.republish = true;
        self.population_version = p.population_version;
        self.fleet.set_last_id(p.next_assignment);
        self.fleet.stats = coadapt_fleet::DispatchStats::default();
        self.time = p.time;
    }

    /// Takes a snapshot of the learner and `p` (rows of `out`).
    pub(super) fn snapshot(&self, p: &mut Progress, out: &mut RunWriter, snaps: &mut Snapshots, label: &str) -> Result<(), CoadaptError> {
        let Some(root) = snaps.root.clone() else { return Ok(()) };
        let t = Instant::now();
        self.progress(p);
        out.sync()?;
        p.written = out.written_so_far();
        let seq = snaps.next_sequence;
        let dir = snapshot::write(&root, seq, &snaps.run_id, label, snaps.cfg.keep, |o| {
            self.fear.save_state(o)?;
            o.put("progress", &*p)
        })?;
        snaps.next_sequence += 1;
        snaps.taken += 1;
        snaps.last_write_seconds = t.elapsed().as_secs_f64();
        snaps.seconds += snaps.last_write_seconds;
        snaps.last_bytes = std::fs::read_dir(&dir)?.filter_map(|e| e.ok()?.metadata().ok()).map(|m| m.len()).sum();
        snaps.last_at = Some(Instant::now());
        snaps.last_unix = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
        Ok(())
    }

    /// The counters for `/metrics`.
    pub(super) fn stats(&self, design: usize, episodes: u64, steps: u64, policy_lag: u64, snaps: &Snapshots, resumes: u64) -> super::Stats {
        use crate::fear::ActingPolicy::{Individual, Population};
        super::Stats {
            design,
            episodes,
            steps,
            time: self.time(),
            replay_population: self.fear.population_transitions(),
            replay_species: self.fear.species_transitions(),
            start_states: self.fear.start_states(),
            updates_population: self.fear.agent(Population).updates(),
            updates_individual: self.fear.agent(Individual).updates(),
            policy_lag,
            snapshots: snaps.taken,
            snapshot_seconds: snaps.seconds,
            snapshot_bytes: snaps.last_bytes,
            snapshot_unix: snaps.last_unix,
            resumes,
            design_request_seconds: self.last_request_seconds,
        }
    }
}
