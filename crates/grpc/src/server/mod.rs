//! The learner's side: binds the port, serves Fleet, health and reflection on a runtime thread
//! of its own, and hands the learner its channel ends.

mod queues;
mod service;
mod topic;

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use coadapt_transport::messages::Dims;
use coadapt_transport::{Assignment, DesignReply, DesignRequest, ExperienceChunk, LearnerLinks, Receiver, Sender, TransportError};
use coadapt_wire::Wire;
use coadapt_wire::pb;
use tokio::sync::watch;

use crate::GrpcConfig;
use queues::{Inbox, Outbox};

/// Chunks the learner's experience queue holds before senders wait (their unacknowledged
/// window then fills, and `send` waits in the actors: backpressure, not memory growth).
const INBOX_CAPACITY: usize = 4096;

/// Which role a client registered as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClientRole {
    Actor,
    Optimizer,
}

/// What the learner knows of one client, from its registration, heartbeats and polls.
#[derive(Clone, Debug)]
pub struct ActorStatus {
    pub id: u64,
    pub role: ClientRole,
    pub last_seen: Instant,
    /// The weights version the client acts with (the policy lag is the newest minus this).
    pub weights_version: u64,
    /// Seen within three heartbeats and not gone.
    pub alive: bool,
}

#[derive(Debug)]
pub(crate) struct ClientRecord {
    pub(crate) role: ClientRole,
    pub(crate) id: u64,
    pub(crate) last_seen: Instant,
    pub(crate) weights_version: u64,
    /// It has been told the fleet is finished (so a shutdown need not wait for it).
    pub(crate) told_finished: bool,
    pub(crate) left: bool,
}

/// State shared by the RPC handlers and the learner's channel ends.
#[derive(Debug)]
pub(crate) struct Hub {
    pub(crate) cfg: GrpcConfig,
    pub(crate) experience: Arc<Inbox<ExperienceChunk>>,
    pub(crate) replies: Arc<Inbox<DesignReply>>,
    pub(crate) assignments: Arc<Outbox<pb::Assignment>>,
    pub(crate) requests: Arc<Outbox<pb::DesignRequest>>,
    pub(crate) acting: watch::Receiver<topic::Snapshot>,
    pub(crate) population: watch::Receiver<topic::Snapshot>,
    pub(crate) clients: Mutex<HashMap<u64, ClientRecord>>,
    pub(crate) dims: Mutex<Option<Dims>>,
    pub(crate) shutdown: watch::Receiver<bool>,
}

impl Hub {
    fn finished_for(&self, role: ClientRole) -> bool {
        match role {
            ClientRole::Actor => self.assignments.is_finished(),
            ClientRole::Optimizer => self.requests.is_finished(),
        }
    }

    fn alive(&self, r: &ClientRecord, now: Instant) -> bool {
        !r.left && now.duration_since(r.last_seen) < self.cfg.heartbeat * 3
    }
}

