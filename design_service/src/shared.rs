//! What every handler shares: the model source, the server's bounds ([`ServeConfig`]), the
//! bounded pool of computations with its busy share, and the checks of a design.

use std::sync::Arc;
use std::time::Duration;

use coadapt_design_optimizer::objective::ObjectiveWorkspace;
use tokio::sync::{Semaphore, watch};
use tonic::Status;

use crate::model::{DesignModel, ModelSource};

/// The server's bounds.
#[derive(Clone, Debug)]
pub struct ServeConfig {
    /// Most designs one Score or ModelInfer call may carry.
    pub max_score_batch: usize,
    /// Most designs one Optimize call may score (particles x iterations): the reference's PSO
    /// is 700 x 250.
    pub max_optimize_evaluations: u64,
    /// Most rows one History call returns.
    pub history_page: usize,
    /// Scoring calls computed at once (each on one blocking thread); more wait their turn, so
    /// queries take at most this many cores from the process.
    pub max_concurrent: usize,
    /// The server's deadline for any call.
    pub rpc_timeout: Duration,
    /// Largest message, either way.
    pub max_message_bytes: usize,
    /// TCP connections one remote address may hold open.
    pub max_connections_per_peer: usize,
    /// TCP connections open in all.
    pub max_connections: usize,
    /// TLS and accepted tokens (clients, optimisers and operators may query).
    pub auth: coadapt_auth::ServerAuth,
    /// The share of one core that queries may keep busy, in (0, 1]: after computing for `t`
    /// the pool rests `t (1/share - 1)` before the next computation (a reply is not delayed,
    /// the next query is). 1: no rest (a finished run's server); a learner serving during its
    /// run keeps most of its machine for training with a small share.
    pub max_busy_share: f64,
    /// HTTP routes served on the same listener beside gRPC (the operator page), with the same
    /// TLS, connection limits and deadline; they do their own authentication (the gRPC
    /// interceptors see only gRPC calls). `None`: gRPC only (HTTP/2 alone is accepted).
    pub pages: Option<axum::Router>,
}

impl Default for ServeConfig {
    fn default() -> Self {
        Self {
            max_score_batch: 10_000,
            max_optimize_evaluations: 700 * 250,
            history_page: 1000,
            max_concurrent: 1,
            rpc_timeout: Duration::from_secs(30),
            max_message_bytes: 16 << 20,
            max_connections_per_peer: 64,
            max_connections: 256,
            auth: coadapt_auth::ServerAuth::default(),
            max_busy_share: 1.0,
            pages: None,
        }
    }
}

/// What the handlers share.
#[derive(Debug)]
pub(crate) struct Shared {
    pub(crate) source: Arc<dyn ModelSource>,
    pub(crate) cfg: ServeConfig,
    pub(crate) permits: Arc<Semaphore>,
    /// Set when the server stops: open streams end.
    pub(crate) stop: watch::Receiver<bool>,
}

impl Shared {
    /// The current model, or UNAVAILABLE.
    pub(crate) fn model(&self) -> Result<Arc<DesignModel>, Status> {
        self.source.model().ok_or_else(|| Status::unavailable("no population networks yet: the run has not trained them"))
    }

