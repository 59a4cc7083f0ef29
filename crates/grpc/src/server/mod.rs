//! The learner's side: binds the port, serves Fleet, health and reflection on a runtime thread
//! of its own, and hands the learner its channel ends.
//!
//! # Trust model
//! A client registers a session (`Hello.session`, 64 random bits) and presents it in every
//! later call: in `Beat` and `Poll`, and in the `coadapt-session` metadata of its push streams.
//! The session is a capability token: whoever knows it acts as that client, and nothing else
//! does. Every call must name a registered session of the right role (actors poll assignments
//! and push experience, the optimiser polls design requests and pushes replies); an unknown
//! session is refused with FAILED_PRECONDITION "register first". Sender ids, assignments and
//! deliveries are bound to the session that first used or received them. A session silent
//! for `GrpcConfig::session_idle_timeout` is forgotten. This keeps clients from taking or
//! completing each other's work by guessing ids. It is not authentication: that is TLS and
//! the role tokens (`coadapt_auth`), checked by the gate in front of every call (`router`),
//! and which the binaries require off loopback unless told `--insecure`.

mod episodes;
use coadapt_auth::peers;
mod queues;
mod router;
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
use episodes::Episodes;
use queues::{Inbox, InboxLimits, Outbox, Reason};

/// Chunks the learner's experience queue holds before senders wait (their unacknowledged
/// window then fills, and `send` waits in the actors: backpressure, not memory growth).
const INBOX_CAPACITY: usize = 4096;

/// Which role a client registered as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClientRole {
    Actor,
    Optimizer,
}

/// What the learner refused or dropped from its clients, by reason, since it started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Refusals {
    /// Calls under a session that is not registered (never, or forgotten after silence).
    pub unregistered: u64,
    /// Calls of a session on the other role's queues, or a `Register` changing its role.
    pub wrong_role: u64,
    /// Registrations refused: `GrpcConfig::max_sessions` sessions are registered.
    pub sessions_full: u64,
    /// Frames under a sender id that another session uses.
    pub foreign_sender: u64,
    /// Frames of a new sender beyond `GrpcConfig::max_senders_per_session`.
    pub too_many_senders: u64,
    /// Frames whose sequence number jumps more than the send window ahead.
    pub seq_jump: u64,
    /// Chunks for an assignment held by another session or not handed out yet.
    pub foreign_assignment: u64,
    /// Chunks whose `end.length` or number of transitions is wrong or above the longest episode.
    pub bad_length: u64,
    /// Empty chunks not passed on (more than one per heartbeat for an episode).
    pub empty_dropped: u64,
    /// Chunks queued for an assignment before the learner issued it, dropped when it did.
    pub purged: u64,
    /// Calls stamped with another learner start's run id (clients of a predecessor that have
    /// not registered with this start yet); they register again and drop that start's state.
    pub other_run: u64,
    /// Connections closed as they were accepted: their host held
    /// `GrpcConfig::max_connections_per_peer` already.
    pub connections_per_peer: u64,
    /// Connections closed as they were accepted: `GrpcConfig::max_connections` were open.
    pub connections_total: u64,
    /// Calls without a token, or with one the learner does not accept (UNAUTHENTICATED).
    pub unauthenticated: u64,
    /// Calls whose token's role may not make them (PERMISSION_DENIED): a client's token on the
    /// fleet, an actor's on the population weights, a token of one role registering as another.
    pub permission_denied: u64,
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
    /// This learner start's run id (never 0).
    pub(crate) run_id: u64,
    pub(crate) experience: Arc<Inbox<ExperienceChunk, Episodes>>,
    pub(crate) replies: Arc<Inbox<DesignReply>>,
    pub(crate) assignments: Arc<Outbox<pb::Assignment>>,
    pub(crate) requests: Arc<Outbox<pb::DesignRequest>>,
    pub(crate) acting: watch::Receiver<topic::Snapshot>,
    pub(crate) population: watch::Receiver<topic::Snapshot>,
    pub(crate) clients: Mutex<HashMap<u64, ClientRecord>>,
    pub(crate) dims: Mutex<Option<Dims>>,
    pub(crate) shutdown: watch::Receiver<bool>,
    pub(crate) refusals: Mutex<Refusals>,
    /// Calls the token gates refused.
    pub(crate) gate_counts: Arc<coadapt_auth::GateCounts>,
}

