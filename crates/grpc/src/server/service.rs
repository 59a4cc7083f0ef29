//! The RPC handlers of `coadapt.v1.Fleet` (the router that serves them beside health and
//! reflection: `router.rs`).

use std::net::IpAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use coadapt_auth::Role;
use coadapt_transport::Validate;
use coadapt_wire::Wire;
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_server::Fleet;
use prost::Message;
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use super::queues::{Gate, Inbox, Incoming, Offer, Outbox, Reason, Take};
use super::topic::Snapshot;
use super::{ClientRecord, ClientRole, Hub};
use crate::frames::Frame;
use crate::{PROTOCOL, REFUSED_HEADER, REGISTER_HEADER, RUN_HEADER, SESSION_HEADER};

type Acks = ReceiverStream<Result<pb::Ack, Status>>;

#[derive(Debug)]
pub(super) struct FleetService {
    hub: Arc<Hub>,
}

impl FleetService {
    pub(super) fn new(hub: Arc<Hub>) -> Self {
        Self { hub }
    }
}

fn role_of(role: i32) -> Result<ClientRole, Status> {
    match pb::Role::try_from(role) {
        Ok(pb::Role::Actor) => Ok(ClientRole::Actor),
        Ok(pb::Role::Optimizer) => Ok(ClientRole::Optimizer),
        _ => Err(Status::invalid_argument(format!("role: {role} is not actor (1) or optimizer (2)"))),
    }
}

fn unavailable() -> Status {
    Status::unavailable("the learner is shutting down")
}

fn role_name(role: ClientRole) -> &'static str {
    match role {
        ClientRole::Actor => "an actor",
        ClientRole::Optimizer => "an optimizer",
    }
}

/// The session is not registered (never, or forgotten after silence, or the learner
/// restarted): our clients register again when they see the marker.
fn unregistered(session: u64) -> Status {
    let mut s = Status::failed_precondition(format!("session: {session:#x} is not registered here: register first"));
    s.metadata_mut().insert(REGISTER_HEADER, tonic::metadata::MetadataValue::from_static("first"));
    s
}

/// A call stamped with another learner start's run id: the client registers again, which tells
/// it the current run id (and it drops what it kept of the old start).
fn other_run(hub: &Hub, peer: Option<IpAddr>, claimed: u64) -> Status {
    let mut s = Status::failed_precondition(format!(
        "run id {claimed:#x}: this is learner start {:#x} (the learner restarted): register again",
        hub.run_id
    ));
    hub.count(Reason::OtherRun, 1, peer, s.message());
    s.metadata_mut().insert(REGISTER_HEADER, tonic::metadata::MetadataValue::from_static("first"));
    s
}

/// Admits what a client stamped with run id `claimed` (0: not stamped).
fn same_run(hub: &Hub, peer: Option<IpAddr>, claimed: u64) -> Result<(), Status> {
    if claimed == 0 || claimed == hub.run_id { Ok(()) } else { Err(other_run(hub, peer, claimed)) }
}

/// The run id a push stream's frames belong to, from its metadata (0: not named).
fn stream_run<T>(req: &Request<T>) -> Result<u64, Status> {
    let Some(v) = req.metadata().get(RUN_HEADER) else { return Ok(0) };
    v.to_str()
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .ok_or_else(|| Status::invalid_argument(format!("metadata {RUN_HEADER}: not a run id")))
}

/// An answer stamped with this learner start's run id.
fn stamped<T>(hub: &Hub, body: T) -> Response<T> {
    let mut r = Response::new(body);
    r.metadata_mut().insert(RUN_HEADER, hub.run_id.into());
    r
}

/// The caller's IP address (none when the call did not come over TCP).
fn peer_of<T>(req: &Request<T>) -> Option<IpAddr> {
    req.remote_addr().map(|a| a.ip())
}

/// The session a push stream belongs to, from its metadata.
fn stream_session<T>(req: &Request<T>) -> Result<u64, Status> {
    let Some(v) = req.metadata().get(SESSION_HEADER) else {
        return Err(Status::failed_precondition(format!("metadata {SESSION_HEADER}: missing (register first, then name the session)")));
    };
    v.to_str()
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .ok_or_else(|| Status::invalid_argument(format!("metadata {SESSION_HEADER}: not a session number")))
}

