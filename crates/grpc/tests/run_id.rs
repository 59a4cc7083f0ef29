//! A learner that crashes and is started again (`--resume`, perhaps from a snapshot several
//! episodes old) is a new learner start with a run id of its own. Clients that survive the
//! restart must not mix the two starts: the old start's cached weights, unacknowledged frames
//! and long-poll acknowledgements never reach the new one, whatever its version numbers.

use crate::common;

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use coadapt_grpc::{ClientRole, LearnerServer, actor_links, optimizer_links, serve_learner};
use coadapt_transport::conformance::{chunk, weights};
use coadapt_transport::{Assignment, DesignReply, EpisodeMode};
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;
use coadapt_wire::pb::fleet_server::{Fleet, FleetServer};
use tonic::transport::Channel;
use tonic::{Request, Response, Status, Streaming};

const LONG: Duration = Duration::from_secs(10);

fn assignment(id: u64) -> Assignment {
    Assignment { id, design_index: 0, design: vec![1.0, id as f32], mode: EpisodeMode::Train, seed: id, min_weights_version: 0 }
}

fn reply(index: u32) -> DesignReply {
    DesignReply { index, design: vec![1.0, 2.0], method: "pso-q".into(), predicted_objective: None, design_rollouts: 0 }
}

/// Waits until `n` clients have registered with `server` (the new start), then a few
/// heartbeats more, so each has read the answer to its registration.
fn wait_registered(server: &LearnerServer, n: usize) {
    let t = Instant::now();
    while server.clients().len() < n {
        assert!(t.elapsed() < LONG, "only {:?} registered with the new learner", server.clients());
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(400));
}

/// The new start publishes a LOWER version than the old one had: the subscriber drops what it
/// cached from the old start and waits for the new start's weights.
#[test]
fn weights_of_the_old_start_are_dropped_whatever_the_versions() {
    let cfg = common::cfg();
    let (mut a, server_a, endpoint) = common::learner();
    let addr = server_a.local_addr();
    let mut actor = actor_links(&endpoint, 1, &cfg).expect("actor");
    a.acting_weights.publish(weights(5, 100)).expect("publish");
    assert_eq!(actor.weights.wait_for(5, LONG).expect("wait").expect("weights").version, 5);

    // Start A crashes; start B resumes from an older snapshot and republishes version 2.
    drop(server_a);
    drop(a);
    let (mut b, server_b) = serve_learner(addr, &cfg).expect("a new learner start on the same port");
    wait_registered(&server_b, 1);
    b.acting_weights.publish(weights(2, 100)).expect("publish");
    let got = actor.weights.wait_for(1, LONG).expect("wait").expect("weights");
    assert_eq!(got.version, 2, "the actor acted with start A's cached version {} instead of start B's", got.version);
    assert_eq!(*got, weights(2, 100));
    b.acting_weights.publish(weights(3, 100)).expect("publish");
    assert_eq!(*actor.weights.wait_for(3, LONG).expect("wait").expect("weights"), weights(3, 100));
}

/// Experience and design replies the old start never acknowledged (sent while it was away) are
/// dropped, not delivered to the new start, which issues those episodes itself; what the role
/// code sends afterwards reaches the new start, numbered afresh.
#[test]
fn unacknowledged_frames_of_the_old_start_never_reach_the_new_one() {
    let cfg = common::cfg();
    let (mut a, server_a, endpoint) = common::learner();
    let addr = server_a.local_addr();
    let mut actor = actor_links(&endpoint, 1, &cfg).expect("actor");
    let mut opt = optimizer_links(&endpoint, &cfg).expect("optimizer");
    actor.experience.send(chunk(1)).expect("send");
    opt.replies.send(reply(1)).expect("send");
    assert_eq!(a.experience.recv_timeout(LONG).expect("recv"), Some(chunk(1)));
    assert_eq!(a.design_replies.recv_timeout(LONG).expect("recv"), Some(reply(1)));
    std::thread::sleep(Duration::from_millis(200));

    drop(server_a);
    drop(a);
    for i in 10..15 {
        actor.experience.send(chunk(i)).expect("into the window while the learner is away");
    }
    opt.replies.send(reply(10)).expect("into the window while the learner is away");

    let (mut b, server_b) = serve_learner(addr, &cfg).expect("a new learner start on the same port");
    wait_registered(&server_b, 2);
    actor.experience.send(chunk(99)).expect("send");
    opt.replies.send(reply(99)).expect("send");
    let got = b.experience.recv_timeout(LONG).expect("recv").expect("a chunk");
    assert_eq!(got.assignment, 99, "start B received start A's unacknowledged chunk {}", got.assignment);
    assert_eq!(b.experience.recv_timeout(Duration::from_millis(300)).expect("recv"), None, "nothing else");
    let got = b.design_replies.recv_timeout(LONG).expect("recv").expect("a reply");
    assert_eq!(got.index, 99, "start B received start A's unacknowledged reply {}", got.index);
    assert_eq!(b.design_replies.recv_timeout(Duration::from_millis(300)).expect("recv"), None, "nothing else");
    assert!(server_b.clients().iter().any(|c| c.role == ClientRole::Optimizer));
}

