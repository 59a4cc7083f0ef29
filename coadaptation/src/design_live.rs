//! The learner's design service during a run: `coadapt.v1.DesignService` and the Open
//! Inference Protocol model `design-critic`, served by the process that holds the population
//! networks (`[design-service] listen`, `coadapt run --serve ADDR`).
//!
//! The model is the one the optimiser gets: at each design request the learner publishes the
//! population networks and sends the request's start states; the tees here keep a copy of the
//! first and build the model when the second goes out, so a Score is the value the optimiser
//! maximised when it chose the latest design. The run's designs come from the run directory's
//! writer as it writes them. Queries are computed on the server's own bounded pool
//! (`max-concurrent` threads), never on the learner's thread.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::error::Context;
use coadapt_core::EnvSpec;
use coadapt_design_service::{DesignServer, LiveSource, ServeConfig};
use coadapt_learner::run_dir::{DesignsObserver, RunWriter};
use coadapt_transport::{DesignRequest, LearnerLinks, Publisher, Sender, TransportError, Weights};
use serde::{Deserialize, Serialize};

use crate::config::RunConfig;

/// `[design-service]`: the learner's design queries during a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct DesignServiceConfig {
    /// Address the learner serves DesignService and `design-critic` on (e.g.
    /// `127.0.0.1:50061`; port 0 picks one, printed on stderr; empty: not served).
    pub listen: String,
    /// Most designs one Score or ModelInfer call (and one Landscape grid) may carry.
    pub max_score_batch: usize,
    /// Most designs one Optimize call may score (particles x iterations).
    pub max_optimize_evaluations: u64,
    /// Queries computed at once, each on one thread of the server's own pool: what queries can
    /// take from the learner's machine at most.
    pub max_concurrent: usize,
    /// Most rows one History call returns.
    pub history_page: usize,
    /// The server's deadline for a call (an Optimize's or a Watch's stream may run longer).
    pub rpc_timeout_secs: f64,
    /// The share of one core queries may keep busy, in (0, 1]: after computing for t the
    /// server rests t (1/share - 1) before the next query, so training keeps its machine
    /// (BENCHMARKS.md: the learner's updates/s with a client scoring in a loop).
    pub max_busy_share: f64,
}

impl Default for DesignServiceConfig {
    fn default() -> Self {
        let d = ServeConfig::default();
        Self {
            listen: String::new(),
            max_score_batch: d.max_score_batch,
            max_optimize_evaluations: d.max_optimize_evaluations,
            max_concurrent: d.max_concurrent,
            history_page: d.history_page,
            rpc_timeout_secs: d.rpc_timeout.as_secs_f64(),
            max_busy_share: 0.2,
        }
    }
}

impl DesignServiceConfig {
    /// The server's bounds, each checked (the error names the key).
    pub fn serve_config(&self) -> crate::Result<ServeConfig> {
        let positive = |key: &str, v: usize| {
            if v == 0 { crate::error::bail!("design-service.{key}: 0 would refuse every request; at least 1") } else { Ok(v) }
        };
        let rpc_timeout = Duration::try_from_secs_f64(self.rpc_timeout_secs)
            .ok()
            .filter(|d| !d.is_zero())
            .with_context(|| format!("design-service.rpc-timeout-secs: {} is not a positive number of seconds", self.rpc_timeout_secs))?;
        if !(self.max_busy_share > 0.0 && self.max_busy_share <= 1.0) {
            crate::error::bail!("design-service.max-busy-share: {} is not in (0, 1]", self.max_busy_share);
        }
        if self.max_optimize_evaluations == 0 {
            crate::error::bail!("design-service.max-optimize-evaluations: 0 would refuse every Optimize; at least 1");
        }
        Ok(ServeConfig {
            max_score_batch: positive("max-score-batch", self.max_score_batch)?,
            max_optimize_evaluations: self.max_optimize_evaluations,
            max_concurrent: positive("max-concurrent", self.max_concurrent)?,
            history_page: positive("history-page", self.history_page)?,
            rpc_timeout,
            max_busy_share: self.max_busy_share,
            ..ServeConfig::default()
        })
    }
}

/// What builds the live model from the published networks.
struct Builder {
    cfg: RunConfig,
    spec: EnvSpec,
    run_id: String,
    source: Arc<LiveSource>,
    /// The newest population networks published.
    weights: Mutex<Option<Weights>>,
}

impl Builder {
    fn request(&self, r: &DesignRequest) {
        let w = self.weights.lock().unwrap_or_else(|e| e.into_inner());
        let Some(w) = w.as_ref().filter(|w| w.version == r.weights_version) else { return };
        let critics: Vec<&[f32]> = [&w.q1, &w.q2].into_iter().chain(&w.heads).map(Vec::as_slice).collect();
        match crate::serve::design_model(&self.cfg, &self.spec, w.version, self.run_id.clone(), (&w.policy, &critics), &r.start_states) {
            Ok(m) => self.source.set_model(m),
            // The optimiser gets the same networks and states: it will say what is wrong.
            Err(e) => coadapt_log::logln!("learner: design service: no model for weights version {}: {e:#}", w.version),
        }
    }
}

