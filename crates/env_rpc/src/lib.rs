//! Environments over DeepMind's dm_env_rpc v1: any robot or simulator that speaks the protocol
//! is a coadapt environment, and coadapt's robots are served to any dm_env_rpc client.
//!
//! # Layout
//! - [`profile`]: the coadapt profile (proto/README.md): which tensors carry the action, the
//!   state, the reward, the discount and the design; building and reading specs.
//! - [`client`]: [`RemoteEnv`], an [`coadapt_core::Env`] over one connection and one world,
//!   with deadlines, reconnection and validation of everything the server sends.
//! - [`server`]: the `Environment` service over any coadapt `Env` factory (`coadapt
//!   env-serve`), and a background server for tests and benchmarks.
//!
//! Environment names of the form `dm-env-rpc://HOST:PORT` ([`is_remote`]; [`endpoint`], or an
//! [`AddressError`] naming what is wrong with one) select a [`RemoteEnv`] wherever coadapt takes
//! an environment name.

pub mod client;
pub mod profile;
pub mod server;

use std::future::Future;
use std::sync::OnceLock;
use std::time::Duration;

pub use client::{RemoteEnv, RemoteError, RemoteStats};
pub use server::{BackgroundServer, EnvFactory, EnvService, ServerHandle, ServerLimits, ServerRefusals, WorldSettings, plain};

/// The scheme of remote environment names.
pub const SCHEME: &str = "dm-env-rpc://";

/// Whether an environment name is a dm_env_rpc address.
pub fn is_remote(name: &str) -> bool {
    name.starts_with(SCHEME)
}

/// Why an environment name is not a `dm-env-rpc://HOST:PORT` address.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AddressError {
    #[error("`{url}` is not a {}HOST:PORT address", SCHEME)]
    NotRemote { url: String },
    #[error("`{url}`: no port (expected {}HOST:PORT)", SCHEME)]
    NoPort { url: String },
    /// No host, or a path after the port.
    #[error("`{url}`: expected {}HOST:PORT", SCHEME)]
    Malformed { url: String },
    #[error("`{url}`: port `{port}` is not a number in 1-65535")]
    BadPort { url: String, port: String },
}

/// `dm-env-rpc://HOST:PORT` to the HTTP/2 endpoint `http://HOST:PORT`.
pub fn endpoint(url: &str) -> Result<String, AddressError> {
    let rest = url.strip_prefix(SCHEME).ok_or_else(|| AddressError::NotRemote { url: url.to_string() })?;
    let (host, port) = rest.rsplit_once(':').ok_or_else(|| AddressError::NoPort { url: url.to_string() })?;
    if host.is_empty() || rest.contains('/') {
        return Err(AddressError::Malformed { url: url.to_string() });
    }
    port.parse::<u16>().map_err(|_| AddressError::BadPort { url: url.to_string(), port: port.to_string() })?;
    Ok(format!("http://{rest}"))
}

/// Deadlines and reconnection of a [`RemoteEnv`].
#[derive(Clone, Debug)]
pub struct RemoteOptions {
    /// Connecting and opening the stream.
    pub connect_timeout: Duration,
    /// Every request (a step of a real robot may take a while).
    pub request_timeout: Duration,
    /// HTTP/2 keep-alive ping interval (pings unanswered for `request_timeout` drop the
    /// connection).
    pub keep_alive: Duration,
    /// How long `reset` keeps trying to reconnect before it gives up.
    pub reconnect_for: Duration,
    /// The longest wait between reconnection attempts (waits double from 100 ms).
    pub max_backoff: Duration,
    /// TLS (the CA that signed the server; a certificate for mutual TLS) and the actor's token.
    pub auth: coadapt_auth::ClientAuth,
    /// Settings of the world beyond the design and seed (a scalar each, e.g. `friction`), sent
    /// with CreateWorld on every (re)connection; a server that does not know one refuses it.
    pub world_settings: Vec<(String, f32)>,
}

impl Default for RemoteOptions {
    fn default() -> Self {
        Self {
            connect_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(10),
            keep_alive: Duration::from_secs(10),
            reconnect_for: Duration::from_secs(60),
            max_backoff: Duration::from_secs(5),
            auth: coadapt_auth::ClientAuth::default(),
            world_settings: Vec::new(),
        }
    }
}

static RUNTIME: OnceLock<tokio::runtime::Runtime> = OnceLock::new();

/// Runs `fut` on this crate's client runtime and waits for it on the calling thread, which
/// may be any thread (even one inside another runtime).
pub(crate) fn block<F>(fut: F) -> Result<F::Output, String>
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    let rt = match RUNTIME.get() {
        Some(rt) => rt,
        None => {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .thread_name("coadapt-env-rpc")
                .enable_all()
                .build()
                .map_err(|e| format!("starting the dm_env_rpc client runtime: {e}"))?;
            RUNTIME.get_or_init(|| rt)
        }
    };
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    rt.spawn(async move {
        let _ = tx.send(fut.await);
    });
    rx.recv().map_err(|_| "the dm_env_rpc client runtime dropped a call".to_string())
}