/// (Poll.received, answered with a delivery or an empty poll rather than an error), per poll.
type Polls = Arc<Mutex<Vec<(u64, bool)>>>;

/// A Fleet service in front of the real new start that records each assignment poll it
/// relays and whether the learner answered it.
struct Recorder {
    learner: FleetClient<Channel>,
    polls: Polls,
}

/// The learner's answer, with its `coadapt-*` metadata.
fn relay<T>(r: Response<T>) -> Response<T> {
    let (md, body, _) = r.into_parts();
    let mut out = Response::new(body);
    for kv in md.iter() {
        if let tonic::metadata::KeyAndValueRef::Ascii(k, v) = kv
            && k.as_str().starts_with("coadapt-")
        {
            out.metadata_mut().insert(k.clone(), v.clone());
        }
    }
    out
}

type Nothing<T> = tokio_stream::Empty<Result<T, Status>>;

#[tonic::async_trait]
impl Fleet for Recorder {
    async fn register(&self, req: Request<pb::Hello>) -> Result<Response<pb::Welcome>, Status> {
        self.learner.clone().register(req.into_inner()).await.map(relay)
    }

    async fn heartbeat(&self, req: Request<pb::Beat>) -> Result<Response<pb::BeatReply>, Status> {
        self.learner.clone().heartbeat(req.into_inner()).await.map(relay)
    }

    type PushExperienceStream = Nothing<pb::Ack>;

    async fn push_experience(&self, _: Request<Streaming<pb::ExperienceFrame>>) -> Result<Response<Self::PushExperienceStream>, Status> {
        Err(Status::unavailable("not relayed"))
    }

    type PushDesignRepliesStream = Nothing<pb::Ack>;

    async fn push_design_replies(
        &self,
        _: Request<Streaming<pb::DesignReplyFrame>>,
    ) -> Result<Response<Self::PushDesignRepliesStream>, Status> {
        Err(Status::unavailable("not relayed"))
    }

    type WatchWeightsStream = Nothing<pb::WeightsUpdate>;

    async fn watch_weights(&self, _: Request<pb::WatchRequest>) -> Result<Response<Self::WatchWeightsStream>, Status> {
        Err(Status::unavailable("not relayed"))
    }

    async fn next_assignment(&self, req: Request<pb::Poll>) -> Result<Response<pb::AssignmentDelivery>, Status> {
        let p = req.into_inner();
        let received = p.received;
        let answer = self.learner.clone().next_assignment(p).await;
        self.polls.lock().expect("polls").push((received, answer.is_ok()));
        answer.map(relay)
    }

    async fn next_design_request(&self, _: Request<pb::Poll>) -> Result<Response<pb::DesignRequestDelivery>, Status> {
        Err(Status::unavailable("not relayed"))
    }
}

/// Serves a recorder on `addr` that relays to the learner at `learner`; returns what it records
/// and its runtime (it serves until the runtime is dropped).
fn serve_recorder(addr: SocketAddr, learner: String) -> (Polls, tokio::runtime::Runtime) {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().expect("runtime");
    let learner = rt.block_on(FleetClient::connect(learner)).expect("connect to the learner");
    let recorder = Recorder { learner, polls: Arc::default() };
    let polls = recorder.polls.clone();
    let listener = rt.block_on(tokio::net::TcpListener::bind(addr)).expect("the old start's port");
    let incoming = tonic::transport::server::TcpIncoming::from(listener);
    rt.spawn(tonic::transport::Server::builder().add_service(FleetServer::new(recorder)).serve_with_incoming(incoming));
    (polls, rt)
}