struct PopulationTee {
    inner: Box<dyn Publisher<Weights>>,
    builder: Arc<Builder>,
}

impl Publisher<Weights> for PopulationTee {
    fn publish(&mut self, w: Weights) -> Result<(), TransportError> {
        *self.builder.weights.lock().unwrap_or_else(|e| e.into_inner()) = Some(w.clone());
        self.inner.publish(w)
    }
}

struct RequestTee {
    inner: Box<dyn Sender<DesignRequest>>,
    builder: Arc<Builder>,
}

impl Sender<DesignRequest> for RequestTee {
    fn send(&mut self, r: DesignRequest) -> Result<(), TransportError> {
        self.builder.request(&r);
        self.inner.send(r)
    }
}

/// Stands in for a link while it is moved into its tee.
struct Nowhere;

impl Publisher<Weights> for Nowhere {
    fn publish(&mut self, _: Weights) -> Result<(), TransportError> {
        Err(TransportError::Closed)
    }
}

impl Sender<DesignRequest> for Nowhere {
    fn send(&mut self, _: DesignRequest) -> Result<(), TransportError> {
        Err(TransportError::Closed)
    }
}

/// The running service; dropping it ends Watch streams and stops the server.
#[derive(Debug)]
pub struct LiveService {
    source: Arc<LiveSource>,
    /// What the operator page knows of the learner's progress.
    page: Arc<crate::page::Live>,
    server: DesignServer,
}

impl LiveService {
    pub fn local_addr(&self) -> SocketAddr {
        self.server.local_addr()
    }

    /// A design begins training (its row has no episodes yet): watchers see it chosen.
    pub fn design_started(&self, row: &coadapt_learner::run_dir::DesignRow) {
        self.source.upsert(crate::serve::history_row(row.clone()));
    }

    /// Every event of the learner, for the operator page's status.
    pub fn observe(&self, e: &coadapt_learner::coadapt::RunEvent<'_>) {
        self.page.observe(e);
    }
}

impl Drop for LiveService {
    fn drop(&mut self) {
        self.page.finish();
        self.source.end();
    }
}

/// Starts the service if `cfg.design-service.listen` names an address: wraps the learner's
/// population and design-request links and observes `writer`'s design rows. `None` when off.
pub fn start(
    cfg: &RunConfig,
    spec: &EnvSpec,
    run_id: &str,
    links: &mut LearnerLinks,
    writer: &mut RunWriter,
) -> crate::Result<Option<LiveService>> {
    let listen = cfg.design_service.listen.trim();
    if listen.is_empty() {
        return Ok(None);
    }
    let addr: SocketAddr = listen
        .parse()
        .map_err(|_| crate::AppError::Config(format!("design-service.listen: {listen:?} is not an address like 127.0.0.1:50061")))?;
    coadapt_fleet::check_listen("design-service.listen", addr, &cfg.security)?;
    let mut serve_cfg = cfg.design_service.serve_config()?;
    serve_cfg.auth = cfg.security.server_auth()?;
    let history = writer.read_designs().context("reading designs.csv for the design service")?;
    let source = Arc::new(LiveSource::new(history.into_iter().map(crate::serve::history_row).collect()));
    let builder = Arc::new(Builder {
        cfg: cfg.clone(),
        spec: spec.clone(),
        run_id: run_id.to_string(),
        source: source.clone(),
        weights: Mutex::new(None),
    });
    let inner = std::mem::replace(&mut links.population_weights, Box::new(Nowhere));
    links.population_weights = Box::new(PopulationTee { inner, builder: builder.clone() });
    let inner = std::mem::replace(&mut links.design_requests, Box::new(Nowhere));
    links.design_requests = Box::new(RequestTee { inner, builder });
    let rows = source.clone();
    writer.observe_designs(DesignsObserver(Box::new(move |r| rows.upsert(crate::serve::history_row(r.clone())))));
    let live = Arc::new(crate::page::Live::default());
    let page = crate::page::Page::new(crate::page::PageSetup {
        dir: std::fs::canonicalize(writer.dir()).unwrap_or_else(|_| writer.dir().to_path_buf()),
        cfg: cfg.clone(),
        spec: spec.clone(),
        tokens: serve_cfg.auth.tokens.clone(),
        tls: serve_cfg.auth.tls.is_some(),
        live: Some(live.clone()),
        model: Some(source.clone()),
    });
    serve_cfg.pages = Some(page.router());
    let tls = serve_cfg.auth.tls.is_some();
    let server = coadapt_design_service::serve(addr, serve_cfg, source.clone())
        .with_context(|| format!("design-service.listen: serving on {addr}"))?;
    coadapt_log::logln!(
        "learner: design service (coadapt.v1.DesignService, design-critic) on grpc://{0} from the first design request on; operator page on {1}://{0}/",
        server.local_addr(),
        if tls { "https" } else { "http" }
    );
    Ok(Some(LiveService { source, page: live, server }))
}
