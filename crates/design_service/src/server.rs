//! One tonic server for the DesignService and the Open Inference Protocol.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use coadapt_design_optimizer::objective::ObjectiveWorkspace;
use coadapt_grpc::{LimitedIncoming, PeerLimits};
use coadapt_wire::inference::grpc_inference_service_server::GrpcInferenceServiceServer;
use coadapt_wire::pb::design_service_server::DesignServiceServer;
use tokio::sync::{Semaphore, watch};
use tonic::Status;

use crate::design::Design;
use crate::inference::Inference;
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
    /// The twin critics' disagreement (`None`: not asked for, or one critic).
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

/// How long a stopping server waits for its clients to close their connections.
const STOP_GRACE: Duration = Duration::from_secs(1);

/// A running server; dropping it stops it (within [`STOP_GRACE`] and a little more, whatever
/// its clients do).
#[derive(Debug)]
pub struct DesignServer {
    local_addr: SocketAddr,
    shutdown: watch::Sender<bool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl DesignServer {
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }
}

impl Drop for DesignServer {
    fn drop(&mut self) {
        let _ = self.shutdown.send(true);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Binds `addr` (port 0 picks one) and serves the DesignService and the Open Inference
/// Protocol from `source`, with grpc.health.v1 (per service and overall) and reflection.
pub fn serve(addr: SocketAddr, cfg: ServeConfig, source: Arc<dyn ModelSource>) -> std::io::Result<DesignServer> {
    let listener = std::net::TcpListener::bind(addr)?;
    listener.set_nonblocking(true)?;
    let local_addr = listener.local_addr()?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .max_blocking_threads(cfg.max_concurrent.max(1))
        .thread_name("coadapt-design-service")
        .enable_all()
        .build()?;
    let listener = {
        let _in = rt.enter();
        tokio::net::TcpListener::from_std(listener)?
    };
    let limits = PeerLimits::new("design_service", cfg.max_connections_per_peer, cfg.max_connections);
    let incoming = LimitedIncoming::new(listener, limits, "coadapt design service");
    let (shutdown, mut stop) = watch::channel(false);
    let shared =
        Arc::new(Shared { source, permits: Arc::new(Semaphore::new(cfg.max_concurrent.max(1))), cfg: cfg.clone(), stop: stop.clone() });
    let max = cfg.max_message_bytes;
    use coadapt_auth::Role;
    use tonic::service::interceptor::InterceptedService;
    let queries = cfg.auth.gate(&[Role::Client, Role::Optimizer]).server("design_service");
    let any = cfg.auth.gate(&Role::ALL).counting(queries.counts().clone()).server("design_service");
    let design = InterceptedService::new(
        DesignServiceServer::new(Design { shared: shared.clone() }).max_decoding_message_size(max).max_encoding_message_size(max),
        queries.clone(),
    );
    let inference = InterceptedService::new(
        GrpcInferenceServiceServer::new(Inference { shared: shared.clone() }).max_decoding_message_size(max).max_encoding_message_size(max),
        queries,
    );
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(coadapt_wire::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(coadapt_wire::INFERENCE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let (v1, v1alpha) = (
        InterceptedService::new(reflection().build_v1().map_err(std::io::Error::other)?, any.clone()),
        InterceptedService::new(reflection().build_v1alpha().map_err(std::io::Error::other)?, any),
    );
    let (reporter, health) = tonic_health::server::health_reporter();
    let set_health = |reporter: tonic_health::server::HealthReporter, ready: bool| async move {
        for name in ["", "coadapt.v1.DesignService", "inference.GRPCInferenceService"] {
            let status = if ready { tonic_health::ServingStatus::Serving } else { tonic_health::ServingStatus::NotServing };
            reporter.set_service_status(name, status).await;
        }
    };
    let ready = shared.source.model().is_some();
    rt.block_on(set_health(reporter.clone(), ready));
    if !ready {
        // A running learner has no networks until its first design request: serving from then.
        let (source, reporter, mut stop) = (shared.source.clone(), reporter.clone(), stop.clone());
        rt.spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(200));
            loop {
                tokio::select! {
                    _ = tick.tick() => {}
                    _ = stop.wait_for(|s| *s) => return,
                }
                if source.model().is_some() {
                    set_health(reporter, true).await;
                    return;
                }
            }
        });
    }
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = &cfg.auth.tls {
        builder = builder.tls_config(tls.config()).map_err(std::io::Error::other)?;
    }
    let router = builder
        .timeout(cfg.rpc_timeout)
        .max_concurrent_streams(64)
        .http2_max_pending_accept_reset_streams(Some(32))
        .add_service(design)
        .add_service(inference)
        .add_service(health)
        .add_service(v1)
        .add_service(v1alpha);
    let thread = std::thread::Builder::new().name("coadapt-design-service".into()).spawn(move || {
        let _reporter = reporter;
        rt.block_on(async move {
            let mut stop_late = stop.clone();
            let graceful = async move {
                let _ = stop.wait_for(|s| *s).await;
            };
            // A graceful stop waits for every client to close its connection; one that never
            // does (idle, hostile, or frozen) must not hold the process: cut after a grace.
            let cut = async move {
                let _ = stop_late.wait_for(|s| *s).await;
                tokio::time::sleep(STOP_GRACE).await;
            };
            tokio::select! {
                r = router.serve_with_incoming_shutdown(incoming, graceful) => {
                    if let Err(e) = r {
                        coadapt_log::logln!("coadapt design service: stopped: {e}");
                    }
                }
                () = cut => {}
            }
        });
        rt.shutdown_timeout(Duration::from_millis(200));
    })?;
    Ok(DesignServer { local_addr, shutdown, thread: Some(thread) })
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