/// The actor received an assignment from start A (delivery 1 of A's numbering). Its polls to
/// start B must not acknowledge that delivery: B's numbering is B's own, and a stale
/// acknowledgement could confirm a delivery of B's the actor never received.
#[test]
fn an_assignment_received_from_the_old_start_is_not_acknowledged_to_the_new_one() {
    let cfg = common::cfg();
    let (mut a, server_a, endpoint) = common::learner();
    let addr = server_a.local_addr();
    let mut actor = actor_links(&endpoint, 1, &cfg).expect("actor");
    a.assignments.send(assignment(1)).expect("send");
    assert_eq!(actor.assignments.recv_timeout(LONG).expect("recv"), Some(assignment(1)));

    drop(server_a);
    drop(a);
    // Start B, reached through a recorder on start A's port.
    let (mut b, server_b, b_endpoint) = common::learner();
    let (polls, _relay) = serve_recorder(addr, b_endpoint);

    b.assignments.send(assignment(2)).expect("send");
    assert_eq!(actor.assignments.recv_timeout(LONG).expect("recv"), Some(assignment(2)), "start B's assignment");
    let polls = polls.lock().expect("polls").clone();
    let answered: Vec<u64> = polls.iter().filter(|(_, ok)| *ok).map(|(r, _)| *r).collect();
    assert_eq!(answered.first(), Some(&0), "start B accepted polls acknowledging deliveries {answered:?} (all polls: {polls:?})");
    assert!(server_b.actors().iter().any(|s| s.id == 1));
}

/// The server's half, seen by a raw client: a learner start answers with its run id and refuses
/// (register first) what is stamped with another start's, so a predecessor's acknowledgements,
/// frames and version numbers never count; unstamped calls (0) are taken as its own.
#[test]
fn a_learner_start_refuses_what_is_stamped_with_another_run_id() {
    const A: u64 = 0xA;
    const B: u64 = 0xB;
    let cfg = coadapt_grpc::GrpcConfig { run_id: Some(B), ..common::cfg() };
    let (mut learner, server, endpoint) = common::learner_with(&cfg);
    assert_eq!(server.run_id(), B);
    let (_l1, s1, _) = common::learner();
    let (_l2, s2, _) = common::learner();
    assert!(s1.run_id() != 0 && s1.run_id() != s2.run_id(), "a start without a run id draws its own");

    learner.assignments.send(assignment(1)).expect("send");
    learner.acting_weights.publish(weights(2, 10)).expect("publish");
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    rt.block_on(async move {
        let mut c = FleetClient::connect(endpoint).await.expect("connect");
        let session = 0x5E55;
        let hello =
            pb::Hello { fleet: cfg.fleet.clone(), protocol: coadapt_grpc::PROTOCOL, role: pb::Role::Actor as i32, actor_id: 3, session };
        assert_eq!(c.register(hello).await.expect("register").into_inner().run_id, B);
        let register_first = |s: Status| {
            assert_eq!(s.code(), tonic::Code::FailedPrecondition, "{s:?}");
            assert!(s.metadata().get("coadapt-register").is_some(), "{s:?}");
        };

        // A poll acknowledging start A's delivery 7 is refused; start B's numbering is its own.
        let poll = |run_id, received| pb::Poll { session, received, wait_ms: 0, leaving: false, run_id };
        register_first(c.next_assignment(poll(A, 7)).await.expect_err("another start's acknowledgement"));
        let d = c.next_assignment(poll(B, 0)).await.expect("poll");
        assert_eq!(d.metadata().get("coadapt-run").and_then(|v| v.to_str().ok()), Some(B.to_string().as_str()));
        assert_eq!(d.into_inner().seq, 1);

        let beat = |run_id| pb::Beat { session, role: pb::Role::Actor as i32, actor_id: 3, weights_version: 9, leaving: false, run_id };
        register_first(c.heartbeat(beat(A)).await.expect_err("another start's heartbeat"));
        assert_eq!(c.heartbeat(beat(B)).await.expect("beat").into_inner().run_id, B);

        // A stream of start A's frames is refused before any frame counts.
        let frame = pb::ExperienceFrame { sender: 5, seq: 1, chunk: Some(coadapt_wire::Wire::to_pb(&chunk(1))), fin: false };
        let mut req = Request::new(tokio_stream::iter(vec![frame]));
        req.metadata_mut().insert("coadapt-session", session.into());
        req.metadata_mut().insert("coadapt-run", A.into());
        match c.push_experience(req).await {
            Err(s) => register_first(s),
            Ok(r) => register_first(r.into_inner().message().await.expect_err("another start's frames")),
        }

        // Start A's version 5 says nothing about start B's: B sends its newest, version 2.
        let watch = |run_id| pb::WatchRequest { topic: pb::WeightsTopic::Acting as i32, min_version: 6, run_id };
        let mut s = c.watch_weights(watch(A)).await.expect("watch").into_inner();
        assert_eq!(s.message().await.expect("update").expect("one").weights.map(|w| w.version), Some(2));
        let mut s = c.watch_weights(watch(B)).await.expect("watch").into_inner();
        assert!(s.message().await.expect("update").expect("one").weights.is_none(), "only a keep-alive: B's own version 6 is not out");
    });
    assert_eq!(learner.experience.recv_timeout(Duration::from_millis(200)).expect("recv"), None);
    assert_eq!(server.refusals().other_run, 3);
}
