//! Scoring designs by simulation: the [`RolloutEvaluator`] the simulation baselines and the
//! critic-screened rollouts run their rollouts through, and why one failed ([`RolloutError`]).

/// Scores designs by simulation: one rollout of `policy` per design, started from reset seed
/// `seeds[k]` for design `k`, fitness the mean per-step reward (higher is better).
pub trait RolloutEvaluator {
    fn evaluate(&mut self, policy: &[f32], designs: &[f32], seeds: &[u64], fitness: &mut [f32]) -> Result<(), RolloutError>;

    /// The return of one rollout of `policy` per design from `seeds[k]`, over at most `steps`
    /// steps (the whole episode when 0), for the critic-screened rollouts. An evaluator that
    /// cannot cut an episode short says so.
    fn returns(
        &mut self,
        _policy: &[f32],
        _designs: &[f32],
        _seeds: &[u64],
        _steps: usize,
        _returns: &mut [f32],
    ) -> Result<(), RolloutError> {
        Err(RolloutError::NoShortRollouts)
    }
}

/// Why a [`RolloutEvaluator`] gave no scores.
#[derive(Debug, thiserror::Error)]
pub enum RolloutError {
    /// This evaluator cannot cut an episode short (`exploit = "screened"` needs it to).
    #[error("this rollout evaluator cannot run the short rollouts of exploit = \"screened\"")]
    NoShortRollouts,
    /// A thread running rollouts panicked.
    #[error("a rollout thread panicked")]
    Panicked,
    /// A rollout failed: the robot, the policy's weights (the evaluator's own error).
    #[error(transparent)]
    Failed(Box<dyn std::error::Error + Send + Sync>),
}
