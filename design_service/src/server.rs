//! One tonic server for the DesignService and the Open Inference Protocol.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use coadapt_grpc::{LimitedIncoming, PeerLimits};
use coadapt_wire::inference::grpc_inference_service_server::GrpcInferenceServiceServer;
use coadapt_wire::pb::design_service_server::DesignServiceServer;
use tokio::sync::{Semaphore, watch};

use crate::design::Design;
use crate::inference::Inference;
use crate::model::ModelSource;
pub use crate::shared::ServeConfig;
use crate::shared::Shared;

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
/// Protocol from `source`, with grpc.health.v1 (per service and overall) and reflection, and
/// [`ServeConfig::pages`] beside them when set.
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
    let mut routes = tonic::service::Routes::builder();
    routes.add_service(design).add_service(inference).add_service(health).add_service(v1).add_service(v1alpha);
    let mut routes = routes.routes();
    if let Some(pages) = cfg.pages.clone() {
        // A browser speaks HTTP/1.1 in plaintext (over TLS it takes h2, the only protocol the
        // server's ALPN offers); gRPC clients keep HTTP/2 either way.
        builder = builder.accept_http1(true);
        routes = tonic::service::Routes::from(routes.into_axum_router().merge(pages));
    }
    let router =
        builder.timeout(cfg.rpc_timeout).max_concurrent_streams(64).http2_max_pending_accept_reset_streams(Some(32)).add_routes(routes);
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