impl Hub {
    /// Counts `n` refusals (or drops) of `reason` here and in the process's refusal ledger
    /// (by peer, for `/metrics`); `message` is what the client was told.
    pub(crate) fn count(&self, reason: Reason, n: u64, peer: Option<std::net::IpAddr>, message: &str) {
        coadapt_auth::refusals::record_n("fleet", reason.label(), peer, message, reason.notice(), n);
        let Ok(mut r) = self.refusals.lock() else { return };
        let field = match reason {
            Reason::Unregistered => &mut r.unregistered,
            Reason::WrongRole => &mut r.wrong_role,
            Reason::SessionsFull => &mut r.sessions_full,
            Reason::ForeignSender => &mut r.foreign_sender,
            Reason::TooManySenders => &mut r.too_many_senders,
            Reason::SeqJump => &mut r.seq_jump,
            Reason::ForeignAssignment => &mut r.foreign_assignment,
            Reason::BadLength => &mut r.bad_length,
            Reason::EmptyDropped => &mut r.empty_dropped,
            Reason::Purged => &mut r.purged,
            Reason::OtherRun => &mut r.other_run,
            Reason::PermissionDenied => &mut r.permission_denied,
        };
        *field = field.saturating_add(n);
    }

    /// How long a session may be silent before it is forgotten.
    pub(crate) fn idle_limit(&self) -> Duration {
        self.cfg.session_idle_timeout.max(self.cfg.heartbeat.saturating_mul(3))
    }

    /// Forgets the sessions silent for longer than the idle limit, with their senders and
    /// deliveries.
    pub(crate) fn prune(&self, now: Instant) {
        let idle = self.idle_limit();
        let gone: Vec<u64> = match self.clients.lock() {
            Ok(mut clients) => {
                let gone: Vec<u64> = clients.iter().filter(|(_, r)| now.duration_since(r.last_seen) > idle).map(|(s, _)| *s).collect();
                for s in &gone {
                    clients.remove(s);
                }
                gone
            }
            Err(_) => return,
        };
        for s in gone {
            self.experience.forget_session(s);
            self.replies.forget_session(s);
            self.assignments.forget(s);
            self.requests.forget(s);
        }
    }

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
    peers: Arc<peers::PeerLimits>,
    health: tonic_health::server::HealthReporter,
    handle: tokio::runtime::Handle,
    shutdown: watch::Sender<bool>,
    force: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Binds `addr` (port 0 picks one) and serves the fleet; returns the learner's channel ends
/// and the server handle. The server speaks for the learner start `cfg.run_id` (a random one
/// if `None`): clients that registered with another start drop what they kept of it.
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
    let limits = InboxLimits {
        capacity: INBOX_CAPACITY,
        max_bytes: cfg.inbox_max_bytes,
        window: u64::try_from(cfg.send_window).unwrap_or(u64::MAX),
        max_senders: cfg.max_senders_per_session,
    };
    let hub = Arc::new(Hub {
        cfg: cfg.clone(),
        run_id: cfg.run_id.filter(|&r| r != 0).unwrap_or_else(crate::random_u64),
        experience: Arc::new(Inbox::new(limits, Episodes::new(cfg.max_episode_steps, cfg.heartbeat))),
        replies: Arc::new(Inbox::new(limits, ())),
        assignments: Arc::new(Outbox::new()),
        requests: Arc::new(Outbox::new()),
        acting,
        population,
        clients: Mutex::new(HashMap::new()),
        dims: Mutex::new(None),
        shutdown: shutdown_rx.clone(),
        refusals: Mutex::new(Refusals::default()),
        gate_counts: Arc::default(),
    });
    let links = LearnerLinks {
        experience: Box::new(InboxReceiver(hub.experience.clone())),
        assignments: Box::new(AssignmentSender { hub: hub.clone() }),
        acting_weights: Box::new(acting_pub),
        population_weights: Box::new(population_pub),
        design_requests: Box::new(OutboxSender::<DesignRequest> { outbox: hub.requests.clone() }),
        design_replies: Box::new(InboxReceiver(hub.replies.clone())),
    };