/// The running server. Dropping it (or [`LearnerServer::shutdown`]) stops it; if the learner
/// has finished the fleet, it first waits (a few heartbeats at most) until every live client
/// has been told, so clients of a learner that ended normally end normally too.
#[derive(Debug)]
pub struct LearnerServer {
    local_addr: SocketAddr,
    hub: Arc<Hub>,
    shutdown: watch::Sender<bool>,
    force: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Binds `addr` (port 0 picks one) and serves the fleet; returns the learner's channel ends
/// and the server handle.
pub fn serve_learner(addr: SocketAddr, cfg: &GrpcConfig) -> Result<(LearnerLinks, LearnerServer), TransportError> {
    let io = |e: std::io::Error| TransportError::Io(format!("learner server on {addr}: {e}"));
    let listener = std::net::TcpListener::bind(addr).map_err(io)?;
    listener.set_nonblocking(true).map_err(io)?;
    let local_addr = listener.local_addr().map_err(io)?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("coadapt-grpc-server")
        .enable_all()
        .build()
        .map_err(io)?;
    let listener = {
        let _in_rt = rt.enter();
        tokio::net::TcpListener::from_std(listener).map_err(io)?
    };

    let (acting_pub, acting) = topic::topic(cfg.max_message_bytes);
    let (population_pub, population) = topic::topic(cfg.max_message_bytes);
    let (shutdown, shutdown_rx) = watch::channel(false);
    let hub = Arc::new(Hub {
        cfg: cfg.clone(),
        experience: Arc::new(Inbox::new(INBOX_CAPACITY)),
        replies: Arc::new(Inbox::new(INBOX_CAPACITY)),
        assignments: Arc::new(Outbox::new()),
        requests: Arc::new(Outbox::new()),
        acting,
        population,
        clients: Mutex::new(HashMap::new()),
        dims: Mutex::new(None),
        shutdown: shutdown_rx.clone(),
    });
    let links = LearnerLinks {
        experience: Box::new(InboxReceiver(hub.experience.clone())),
        assignments: Box::new(OutboxSender::<Assignment> { outbox: hub.assignments.clone() }),
        acting_weights: Box::new(acting_pub),
        population_weights: Box::new(population_pub),
        design_requests: Box::new(OutboxSender::<DesignRequest> { outbox: hub.requests.clone() }),
        design_replies: Box::new(InboxReceiver(hub.replies.clone())),
    };

    let router = service::router(hub.clone(), &rt).map_err(|e| TransportError::Io(format!("building the services: {e}")))?;
    let (force, force_rx) = tokio::sync::oneshot::channel::<()>();
    let mut stop = shutdown_rx;
    let incoming = tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
    let thread = std::thread::Builder::new()
        .name("coadapt-grpc-learner".into())
        .spawn(move || {
            let served = rt.spawn(async move {
                let graceful = async move {
                    let _ = stop.wait_for(|s| *s).await;
                };
                if let Err(e) = router.serve_with_incoming_shutdown(incoming, graceful).await {
                    eprintln!("coadapt-grpc: learner server stopped: {e}");
                }
            });
            rt.block_on(async move {
                tokio::select! {
                    _ = served => {}
                    _ = force_rx => {}
                }
            });
            // Whatever is still running (a connection that would not close) ends here.
            rt.shutdown_timeout(Duration::from_millis(200));
        })
        .map_err(io)?;
    Ok((links, LearnerServer { local_addr, hub, shutdown, force: Some(force), thread: Some(thread) }))
}

impl LearnerServer {
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Every client seen, newest session per (role, id).
    pub fn clients(&self) -> Vec<ActorStatus> {
        let now = Instant::now();
        let Ok(clients) = self.hub.clients.lock() else { return Vec::new() };
        let mut newest: HashMap<(u64, bool), &ClientRecord> = HashMap::new();
        for r in clients.values() {
            let key = (r.id, r.role == ClientRole::Actor);
            if newest.get(&key).is_none_or(|o| o.last_seen < r.last_seen) {
                newest.insert(key, r);
            }
        }
        let mut out: Vec<ActorStatus> = newest
            .values()
            .map(|r| ActorStatus {
                id: r.id,
                role: r.role,
                last_seen: r.last_seen,
                weights_version: r.weights_version,
                alive: self.hub.alive(r, now),
            })
            .collect();
        out.sort_by_key(|s| (s.role == ClientRole::Optimizer, s.id));
        out
    }

    /// The actors seen, by id: liveness and the weights version each acts with.
    pub fn actors(&self) -> Vec<ActorStatus> {
        self.clients().into_iter().filter(|c| c.role == ClientRole::Actor).collect()
    }

    /// From now on, received experience and design replies are also checked against the
    /// robot's dimensions (obs, action and design widths); a mismatch is refused.
    pub fn expect_dims(&self, dims: Dims) {
        if let Ok(mut d) = self.hub.dims.lock() {
            *d = Some(dims);
        }
    }

    /// Stops serving (see the type's documentation for the wait before).
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        let Some(thread) = self.thread.take() else { return };
        self.linger();
        let _ = self.shutdown.send(true);
        // Streams end at the signal; a connection that does not close in time is cut.
        let deadline = Instant::now() + Duration::from_secs(2);
        while !thread.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
        if let Some(force) = self.force.take() {
            let _ = force.send(());
        }
        let _ = thread.join();
    }

    /// Waits until every live client of a finished role has been told, three heartbeats at most.
    fn linger(&self) {
        let deadline = Instant::now() + self.hub.cfg.heartbeat * 3;
        while Instant::now() < deadline {
            let now = Instant::now();
            let waiting = match self.hub.clients.lock() {
                Ok(c) => c.values().any(|r| self.hub.alive(r, now) && !r.told_finished && self.hub.finished_for(r.role)),
                Err(_) => false,
            };
            if !waiting {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for LearnerServer {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The learner's end of a queue from the clients.
#[derive(Debug)]
struct InboxReceiver<T>(Arc<Inbox<T>>);

impl<T: Send> Receiver<T> for InboxReceiver<T> {
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<T>, TransportError> {
        self.0.pop_timeout(timeout)
    }
}

/// The learner's end of a queue to the clients; dropping it finishes the fleet for that role.
#[derive(Debug)]
struct OutboxSender<T: Wire> {
    outbox: Arc<Outbox<T::Pb>>,
}

impl<T: Wire + Send> Sender<T> for OutboxSender<T>
where
    T::Pb: Clone + Send + Sync,
{
    fn send(&mut self, msg: T) -> Result<(), TransportError> {
        self.outbox.push(msg.to_pb())
    }
}

impl<T: Wire> Drop for OutboxSender<T> {
    fn drop(&mut self) {
        self.outbox.finish();
    }
}
