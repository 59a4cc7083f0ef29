//! What the learner tells as it goes ([`RunEvent`], [`Stats`] for `/metrics`) and what a
//! finished run leaves ([`RunOutcome`]).

use crate::fear::FearLearner;
use crate::flow::LearnerTime;
use crate::prototype::{Outcome, ResetMode};
use crate::run_dir::{DesignRow, EpisodeRow};

/// What the learner reports as it goes (for progress lines).
#[derive(Clone, Debug)]
pub enum RunEvent<'a> {
    DesignStart {
        index: usize,
        row: &'a DesignRow,
    },
    Episode {
        row: &'a EpisodeRow,
        episodes_in_design: usize,
    },
    DesignEnd {
        row: &'a DesignRow,
    },
    /// `row` waits for its prototype (`prototype.json` is written); `names` name the entries
    /// of `row.design`.
    AwaitingPrototype {
        index: usize,
        row: &'a DesignRow,
        names: &'a [String],
    },
    /// The operator's verdict on `row`'s prototype; `requested` is the design asked for (as
    /// built, `row.design` is the measured one).
    PrototypeDecided {
        row: &'a DesignRow,
        outcome: &'a Outcome,
        requested: &'a [f32],
    },
    /// An episode waits for the robot to be reset by hand (`reset.json` is written).
    AwaitingReset {
        design_index: usize,
        episode: usize,
        episodes_in_design: usize,
        mode: ResetMode,
    },
    ResetConfirmed {
        design_index: usize,
        episode: usize,
        mode: ResetMode,
    },
    /// The learner's counters, after every episode and snapshot (for `/metrics`).
    Stats(&'a Stats),
}

/// What `/metrics` shows of the learner.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stats {
    /// The design being trained (0-based).
    pub design: usize,
    /// Episodes finished in the run (all starts of the learner).
    pub episodes: u64,
    /// Environment steps of training episodes.
    pub steps: u64,
    pub time: LearnerTime,
    pub replay_population: usize,
    pub replay_species: usize,
    pub start_states: usize,
    pub updates_population: u64,
    pub updates_individual: u64,
    /// The last episode's policy lag.
    pub policy_lag: u64,
    /// Snapshots taken by this start, their total seconds, the last one's size and time
    /// (seconds since the Unix epoch; 0: none yet).
    pub snapshots: u64,
    pub snapshot_seconds: f64,
    pub snapshot_bytes: u64,
    pub snapshot_unix: f64,
    /// Starts of the learner that resumed this run.
    pub resumes: u64,
    /// Seconds the last design request took.
    pub design_request_seconds: f64,
}

/// What a finished (or interrupted) run leaves.
#[derive(Debug)]
pub struct RunOutcome {
    pub learner: FearLearner,
    /// The designs trained on (as built), in order.
    pub designs: Vec<DesignRow>,
    /// Proposals the operator rejected, in order (each also a row of `designs.csv`).
    pub rejected: Vec<DesignRow>,
    pub interrupted: bool,
    /// Where the learner's time went.
    pub time: LearnerTime,
}
