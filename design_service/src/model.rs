//! The design critic as a model: Eq. 5.6 over fixed networks and start states.

use std::sync::Arc;

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::objective::{DesignObjective, ObjectiveError, ObjectiveWorkspace, QMode};
use coadapt_nn::Mlp;

/// Eq. 5.6 of the population networks of one version over one start-state batch.
#[derive(Debug)]
pub struct DesignModel {
    /// The robot (environment) name.
    pub robot: String,
    /// One name per design dimension.
    pub names: Vec<String>,
    /// The design box.
    pub bounds: BoxSpace,
    /// The population networks' version.
    pub weights_version: u64,
    /// The run id of the learner start the networks come from.
    pub run_id: String,
    objective: DesignObjective,
    mode: QMode,
}

impl DesignModel {
    /// `policy`/`phi` the population policy, `critic`/`thetas` its critic(s) (Q1, Q1 and Q2,
    /// then any ensemble heads, as many as `mode` reads), `start_states` `n x obs_dim`, the
    /// design in the observation columns `design_at..`.
    pub fn new(
        robot: String,
        names: Vec<String>,
        bounds: BoxSpace,
        weights_version: u64,
        run_id: String,
        nets: (&Mlp, &[f32], &Mlp, &[&[f32]]),
        start_states: &[f32],
        design_at: usize,
        mode: QMode,
    ) -> Result<Self, ObjectiveError> {
        let (policy, phi, critic, thetas) = nets;
        if names.len() != bounds.dim() {
            return Err(ObjectiveError::Shape {
                what: "design names",
                why: format!("{} names for {} dimensions", names.len(), bounds.dim()),
            });
        }
        let objective = DesignObjective::new(policy, phi, critic, thetas, start_states, design_at, bounds.dim())?;
        objective.check_mode(mode)?;
        Ok(Self { robot, names, bounds, weights_version, run_id, objective, mode })
    }

    pub fn design_dim(&self) -> usize {
        self.bounds.dim()
    }

    pub fn start_states(&self) -> usize {
        self.objective.n_states()
    }

    /// Scores `designs` (`n x design_dim`, checked by the caller) into `mean` and `spread`.
    pub fn score(&self, designs: &[f32], mean: &mut [f32], spread: &mut [f32], ws: &mut ObjectiveWorkspace) {
        self.objective.evaluate_with_spread(designs, self.mode, 256, mean, spread, ws);
    }

    /// Whether the model has two critics or more, so that [`Self::disagreement`] says something.
    pub fn has_disagreement(&self) -> bool {
        self.objective.heads() >= 2
    }

    /// The critics' disagreement about each design (the mean over the start states of their sd
    /// over the heads: `|Q1 - Q2| / 2` for the twin) into `out`; `false` with one critic.
    pub fn disagreement(&self, designs: &[f32], out: &mut [f32], ws: &mut ObjectiveWorkspace) -> bool {
        self.objective.disagreement(designs, 256, out, ws)
    }
}

/// One row of the run's designs (`designs.csv`).
#[derive(Clone, Debug, PartialEq)]
pub struct HistoryRow {
    pub index: usize,
    pub kind: String,
    pub design: Vec<f32>,
    pub episodes: usize,
    pub best_eval_return: Option<f32>,
    pub last_eval_return: Option<f32>,
    pub predicted_objective: Option<f32>,
    pub design_rollouts: u64,
    pub method: String,
    pub prototype: String,
}

/// A page of history.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HistoryPage {
    pub rows: Vec<HistoryRow>,
    /// Whether rows remain after these.
    pub more: bool,
}

/// A change to the run's designs.
#[derive(Clone, Debug, PartialEq)]
pub enum DesignEvent {
    /// A row, new or in a newer state.
    Row(HistoryRow),
    /// The run has ended: nothing more will change.
    Ended,
}

/// Why a [`ModelSource`] could not read the design history (the server answers INTERNAL,
/// "reading the history: ..."). A `from` past the last design is not an error: its page is
/// empty.
#[derive(Debug, thiserror::Error)]
pub enum HistoryError {
    /// A source that reads its rows from files could not; `what` names the file and what was
    /// done with it (the cause is in the message, not a `source`).
    #[error("{what}: {error}")]
    Io { what: String, error: std::io::Error },
}

/// Where a server finds the current model and the run's designs.
pub trait ModelSource: Send + Sync + std::fmt::Debug {
    /// The current model (`None`: not ready, no networks yet).
    fn model(&self) -> Option<Arc<DesignModel>>;
    /// The rows of the design history from index `from` on: at most `max` (at least one),
    /// and more only to end on a whole design (every row of its index).
    fn history(&self, from: usize, max: usize) -> Result<HistoryPage, HistoryError>;
    /// The changes from now on; `None` once the run has ended (a finished run's files).
    fn subscribe(&self) -> Option<tokio::sync::broadcast::Receiver<DesignEvent>>;
}

/// The rows of `rows` (ordered by index) from index `from` on, at most `max` (at least one)
/// and more only to end on a whole design.
pub(crate) fn page(rows: &[HistoryRow], from: usize, max: usize) -> HistoryPage {
    let start = rows.partition_point(|r| r.index < from);
    let mut end = (start + max.max(1)).min(rows.len());
    // A page ends after a whole design: its rejected proposals and its final row share one
    // index, and the next page starts at the next index.
    while end < rows.len() && rows[end].index == rows[end - 1].index {
        end += 1;
    }
    HistoryPage { rows: rows[start..end].to_vec(), more: end < rows.len() }
}

/// A model and history that do not change: a finished run.
#[derive(Debug)]
pub struct StaticSource {
    pub model: Arc<DesignModel>,
    pub history: Vec<HistoryRow>,
}

impl ModelSource for StaticSource {
    fn model(&self) -> Option<Arc<DesignModel>> {
        Some(self.model.clone())
    }

    fn history(&self, from: usize, max: usize) -> Result<HistoryPage, HistoryError> {
        Ok(page(&self.history, from, max))
    }

    fn subscribe(&self) -> Option<tokio::sync::broadcast::Receiver<DesignEvent>> {
        None
    }
}
