//! The clients' side. One tokio runtime per process drives every connection; the sync channel
//! ends hand futures to it and wait on a plain channel, so they can be called from any thread
//! (even one inside another runtime) without `block_on` panics or deadlocks.

mod poll;
mod upstream;
mod weights;

use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, Weak};
use std::time::{Duration, Instant};

use coadapt_transport::{ActorLinks, OptimizerLinks, TransportError};
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;
use tokio::runtime::Runtime;

use crate::{Backoff, CONNECTION_WINDOW, GrpcConfig, PROTOCOL, STREAM_WINDOW, is_permanent, is_unregistered, random_u64, status_error};

static RUNTIME: OnceLock<Runtime> = OnceLock::new();

fn runtime() -> Result<&'static Runtime, TransportError> {
    if let Some(rt) = RUNTIME.get() {
        return Ok(rt);
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("coadapt-grpc-client")
        .enable_all()
        .build()
        .map_err(|e| TransportError::Io(format!("starting the gRPC client runtime: {e}")))?;
    Ok(RUNTIME.get_or_init(|| rt))
}

/// Runs `fut` on the client runtime and waits for it on this thread.
pub(crate) fn block<F>(fut: F) -> Result<F::Output, TransportError>
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    runtime()?.spawn(async move {
        let _ = tx.send(fut.await);
    });
    rx.recv().map_err(|_| TransportError::Io("the gRPC client runtime dropped a call".into()))
}

/// One client's connection and identity, shared by its channel ends.
#[derive(Debug)]
pub(crate) struct Conn {
    pub(crate) client: FleetClient<coadapt_auth::AuthChannel>,
    pub(crate) cfg: GrpcConfig,
    pub(crate) session: u64,
    role: pb::Role,
    actor_id: u64,
    /// The learner said this role's work is finished.
    pub(crate) finished: AtomicBool,
    /// The newest weights version handed to the role (reported in heartbeats).
    pub(crate) weights_version: AtomicU64,
    /// The run id of the learner start we last registered with (0: none yet). What the channel
    /// ends keep is stamped with it.
    run_id: AtomicU64,
    /// The channel ends' state that belongs to one learner start, dropped when the learner
    /// restarts. Its lock also orders the adoption of a new run id.
    ends: Mutex<Vec<Weak<dyn StartBound>>>,
}

/// What a channel end keeps of one learner start (unacknowledged frames, cached weights).
pub(crate) trait StartBound: Send + Sync {
    /// From now on the end belongs to learner start `run_id`: if it belonged to another, it
    /// drops what it kept of that one. Returns what was dropped.
    fn restart(&self, run_id: u64) -> Dropped;
}

/// What a channel end dropped when the learner restarted.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Dropped {
    pub(crate) frames: usize,
    pub(crate) weights_version: Option<u64>,
}

impl Conn {
    /// The run id of the learner start we last registered with.
    pub(crate) fn run_id(&self) -> u64 {
        self.run_id.load(Ordering::Acquire)
    }

    /// Binds a channel end's state to the current learner start and to every later one.
    pub(crate) fn attach(&self, end: Weak<dyn StartBound>) {
        let Ok(mut ends) = self.ends.lock() else { return };
        ends.retain(|e| e.strong_count() > 0);
        if let Some(e) = end.upgrade() {
            e.restart(self.run_id());
        }
        ends.push(end);
    }

    /// A registration was answered by learner start `run_id`. If we were registered with
    /// another start, every channel end drops what it kept of it (the resumed learner issues
    /// that work again itself, and numbers its weights and deliveries afresh).
    fn adopt(&self, run_id: u64) {
        if run_id == 0 {
            return;
        }
        let Ok(ends) = self.ends.lock() else { return };
        let old = self.run_id();
        if old == run_id {
            return;
        }
        let mut dropped = Dropped::default();
        for end in ends.iter().filter_map(Weak::upgrade) {
            let d = end.restart(run_id);
            dropped.frames += d.frames;
            dropped.weights_version = dropped.weights_version.max(d.weights_version);
        }
        self.weights_version.store(0, Ordering::Relaxed);
        // Only now: whoever sees the new run id finds every end moved to it.
        self.run_id.store(run_id, Ordering::Release);
        if old != 0 {
            let who = match self.role {
                pb::Role::Actor => format!("actor {}", self.actor_id),
                _ => "optimizer".to_string(),
            };
            coadapt_log::logln!(
                "coadapt-grpc: {who}: learner restarted (run id {old:016x} -> {run_id:016x}): dropping {} unacknowledged frames and weights version {}",
                dropped.frames,
                dropped.weights_version.unwrap_or(0)
            );
        }
    }