impl FleetService {
    /// Admits a call of `session` as `role`: it must be registered with that role. Records
    /// that the session is alive.
    fn caller(&self, peer: Option<IpAddr>, session: u64, role: ClientRole) -> Result<(), Status> {
        admit(&self.hub, peer, session, role)
    }

    fn told_finished(&self, session: u64) {
        if let Ok(mut clients) = self.hub.clients.lock()
            && let Some(r) = clients.get_mut(&session)
        {
            r.told_finished = true;
        }
    }

    /// A long poll on `outbox` by a session of `role`: (item, seq, finished).
    async fn poll<T: Clone>(
        &self,
        outbox: &Outbox<T>,
        role: ClientRole,
        peer: Option<IpAddr>,
        p: &pb::Poll,
    ) -> Result<(Option<T>, u64, bool), Status> {
        self.caller(peer, p.session, role)?;
        // `received` numbers another start's deliveries: it must not confirm one of ours.
        same_run(&self.hub, peer, p.run_id)?;
        if p.leaving {
            outbox.release(p.session, p.received);
            return Ok((None, 0, false));
        }
        let wait = Duration::from_millis(u64::from(p.wait_ms)).min(self.hub.cfg.long_poll_cap());
        let taken =
            outbox.take(p.session, p.received, wait, self.hub.shutdown.clone()).await.map_err(|e| Status::internal(e.to_string()))?;
        match taken {
            Take::Item(seq, x) => Ok((Some(x), seq, false)),
            Take::Finished => {
                self.told_finished(p.session);
                Ok((None, 0, true))
            }
            Take::Empty if *self.hub.shutdown.borrow() => Err(unavailable()),
            Take::Empty => Ok((None, 0, false)),
        }
    }

    /// Serves one client-to-learner stream of `session`: validate each frame, hand it to the
    /// inbox (a resend is dropped there, a frame of another session's sender or assignment
    /// refused), acknowledge. While the learner's queue is full, repeat the last
    /// acknowledgement every heartbeat so the client knows we are alive.
    fn pump<F: Frame, G: Gate<F::Item> + 'static>(
        &self,
        inbox: Arc<Inbox<F::Item, G>>,
        session: u64,
        role: ClientRole,
        peer: Option<IpAddr>,
        mut frames: Streaming<F>,
    ) -> Acks {
        let (tx, rx) = mpsc::channel(64);
        let hub = self.hub.clone();
        tokio::spawn(async move {
            let mut stop = hub.shutdown.clone();
            loop {
                let frame = tokio::select! {
                    f = frames.message() => Some(f),
                    _ = stop.wait_for(|s| *s) => None,
                };
                let Some(frame) = frame else {
                    let _ = tx.send(Err(unavailable())).await;
                    return;
                };
                let (sender, seq, payload, fin) = match frame {
                    Ok(Some(f)) => f.parts(),
                    Ok(None) => return,
                    Err(status) => {
                        // Oversized or undecodable: the client learns why.
                        let _ = tx.send(Err(status)).await;
                        return;
                    }
                };
                // Still registered (a session forgotten mid-stream registers again).
                if let Err(status) = admit(&hub, peer, session, role) {
                    let _ = tx.send(Err(status)).await;
                    return;
                }
                let (item, bytes) = match (fin, payload) {
                    (true, _) => (None, 0),
                    (false, None) => {
                        let _ = tx.send(Err(Status::invalid_argument(format!("frame {seq}: {}: missing", F::PAYLOAD)))).await;
                        return;
                    }
                    (false, Some(pb)) => {
                        let bytes = pb.encoded_len();
                        match check::<F>(&hub, pb) {
                            Ok(x) => (Some(x), bytes),
                            Err(why) => {
                                let _ = tx.send(Err(Status::invalid_argument(format!("frame {seq}: {}.{why}", F::PAYLOAD)))).await;
                                return;
                            }
                        }
                    }
                };
                let mut incoming = Incoming { sender, session, seq, item, bytes };
                loop {
                    let offered = inbox.offer_wait(incoming, hub.cfg.heartbeat).await;
                    let (offer, back) = match offered {
                        Ok(x) => x,
                        Err(e) => {
                            let _ = tx.send(Err(Status::internal(e.to_string()))).await;
                            return;
                        }
                    };
                    incoming = back;
                    match offer {
                        Offer::Full(_) => {
                            if tx.send(Ok(pb::Ack { acked: inbox.acked(sender) })).await.is_err() {
                                return;
                            }
                        }
                        Offer::Accepted | Offer::Duplicate => break,
                        Offer::Skipped(reason) => {
                            hub.count(reason, 1, peer, "skipped");
                            break;
                        }
                        Offer::Refused(r) => {
                            let mut status = Status::new(r.code, format!("frame {seq}: {}", r.message));
                            hub.count(r.reason, 1, peer, status.message());
                            if r.frame_only {
                                status.metadata_mut().insert(REFUSED_HEADER, seq.into());
                            }
                            let _ = tx.send(Err(status)).await;
                            return;
                        }
                    }
                    if *stop.borrow() {
                        let _ = tx.send(Err(unavailable())).await;
                        return;
                    }
                }
                if tx.send(Ok(pb::Ack { acked: seq })).await.is_err() {
                    return;
                }
            }
        });
        ReceiverStream::new(rx)
    }
}

