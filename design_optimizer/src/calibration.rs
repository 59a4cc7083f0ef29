//! Calibration of the design objective (issue 28): does the critic order bodies the way the
//! robot does?
//!
//! Predicted objectives grow over a run as the critic learns, so a correlation across a run's
//! designs mostly measures time. At each exploitation request the optimiser therefore also scores,
//! with the networks and start states of that one request, the design it chose, the random
//! design it will propose next (the exploration design trained right after the chosen one, when
//! exploration is random) and every design trained before. Once those designs have been trained,
//! `scripts/calibration_report.py` sets the predicted order against the achieved one (best
//! evaluation returns in `designs.csv`).
//!
//! The rows go to `calibration.csv` beside the optimiser's state file. Scoring draws nothing from
//! the optimiser's generator (the next random design comes from a copy of it), so a run writes
//! the same designs with or without it.

use std::io::Write;
use std::path::{Path, PathBuf};

use coadapt_transport::{DesignKind, DesignReply, DesignRequest, Weights};

use crate::role::{ExploreMethod, Optimizer};
use crate::{CriticObjective, ObjectiveError, SwarmObjective};

/// Which design a calibration row scores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Candidate {
    /// The design the request was answered with.
    Chosen,
    /// The random design the next (exploration) request will get.
    NextRandom,
    /// A design trained before this request, with its index in the run.
    Trained(u32),
}

/// One design scored at one request.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationRow {
    /// The request's design index.
    pub request: u32,
    pub candidate: Candidate,
    pub design: Vec<f32>,
    /// Eq. 5.6 under the request's networks, in the optimiser's `q` mode.
    pub predicted: f32,
}

impl Optimizer<'_> {
    /// The calibration rows of an answered request: none for exploration requests.
    pub fn calibration(&self, req: &DesignRequest, w: &Weights, reply: &DesignReply) -> Result<Vec<CalibrationRow>, ObjectiveError> {
        if req.kind != DesignKind::Exploit {
            return Ok(Vec::new());
        }
        let dim = self.spec_bounds().dim();
        let mut candidates: Vec<(Candidate, Vec<f32>)> = vec![(Candidate::Chosen, reply.design.clone())];
        if self.cfg.explore == ExploreMethod::Random {
            let mut rng = self.rng.clone();
            let rejected = crate::reject::Rejected::new(&req.rejected, self.spec_bounds(), self.cfg.reject_radius);
            if let Ok(r) = crate::role::random_design(self.spec_bounds(), &mut rng, &rejected, self.cfg.reject_radius) {
                candidates.push((Candidate::NextRandom, r.design));
            }
        }
        for (i, d) in req.chosen.chunks_exact(dim.max(1)).enumerate() {
            candidates.push((Candidate::Trained(i as u32), d.to_vec()));
        }
        let objective = self.objective(w, &req.start_states)?;
        let mut q = CriticObjective::new(&objective, self.q_mode(), self.cfg.cores);
        let flat: Vec<f32> = candidates.iter().flat_map(|(_, d)| d.iter().copied()).collect();
        let mut scores = vec![0.0; candidates.len()];
        q.evaluate(&flat, &mut scores);
        Ok(candidates
            .into_iter()
            .zip(scores)
            .map(|((candidate, design), predicted)| CalibrationRow { request: req.index, candidate, design, predicted })
            .collect())
    }
}

/// `calibration.csv` beside the optimiser's state file.
#[derive(Debug)]
pub struct CalibrationFile {
    path: PathBuf,
}

/// The file's header.
pub const HEADER: &str = "request,candidate,trained_index,predicted_objective,design";

impl CalibrationFile {
    pub fn beside(state_file: &Path) -> Self {
        Self { path: state_file.with_file_name("calibration.csv") }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends `rows` (the header first when the file is new). A request answered again after a
    /// restart may appear twice; readers keep its last rows.
    pub fn append(&self, rows: &[CalibrationRow]) -> std::io::Result<()> {
        if rows.is_empty() {
            return Ok(());
        }
        let mut text = String::new();
        let new = std::fs::metadata(&self.path).map_or(true, |m| m.len() == 0);
        if new {
            text.push_str(HEADER);
            text.push('\n');
        }
        for r in rows {
            let (kind, index) = match r.candidate {
                Candidate::Chosen => ("chosen", String::new()),
                Candidate::NextRandom => ("next-random", String::new()),
                Candidate::Trained(i) => ("trained", i.to_string()),
            };
            let design: Vec<String> = r.design.iter().map(|x| x.to_string()).collect();
            text.push_str(&format!("{},{kind},{index},{},{}\n", r.request, r.predicted, design.join(";")));
        }
        let mut f = std::fs::File::options().create(true).append(true).open(&self.path)?;
        f.write_all(text.as_bytes())
    }
}