    pub(crate) fn is_finished(&self) -> bool {
        self.finished.load(Ordering::Relaxed)
    }

    fn beat(&self, leaving: bool) -> pb::Beat {
        pb::Beat {
            session: self.session,
            role: self.role as i32,
            actor_id: self.actor_id,
            weights_version: self.weights_version.load(Ordering::Relaxed),
            leaving,
            run_id: self.run_id(),
        }
    }
}

/// Held by every channel end of one client: when the last goes, heartbeats stop and the
/// learner hears that the client left.
#[derive(Debug)]
pub(crate) struct Session {
    pub(crate) conn: Arc<Conn>,
    heartbeat: tokio::task::AbortHandle,
}

impl Drop for Session {
    fn drop(&mut self) {
        self.heartbeat.abort();
        let conn = self.conn.clone();
        let deadline = conn.cfg.rpc_timeout.min(Duration::from_secs(1));
        let _ = block(async move {
            let mut req = tonic::Request::new(conn.beat(true));
            req.set_timeout(deadline);
            let mut client = conn.client.clone();
            let _ = tokio::time::timeout(deadline, client.heartbeat(req)).await;
        });
    }
}

fn connect(endpoint: &str, cfg: &GrpcConfig, role: pb::Role, actor_id: u64) -> Result<Arc<Session>, TransportError> {
    let rt = runtime()?;
    let ep = cfg
        .client_auth
        .endpoint(endpoint)
        .map_err(|e| TransportError::Invalid(format!("endpoint {endpoint:?}: {e}")))?
        .connect_timeout(cfg.connect_timeout)
        .tcp_nodelay(true)
        .http2_keep_alive_interval(cfg.heartbeat)
        .keep_alive_timeout(cfg.rpc_timeout)
        .keep_alive_while_idle(true)
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW);
    let channel = {
        let _in_rt = rt.enter();
        ep.connect_lazy()
    };
    let client = FleetClient::with_interceptor(channel, cfg.client_auth.bearer())
        .max_decoding_message_size(cfg.max_message_bytes)
        .max_encoding_message_size(cfg.max_message_bytes);
    let conn = Arc::new(Conn {
        client,
        cfg: cfg.clone(),
        session: random_u64(),
        role,
        actor_id,
        finished: AtomicBool::new(false),
        weights_version: AtomicU64::new(0),
        run_id: AtomicU64::new(0),
        ends: Mutex::new(Vec::new()),
    });
    block(register(conn.clone()))??;
    let heartbeat = rt.spawn(heartbeats(conn.clone())).abort_handle();
    Ok(Arc::new(Session { conn, heartbeat }))
}

/// Registers, retrying with backoff for up to the connect timeout (the learner may still be
/// starting); refuses a learner of another fleet or protocol at once.
async fn register(conn: Arc<Conn>) -> Result<(), TransportError> {
    let cfg = &conn.cfg;
    let give_up = Instant::now() + cfg.connect_timeout.max(cfg.rpc_timeout.min(Duration::from_secs(1)));
    let mut backoff = Backoff::new(cfg.reconnect_backoff_max);
    loop {
        let status = match conn.register_once().await {
            Ok(()) => return Ok(()),
            Err(s) if is_permanent(&s) => return Err(status_error(&s)),
            Err(s) => s,
        };
        let delay = backoff.next_delay();
        if Instant::now() + delay >= give_up {
            return Err(TransportError::Io(format!("the learner is unreachable: {:?}: {}", status.code(), status.message())));
        }
        tokio::time::sleep(delay).await;
    }
}