/// See [`FleetService::caller`].
fn admit(hub: &Hub, peer: Option<IpAddr>, session: u64, role: ClientRole) -> Result<(), Status> {
    let Ok(mut clients) = hub.clients.lock() else { return Err(Status::internal("client table lock poisoned")) };
    let Some(r) = clients.get_mut(&session) else {
        drop(clients);
        let status = unregistered(session);
        hub.count(Reason::Unregistered, 1, peer, status.message());
        return Err(status);
    };
    if r.role != role {
        let why = format!("role: session {session:#x} is registered as {}, not {}", role_name(r.role), role_name(role));
        drop(clients);
        hub.count(Reason::WrongRole, 1, peer, &why);
        return Err(Status::permission_denied(why));
    }
    r.last_seen = Instant::now();
    Ok(())
}

/// Decodes with validation, then checks the robot's dimensions if the learner declared them.
fn check<F: Frame>(hub: &Hub, pb: <F::Item as Wire>::Pb) -> Result<F::Item, String> {
    let x = F::Item::from_pb(pb).map_err(|e| e.to_string())?;
    if let Ok(dims) = hub.dims.lock()
        && let Some(dims) = *dims
    {
        x.validate(&dims).map_err(|e| e.to_string())?;
    }
    Ok(x)
}

impl FleetService {
    /// PERMISSION_DENIED (counted) unless the caller's token is of `role` (or an operator's).
    fn token_allows<T>(&self, req: &Request<T>, role: ClientRole, what: &str) -> Result<(), Status> {
        let need = match role {
            ClientRole::Actor => Role::Actor,
            ClientRole::Optimizer => Role::Optimizer,
        };
        coadapt_auth::require(req, &[need], &format!("{what} {}", need.name())).map(|_| ()).inspect_err(|s| {
            self.hub.count(Reason::PermissionDenied, 1, peer_of(req), s.message());
        })
    }
}

