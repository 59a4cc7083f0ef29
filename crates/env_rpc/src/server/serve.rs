//! Serving [`EnvService`] on a listener: TLS, tokens and connection limits.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use coadapt_wire::dm_env_rpc::v1::environment_server::EnvironmentServer;

use super::{EnvFactory, EnvService, ServerLimits, ServerRefusals};

/// A running server's view of what it refused.
#[derive(Clone, Debug)]
pub struct ServerHandle {
    service: EnvService,
    peers: Arc<coadapt_auth::PeerLimits>,
}

impl ServerHandle {
    pub fn refusals(&self) -> ServerRefusals {
        ServerRefusals {
            worlds: self.service.refused_worlds(),
            connections_per_peer: self.peers.refused_per_peer.load(Ordering::Relaxed),
            connections_total: self.peers.refused_total.load(Ordering::Relaxed),
        }
    }

    /// Worlds alive.
    pub fn world_count(&self) -> usize {
        self.service.world_count()
    }
}

/// Serves `factory` over dm_env_rpc on `listener` until `shutdown` resolves, with `auth`'s
/// TLS and tokens (actors and operators may step environments) and within `limits`. The
/// handle reads the refusals while the server runs.
pub fn serve<S: std::future::Future<Output = ()> + Send>(
    listener: tokio::net::TcpListener,
    factory: EnvFactory,
    auth: &coadapt_auth::ServerAuth,
    limits: ServerLimits,
    shutdown: S,
) -> (ServerHandle, impl std::future::Future<Output = Result<(), tonic::transport::Error>> + Send + use<S>) {
    let service = EnvService::with_max_worlds(factory, limits.max_worlds);
    let peers = coadapt_auth::PeerLimits::new("env_rpc", limits.max_connections_per_peer, limits.max_connections);
    let handle = ServerHandle { service: service.clone(), peers: peers.clone() };
    let auth = auth.clone();
    (handle, async move { serve_service(listener, service, &auth, peers, shutdown).await })
}

async fn serve_service(
    listener: tokio::net::TcpListener,
    service: EnvService,
    auth: &coadapt_auth::ServerAuth,
    peers: Arc<coadapt_auth::PeerLimits>,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<(), tonic::transport::Error> {
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = &auth.tls {
        builder = builder.tls_config(tls.config())?;
    }
    let gate = auth.gate(&[coadapt_auth::Role::Actor]).server("env_rpc");
    builder
        .http2_keepalive_interval(Some(Duration::from_secs(10)))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)))
        .add_service(tonic::service::interceptor::InterceptedService::new(EnvironmentServer::new(service), gate))
        .serve_with_incoming_shutdown(coadapt_auth::LimitedIncoming::new(listener, peers, "env-serve"), shutdown)
        .await
}

/// A server running on its own runtime (tests, benchmarks): dropping it stops it at once,
/// cutting open streams as a killed process would.
#[derive(Debug)]
pub struct BackgroundServer {
    pub addr: SocketAddr,
    handle: ServerHandle,
    rt: Option<tokio::runtime::Runtime>,
}

impl BackgroundServer {
    /// Binds `addr` (port 0 picks one) and serves `factory`.
    pub fn start(addr: &str, factory: EnvFactory) -> std::io::Result<Self> {
        Self::start_with(addr, factory, coadapt_auth::ServerAuth::default())
    }

    /// [`BackgroundServer::start`] with TLS and tokens (actors and operators may step).
    pub fn start_with(addr: &str, factory: EnvFactory, auth: coadapt_auth::ServerAuth) -> std::io::Result<Self> {
        Self::start_limited(addr, factory, auth, ServerLimits::default())
    }

    /// [`BackgroundServer::start_with`] within `limits`.
    pub fn start_limited(addr: &str, factory: EnvFactory, auth: coadapt_auth::ServerAuth, limits: ServerLimits) -> std::io::Result<Self> {
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).thread_name("env-serve").enable_all().build()?;
        let listener = rt.block_on(tokio::net::TcpListener::bind(addr))?;
        let addr = listener.local_addr()?;
        let (handle, served) = {
            let _in_rt = rt.enter();
            serve(listener, factory, &auth, limits, std::future::pending())
        };
        rt.spawn(async move {
            if let Err(e) = served.await {
                coadapt_log::logln!("env-serve: {e}");
            }
        });
        Ok(Self { addr, handle, rt: Some(rt) })
    }

    /// What the server refused so far.
    pub fn refusals(&self) -> ServerRefusals {
        self.handle.refusals()
    }

    /// Worlds alive on the server.
    pub fn world_count(&self) -> usize {
        self.handle.world_count()
    }

    /// The URL a coadapt client takes: `dm-env-rpc://HOST:PORT`.
    pub fn url(&self) -> String {
        format!("dm-env-rpc://{}", self.addr)
    }
}

impl Drop for BackgroundServer {
    fn drop(&mut self) {
        if let Some(rt) = self.rt.take() {
            rt.shutdown_timeout(Duration::from_millis(100));
        }
    }
}