    let (router, health) = router::router(hub.clone(), &rt).map_err(|e| TransportError::Io(format!("building the services: {e}")))?;
    let handle = rt.handle().clone();
    let (force, force_rx) = tokio::sync::oneshot::channel::<()>();
    rt.spawn(prune_sessions(hub.clone(), shutdown_rx.clone()));
    let mut stop = shutdown_rx;
    let peers = peers::PeerLimits::new("fleet", cfg.max_connections_per_peer, cfg.max_connections);
    let incoming = peers::LimitedIncoming::new(listener, peers.clone(), "coadapt-grpc learner");
    let thread = std::thread::Builder::new()
        .name("coadapt-grpc-learner".into())
        .spawn(move || {
            let served = rt.spawn(async move {
                let graceful = async move {
                    let _ = stop.wait_for(|s| *s).await;
                };
                if let Err(e) = router.serve_with_incoming_shutdown(incoming, graceful).await {
                    coadapt_log::logln!("coadapt-grpc: learner server stopped: {e}");
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
    Ok((links, LearnerServer { local_addr, hub, peers, health, handle, shutdown, force: Some(force), thread: Some(thread) }))
}

/// Sets grpc.health.v1 of a learner server for the whole server (`""`, what probes ask by
/// default) and for `coadapt.v1.Fleet`: NOT_SERVING when the learner cannot make progress, so
/// an orchestrator's probe restarts it.
#[derive(Clone)]
pub struct HealthSwitch {
    reporter: tonic_health::server::HealthReporter,
    handle: tokio::runtime::Handle,
}

impl std::fmt::Debug for HealthSwitch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HealthSwitch").finish_non_exhaustive()
    }
}

impl HealthSwitch {
    /// Call from outside the server's runtime (it blocks on it briefly).
    pub fn set_serving(&self, serving: bool) {
        use tonic_health::ServingStatus::{NotServing, Serving};
        let status = if serving { Serving } else { NotServing };
        let h = self.reporter.clone();
        self.handle.block_on(async move {
            h.set_service_status("", status).await;
            h.set_service_status("coadapt.v1.Fleet", status).await;
        });
    }
}

impl LearnerServer {
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The server's health switch, for a watchdog thread.
    pub fn health(&self) -> HealthSwitch {
        HealthSwitch { reporter: self.health.clone(), handle: self.handle.clone() }
    }

    /// The run id of the learner start this server speaks for (`GrpcConfig::run_id`, or the
    /// one drawn for it).
    pub fn run_id(&self) -> u64 {
        self.hub.run_id
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

    /// What was refused or dropped so far, by reason.
    pub fn refusals(&self) -> Refusals {
        use std::sync::atomic::Ordering::Relaxed;
        let mut r = self.hub.refusals.lock().map(|r| *r).unwrap_or_default();
        r.connections_per_peer = self.peers.refused_per_peer.load(Relaxed);
        r.connections_total = self.peers.refused_total.load(Relaxed);
        r.unauthenticated = self.hub.gate_counts.unauthenticated.load(Relaxed);
        r.permission_denied += self.hub.gate_counts.permission_denied.load(Relaxed);
        r
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

/// Forgets silent sessions every heartbeat until the server stops.
async fn prune_sessions(hub: Arc<Hub>, mut stop: watch::Receiver<bool>) {
    loop {
        tokio::select! {
            _ = tokio::time::sleep(hub.cfg.heartbeat) => hub.prune(Instant::now()),
            _ = stop.wait_for(|s| *s) => return,
        }
    }
}

/// The learner's end of a queue from the clients.
#[derive(Debug)]
struct InboxReceiver<T, G>(Arc<Inbox<T, G>>);

impl<T: Send, G: queues::Gate<T>> Receiver<T> for InboxReceiver<T, G> {
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

/// The learner's end of the assignment queue: an issued assignment is recorded with the
/// experience queue's gate before any actor can take it.
#[derive(Debug)]
struct AssignmentSender {
    hub: Arc<Hub>,
}

impl Sender<Assignment> for AssignmentSender {
    fn send(&mut self, a: Assignment) -> Result<(), TransportError> {
        let pb = a.to_pb();
        let purged = self.hub.experience.issue(pb.id, pb.mode == pb::EpisodeMode::Train as i32);
        self.hub.count(Reason::Purged, purged as u64, None, "queued before the learner issued the assignment");
        self.hub.assignments.push(pb)
    }
}

impl Drop for AssignmentSender {
    fn drop(&mut self) {
        self.hub.assignments.finish();
    }
}