#[tonic::async_trait]
impl Fleet for FleetService {
    async fn register(&self, req: Request<pb::Hello>) -> Result<Response<pb::Welcome>, Status> {
        let role = role_of(req.get_ref().role)?;
        self.token_allows(&req, role, "register as")?;
        let peer = peer_of(&req);
        let h = req.into_inner();
        if h.fleet != self.hub.cfg.fleet {
            return Err(Status::failed_precondition(format!("this learner serves fleet {:?}, not {:?}", self.hub.cfg.fleet, h.fleet)));
        }
        if h.protocol != PROTOCOL {
            return Err(Status::failed_precondition(format!("this learner speaks protocol {PROTOCOL}, not {}", h.protocol)));
        }
        let now = Instant::now();
        let known = self.hub.clients.lock().map(|c| c.contains_key(&h.session)).unwrap_or(false);
        if !known {
            self.hub.prune(now);
        }
        let mut new_optimizer = false;
        let refused = {
            let Ok(mut clients) = self.hub.clients.lock() else { return Err(Status::internal("client table lock poisoned")) };
            let n = clients.len();
            match clients.get_mut(&h.session) {
                // Registering again (a lost answer, a forgotten session) keeps the role.
                Some(r) if r.role != role => Some((
                    Reason::WrongRole,
                    Status::permission_denied(format!("role: session {:#x} is registered as {}", h.session, role_name(r.role))),
                )),
                Some(r) => {
                    r.last_seen = now;
                    r.left = false;
                    r.id = h.actor_id;
                    None
                }
                None if n >= self.hub.cfg.max_sessions => Some((
                    Reason::SessionsFull,
                    Status::resource_exhausted(format!(
                        "sessions: {n} registered, the most this learner serves (GrpcConfig::max_sessions)"
                    )),
                )),
                None => {
                    clients.insert(
                        h.session,
                        ClientRecord { role, id: h.actor_id, last_seen: now, weights_version: 0, told_finished: false, left: false },
                    );
                    new_optimizer = role == ClientRole::Optimizer;
                    None
                }
            }
        };
        if let Some((reason, status)) = refused {
            self.hub.count(reason, 1, peer, status.message());
            return Err(status);
        }
        if new_optimizer {
            // A restarted optimiser: the request its dead predecessor had taken is its now
            // (not after the learner's resend deadline, nor after that session is forgotten).
            let offered = self.hub.requests.offer_held_to(h.session);
            if offered > 0 {
                coadapt_log::logln!(
                    "coadapt-grpc: a new optimiser session; {offered} design request(s) another session had taken offered to it"
                );
            }
        }
        Ok(Response::new(pb::Welcome {
            fleet: self.hub.cfg.fleet.clone(),
            protocol: PROTOCOL,
            max_message_bytes: self.hub.cfg.max_message_bytes as u64,
            run_id: self.hub.run_id,
        }))
    }

    async fn heartbeat(&self, req: Request<pb::Beat>) -> Result<Response<pb::BeatReply>, Status> {
        let role = role_of(req.get_ref().role)?;
        self.token_allows(&req, role, "beat as")?;
        let peer = peer_of(&req);
        let b = req.into_inner();
        self.caller(peer, b.session, role)?;
        same_run(&self.hub, peer, b.run_id)?;
        if let Ok(mut clients) = self.hub.clients.lock()
            && let Some(r) = clients.get_mut(&b.session)
        {
            r.weights_version = b.weights_version;
            r.left = b.leaving;
        }
        let fleet_finished = self.hub.finished_for(role);
        if fleet_finished {
            self.told_finished(b.session);
        }
        Ok(Response::new(pb::BeatReply {
            fleet_finished,
            acting_version: self.hub.acting.borrow().version,
            population_version: self.hub.population.borrow().version,
            run_id: self.hub.run_id,
        }))
    }

    type PushExperienceStream = Acks;

    async fn push_experience(&self, req: Request<Streaming<pb::ExperienceFrame>>) -> Result<Response<Acks>, Status> {
        self.token_allows(&req, ClientRole::Actor, "push experience as")?;
        let session = stream_session(&req)?;
        let peer = peer_of(&req);
        self.caller(peer, session, ClientRole::Actor)?;
        same_run(&self.hub, peer, stream_run(&req)?)?;
        Ok(Response::new(self.pump(self.hub.experience.clone(), session, ClientRole::Actor, peer, req.into_inner())))
    }

    type PushDesignRepliesStream = Acks;

    async fn push_design_replies(&self, req: Request<Streaming<pb::DesignReplyFrame>>) -> Result<Response<Acks>, Status> {
        self.token_allows(&req, ClientRole::Optimizer, "push design replies as")?;
        let session = stream_session(&req)?;
        let peer = peer_of(&req);
        self.caller(peer, session, ClientRole::Optimizer)?;
        same_run(&self.hub, peer, stream_run(&req)?)?;
        Ok(Response::new(self.pump(self.hub.replies.clone(), session, ClientRole::Optimizer, peer, req.into_inner())))
    }

