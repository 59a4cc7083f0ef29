//! The RPC handlers of `coadapt.v1.Fleet`, and the router that serves them beside health and
//! reflection.

use std::sync::Arc;
use std::time::{Duration, Instant};

use coadapt_transport::Validate;
use coadapt_wire::Wire;
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_server::{Fleet, FleetServer};
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use super::queues::{Inbox, Offer, Outbox, Take};
use super::topic::Snapshot;
use super::{ClientRecord, ClientRole, Hub};
use crate::frames::Frame;
use crate::{CONNECTION_WINDOW, PROTOCOL, STREAM_WINDOW};

type Acks = ReceiverStream<Result<pb::Ack, Status>>;

/// Fleet, grpc.health.v1 and reflection (v1 and v1alpha, which know the health service too),
/// with the message-size limit on both directions.
pub(super) fn router(
    hub: Arc<Hub>,
    rt: &tokio::runtime::Runtime,
) -> Result<tonic::transport::server::Router, tonic_reflection::server::Error> {
    let cfg = hub.cfg.clone();
    let fleet = FleetServer::new(FleetService { hub })
        .max_decoding_message_size(cfg.max_message_bytes)
        .max_encoding_message_size(cfg.max_message_bytes);
    let (health_reporter, health) = tonic_health::server::health_reporter();
    // Serving before the first client can ask.
    let (set, is_set) = std::sync::mpsc::sync_channel(1);
    rt.spawn(async move {
        health_reporter.set_serving::<FleetServer<FleetService>>().await;
        let _ = set.send(());
    });
    let _ = is_set.recv();
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(coadapt_wire::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    Ok(tonic::transport::Server::builder()
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW)
        .http2_keepalive_interval(Some(cfg.heartbeat))
        .http2_keepalive_timeout(Some(cfg.rpc_timeout))
        .tcp_nodelay(true)
        .add_service(fleet)
        .add_service(health)
        .add_service(reflection().build_v1()?)
        .add_service(reflection().build_v1alpha()?))
}

#[derive(Debug)]
pub(super) struct FleetService {
    hub: Arc<Hub>,
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

impl FleetService {
    /// Records that `session` is alive; a heartbeat from a session we do not know (we
    /// restarted) registers it again.
    fn touch(&self, session: u64, role: ClientRole, id: u64, weights_version: Option<u64>, left: bool) {
        let Ok(mut clients) = self.hub.clients.lock() else { return };
        let r = clients.entry(session).or_insert(ClientRecord {
            role,
            id,
            last_seen: Instant::now(),
            weights_version: 0,
            told_finished: false,
            left: false,
        });
        r.last_seen = Instant::now();
        r.left = left;
        if let Some(v) = weights_version {
            r.weights_version = v;
        }
    }

    fn told_finished(&self, session: u64) {
        if let Ok(mut clients) = self.hub.clients.lock()
            && let Some(r) = clients.get_mut(&session)
        {
            r.told_finished = true;
        }
    }

    fn seen(&self, session: u64) {
        if let Ok(mut clients) = self.hub.clients.lock()
            && let Some(r) = clients.get_mut(&session)
        {
            r.last_seen = Instant::now();
        }
    }