    /// Resolves when the server stops.
    pub(crate) fn stopping(&self) -> impl std::future::Future<Output = ()> + Send + 'static {
        let mut stop = self.stop.clone();
        async move {
            let _ = stop.wait_for(|s| *s).await;
        }
    }

    /// A place in the bounded pool of computations.
    pub(crate) async fn permit(&self) -> Result<tokio::sync::OwnedSemaphorePermit, Status> {
        self.permits.clone().acquire_owned().await.map_err(|_| Status::unavailable("the server is stopping"))
    }

    /// The rest owed after computing for `busy` ([`ServeConfig::max_busy_share`]).
    pub(crate) fn rest_after(&self, busy: Duration) -> Duration {
        rest_after(self.cfg.max_busy_share, busy)
    }

    /// Eq. 5.6 and its spread for `designs` (checked), on the bounded pool; the pool's place
    /// is kept through the rest the busy share asks for, after the answer is on its way.
    pub(crate) async fn score(&self, m: Arc<DesignModel>, designs: Vec<f32>) -> Result<(Vec<f32>, Vec<f32>), Status> {
        self.score_with(m, designs, false).await.map(|s| (s.mean, s.spread))
    }

    /// [`Self::score`], and the twin critics' disagreement when `disagreement` is asked for
    /// and the model has both critics.
    pub(crate) async fn score_with(&self, m: Arc<DesignModel>, designs: Vec<f32>, disagreement: bool) -> Result<Scores, Status> {
        let permit = self.permit().await?;
        let (scores, busy) = tokio::task::spawn_blocking(move || {
            let t = std::time::Instant::now();
            let n = designs.len() / m.design_dim().max(1);
            let (mut mean, mut spread) = (vec![0.0; n], vec![0.0; n]);
            let mut ws = ObjectiveWorkspace::default();
            m.score(&designs, &mut mean, &mut spread, &mut ws);
            let mut gap = vec![0.0; n];
            let disagreement = (disagreement && m.disagreement(&designs, &mut gap, &mut ws)).then_some(gap);
            (Scores { mean, spread, disagreement }, t.elapsed())
        })
        .await
        .map_err(|e| Status::internal(format!("scoring failed: {e}")))?;
        let rest = self.rest_after(busy);
        if rest.is_zero() {
            drop(permit);
        } else {
            tokio::spawn(async move {
                tokio::time::sleep(rest).await;
                drop(permit);
            });
        }
        Ok(scores)
    }
}

/// What [`Shared::score_with`] gives per design.
#[derive(Debug)]
pub(crate) struct Scores {
    pub mean: Vec<f32>,
    pub spread: Vec<f32>,
    /// The critics' disagreement (`None`: not asked for, or one critic).
    pub disagreement: Option<Vec<f32>>,
}

/// `busy (1/share - 1)`, none for a share of 1 or more (or not a number).
pub(crate) fn rest_after(share: f64, busy: Duration) -> Duration {
    if share.is_finite() && share > 0.0 && share < 1.0 { busy.mul_f64(1.0 / share - 1.0) } else { Duration::ZERO }
}

/// `values` as a design of `m`, or INVALID_ARGUMENT naming `field`: its length, a value that
/// is not finite or outside the design box (the critic knows nothing there).
pub(crate) fn check_design(values: &[f32], m: &DesignModel, field: &str) -> Result<(), Status> {
    let dim = m.design_dim();
    if values.len() != dim {
        return Err(Status::invalid_argument(format!(
            "{field}: {} values; the design has {dim} dimensions ({})",
            values.len(),
            m.names.join(", ")
        )));
    }
    for (j, &v) in values.iter().enumerate() {
        let (lo, hi) = (m.bounds.low[j], m.bounds.high[j]);
        if !(v.is_finite() && v >= lo && v <= hi) {
            return Err(Status::invalid_argument(format!("{field}[{j}] ({}): {v} is outside the design box [{lo}, {hi}]", m.names[j])));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rest_keeps_the_busy_share() {
        let busy = Duration::from_millis(10);
        assert_eq!(rest_after(0.2, busy), Duration::from_millis(40));
        assert_eq!(rest_after(0.5, busy), busy);
        assert_eq!(rest_after(1.0, busy), Duration::ZERO);
        assert_eq!(rest_after(f64::NAN, busy), Duration::ZERO);
        // Busy 10 of every 10 + 40 ms: a share of 0.2.
        let share = busy.as_secs_f64() / (busy + rest_after(0.2, busy)).as_secs_f64();
        assert!((share - 0.2).abs() < 1e-9);
    }
}