    type WatchWeightsStream = ReceiverStream<Result<pb::WeightsUpdate, Status>>;

    async fn watch_weights(&self, req: Request<pb::WatchRequest>) -> Result<Response<Self::WatchWeightsStream>, Status> {
        let topic = match pb::WeightsTopic::try_from(req.get_ref().topic) {
            Ok(pb::WeightsTopic::Acting) => {
                self.token_allows(&req, ClientRole::Actor, "watch the acting weights as")?;
                self.hub.acting.clone()
            }
            // The population networks are the run's critic: optimisers and operators only.
            Ok(pb::WeightsTopic::Population) => {
                self.token_allows(&req, ClientRole::Optimizer, "watch the population weights as")?;
                self.hub.population.clone()
            }
            _ => return Err(Status::invalid_argument(format!("topic: {} is not acting (1) or population (2)", req.get_ref().topic))),
        };
        let w = req.into_inner();
        // Versions of another start are no measure of ours: send our newest, whatever its number.
        let min_version = if w.run_id == 0 || w.run_id == self.hub.run_id { w.min_version } else { 0 };
        let (tx, rx) = mpsc::channel(1);
        tokio::spawn(watch_topic(topic, min_version, self.hub.cfg.heartbeat, self.hub.shutdown.clone(), tx));
        Ok(stamped(&self.hub, ReceiverStream::new(rx)))
    }

    async fn next_assignment(&self, req: Request<pb::Poll>) -> Result<Response<pb::AssignmentDelivery>, Status> {
        self.token_allows(&req, ClientRole::Actor, "take assignments as")?;
        let peer = peer_of(&req);
        let p = req.into_inner();
        let (assignment, seq, finished) = self.poll(&self.hub.assignments, ClientRole::Actor, peer, &p).await?;
        if let Some(a) = &assignment {
            // From now on its experience is accepted from this session only.
            self.hub.experience.deliver(a.id, p.session, a.mode == pb::EpisodeMode::Train as i32);
        }
        Ok(stamped(&self.hub, pb::AssignmentDelivery { assignment, seq, finished }))
    }

    async fn next_design_request(&self, req: Request<pb::Poll>) -> Result<Response<pb::DesignRequestDelivery>, Status> {
        self.token_allows(&req, ClientRole::Optimizer, "take design requests as")?;
        let peer = peer_of(&req);
        let (request, seq, finished) = self.poll(&self.hub.requests, ClientRole::Optimizer, peer, &req.into_inner()).await?;
        Ok(stamped(&self.hub, pb::DesignRequestDelivery { request, seq, finished }))
    }
}

/// Feeds one WatchWeights stream. It takes a slot in the (one-deep) channel before reading the
/// topic, so what it sends is the newest version when there is room to send, never a backlog.
async fn watch_topic(
    mut topic: watch::Receiver<Snapshot>,
    min_version: u64,
    heartbeat: Duration,
    mut stop: watch::Receiver<bool>,
    tx: mpsc::Sender<Result<pb::WeightsUpdate, Status>>,
) {
    let mut want = min_version;
    loop {
        let Ok(permit) = tx.reserve().await else { return };
        let snap = topic.borrow_and_update().clone();
        if let Some(w) = snap.weights.filter(|_| snap.version >= want) {
            want = snap.version + 1;
            permit.send(Ok(pb::WeightsUpdate { weights: Some(w), publisher_closed: false }));
            continue;
        }
        if snap.closed {
            permit.send(Ok(pb::WeightsUpdate { weights: None, publisher_closed: true }));
            return;
        }
        tokio::select! {
            changed = topic.changed() => {
                if changed.is_err() {
                    // The publisher is gone without a last word: treat as closed.
                    permit.send(Ok(pb::WeightsUpdate { weights: None, publisher_closed: true }));
                    return;
                }
            }
            _ = tokio::time::sleep(heartbeat) => permit.send(Ok(pb::WeightsUpdate::default())),
            _ = stop.wait_for(|s| *s) => {
                permit.send(Err(unavailable()));
                return;
            }
        }
    }
}