impl Conn {
    /// One registration of our session (again, after the learner said it does not know it, or
    /// that we stamped a call with another start's run id): learns the learner start's run id.
    pub(crate) async fn register_once(&self) -> Result<(), tonic::Status> {
        let cfg = &self.cfg;
        let hello = pb::Hello {
            fleet: cfg.fleet.clone(),
            protocol: PROTOCOL,
            role: self.role as i32,
            actor_id: self.actor_id,
            session: self.session,
        };
        let mut req = tonic::Request::new(hello);
        req.set_timeout(cfg.rpc_timeout);
        let mut client = self.client.clone();
        match tokio::time::timeout(cfg.rpc_timeout, client.register(req)).await {
            Ok(Ok(w)) => {
                let w = w.into_inner();
                if w.fleet != cfg.fleet || w.protocol != PROTOCOL {
                    return Err(tonic::Status::failed_precondition(format!(
                        "the learner serves fleet {:?} protocol {}, not {:?} protocol {PROTOCOL}",
                        w.fleet, w.protocol, cfg.fleet
                    )));
                }
                self.adopt(w.run_id);
                Ok(())
            }
            Ok(Err(s)) => Err(s),
            Err(_) => Err(tonic::Status::deadline_exceeded("register")),
        }
    }

    /// One heartbeat: returns the reply, and records a finished fleet. A learner that does
    /// not know our session (it restarted, or forgot us) hears a registration instead.
    pub(crate) async fn beat_once(&self, deadline: Duration) -> Option<pb::BeatReply> {
        let mut req = tonic::Request::new(self.beat(false));
        req.set_timeout(deadline);
        let mut client = self.client.clone();
        let reply = match tokio::time::timeout(deadline, client.heartbeat(req)).await.ok()? {
            Ok(r) => r.into_inner(),
            Err(s) if is_unregistered(&s) => {
                let _ = self.register_once().await;
                return None;
            }
            Err(_) => return None,
        };
        if reply.run_id != self.run_id() {
            // Another learner start answers (one that knows our session from another channel
            // end's registration): learn its run id before believing its versions.
            let _ = self.register_once().await;
            return None;
        }
        if reply.fleet_finished {
            self.finished.store(true, Ordering::Relaxed);
        }
        Some(reply)
    }
}

async fn heartbeats(conn: Arc<Conn>) {
    let mut tick = tokio::time::interval(conn.cfg.heartbeat);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        conn.beat_once(conn.cfg.rpc_timeout).await;
    }
}

/// An actor's channel ends, connected to the learner at `endpoint` ("http://host:port").
/// Fails if the learner cannot be reached within the connect timeout or serves another fleet.
pub fn actor_links(endpoint: &str, actor_id: u64, cfg: &GrpcConfig) -> Result<ActorLinks, TransportError> {
    let session = connect(endpoint, cfg, pb::Role::Actor, actor_id)?;
    Ok(ActorLinks {
        assignments: Box::new(poll::PollReceiver::<coadapt_transport::Assignment>::new(session.clone())),
        weights: Box::new(weights::WeightsSubscriber::start(session.clone(), pb::WeightsTopic::Acting)?),
        experience: Box::new(upstream::UpstreamSender::<pb::ExperienceFrame>::start(session)?),
    })
}

/// The design optimiser's channel ends, connected to the learner at `endpoint`.
pub fn optimizer_links(endpoint: &str, cfg: &GrpcConfig) -> Result<OptimizerLinks, TransportError> {
    let session = connect(endpoint, cfg, pb::Role::Optimizer, 0)?;
    Ok(OptimizerLinks {
        requests: Box::new(poll::PollReceiver::<coadapt_transport::DesignRequest>::new(session.clone())),
        replies: Box::new(upstream::UpstreamSender::<pb::DesignReplyFrame>::start(session.clone())?),
        weights: Box::new(weights::WeightsSubscriber::start(session, pb::WeightsTopic::Population)?),
    })
}