    /// A long poll on `outbox`: (item, seq, finished).
    async fn poll<T: Clone>(&self, outbox: &Outbox<T>, p: pb::Poll) -> Result<(Option<T>, u64, bool), Status> {
        self.seen(p.session);
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

    /// Serves one client-to-learner stream: validate each frame, hand it to the inbox (a
    /// resend is dropped there), acknowledge. While the learner's queue is full, repeat the
    /// last acknowledgement every heartbeat so the client knows we are alive.
    fn pump<F: Frame>(&self, inbox: Arc<Inbox<F::Item>>, mut frames: Streaming<F>) -> Acks {
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
                let item = match (fin, payload) {
                    (true, _) => None,
                    (false, None) => {
                        let _ = tx.send(Err(Status::invalid_argument(format!("frame {seq}: {}: missing", F::PAYLOAD)))).await;
                        return;
                    }
                    (false, Some(pb)) => match check::<F>(&hub, pb) {
                        Ok(x) => Some(x),
                        Err(why) => {
                            let _ = tx.send(Err(Status::invalid_argument(format!("frame {seq}: {}.{why}", F::PAYLOAD)))).await;
                            return;
                        }
                    },
                };
                let mut item = item;
                loop {
                    match inbox.offer_wait(sender, seq, item, hub.cfg.heartbeat).await {
                        Ok(Offer::Full(back)) => {
                            item = back;
                            if tx.send(Ok(pb::Ack { acked: inbox.acked(sender) })).await.is_err() {
                                return;
                            }
                        }
                        Ok(_) => break,
                        Err(e) => {
                            let _ = tx.send(Err(Status::internal(e.to_string()))).await;
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

#[tonic::async_trait]
impl Fleet for FleetService {
    async fn register(&self, req: Request<pb::Hello>) -> Result<Response<pb::Welcome>, Status> {
        let h = req.into_inner();
        let role = role_of(h.role)?;
        if h.fleet != self.hub.cfg.fleet {
            return Err(Status::failed_precondition(format!("this learner serves fleet {:?}, not {:?}", self.hub.cfg.fleet, h.fleet)));
        }
        if h.protocol != PROTOCOL {
            return Err(Status::failed_precondition(format!("this learner speaks protocol {PROTOCOL}, not {}", h.protocol)));
        }
        self.touch(h.session, role, h.actor_id, None, false);
        Ok(Response::new(pb::Welcome {
            fleet: self.hub.cfg.fleet.clone(),
            protocol: PROTOCOL,
            max_message_bytes: self.hub.cfg.max_message_bytes as u64,
        }))
    }

    async fn heartbeat(&self, req: Request<pb::Beat>) -> Result<Response<pb::BeatReply>, Status> {
        let b = req.into_inner();
        let role = role_of(b.role)?;
        self.touch(b.session, role, b.actor_id, Some(b.weights_version), b.leaving);
        let fleet_finished = self.hub.finished_for(role);
        if fleet_finished {
            self.told_finished(b.session);
        }
        Ok(Response::new(pb::BeatReply {
            fleet_finished,
            acting_version: self.hub.acting.borrow().version,
            population_version: self.hub.population.borrow().version,
        }))
    }

    type PushExperienceStream = Acks;

    async fn push_experience(&self, req: Request<Streaming<pb::ExperienceFrame>>) -> Result<Response<Acks>, Status> {
        Ok(Response::new(self.pump(self.hub.experience.clone(), req.into_inner())))
    }

    type PushDesignRepliesStream = Acks;

    async fn push_design_replies(&self, req: Request<Streaming<pb::DesignReplyFrame>>) -> Result<Response<Acks>, Status> {
        Ok(Response::new(self.pump(self.hub.replies.clone(), req.into_inner())))
    }

    type WatchWeightsStream = ReceiverStream<Result<pb::WeightsUpdate, Status>>;

    async fn watch_weights(&self, req: Request<pb::WatchRequest>) -> Result<Response<Self::WatchWeightsStream>, Status> {
        let w = req.into_inner();
        let topic = match pb::WeightsTopic::try_from(w.topic) {
            Ok(pb::WeightsTopic::Acting) => self.hub.acting.clone(),
            Ok(pb::WeightsTopic::Population) => self.hub.population.clone(),
            _ => return Err(Status::invalid_argument(format!("topic: {} is not acting (1) or population (2)", w.topic))),
        };
        let (tx, rx) = mpsc::channel(1);
        tokio::spawn(watch_topic(topic, w.min_version, self.hub.cfg.heartbeat, self.hub.shutdown.clone(), tx));
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn next_assignment(&self, req: Request<pb::Poll>) -> Result<Response<pb::AssignmentDelivery>, Status> {
        let (assignment, seq, finished) = self.poll(&self.hub.assignments, req.into_inner()).await?;
        Ok(Response::new(pb::AssignmentDelivery { assignment, seq, finished }))
    }

    async fn next_design_request(&self, req: Request<pb::Poll>) -> Result<Response<pb::DesignRequestDelivery>, Status> {
        let (request, seq, finished) = self.poll(&self.hub.requests, req.into_inner()).await?;
        Ok(Response::new(pb::DesignRequestDelivery { request, seq, finished }))
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
