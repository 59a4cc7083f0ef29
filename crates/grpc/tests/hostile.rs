//! Hostile and broken peers: raw tonic clients (built from the generated types, not our client)
//! that take others' work, invent sessions, poison sequence numbers, flood the learner's queue,
//! keep episodes alive with empty chunks, or lie about episode lengths. Each test names the
//! attack it stops.

mod common;

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use coadapt_grpc::{GrpcConfig, LearnerLinks};
use coadapt_transport::{Assignment, DesignKind, DesignRequest, EpisodeEnd, EpisodeMode, ExperienceChunk};
use coadapt_wire::Wire;
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;
use tokio::runtime::Runtime;
use tonic::transport::Channel;
use tonic::{Code, Status};

/// The request metadata that names the session of a push stream.
const SESSION_HEADER: &str = "coadapt-session";

fn rt() -> &'static Runtime {
    static RT: OnceLock<Runtime> = OnceLock::new();
    RT.get_or_init(|| tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().expect("runtime"))
}

/// Every acknowledgement of a push stream until it ends, and the error that ended it (a stream
/// that says nothing for 5 s ends with DEADLINE_EXCEEDED).
async fn acks(opened: Result<tonic::Response<tonic::Streaming<pb::Ack>>, Status>) -> (Vec<u64>, Option<Status>) {
    let mut acks = match opened {
        Ok(r) => r.into_inner(),
        Err(s) => return (Vec::new(), Some(s)),
    };
    let mut got = Vec::new();
    loop {
        match tokio::time::timeout(Duration::from_secs(5), acks.message()).await {
            Ok(Ok(Some(a))) => got.push(a.acked),
            Ok(Ok(None)) => return (got, None),
            Ok(Err(s)) => return (got, Some(s)),
            Err(_) => return (got, Some(Status::deadline_exceeded("no answer in 5 s"))),
        }
    }
}

/// A raw client on a connection of its own, presenting `session` in every call.
struct Peer {
    client: FleetClient<Channel>,
    session: u64,
    role: pb::Role,
    actor_id: u64,
}

impl Peer {
    /// Connects without registering.
    fn unregistered(endpoint: &str, session: u64, role: pb::Role, actor_id: u64) -> Self {
        let endpoint = endpoint.to_string();
        let client = rt().block_on(async move { FleetClient::connect(endpoint).await.expect("connect") });
        Self { client, session, role, actor_id }
    }

    /// Connects and registers.
    fn new(endpoint: &str, session: u64, role: pb::Role, actor_id: u64) -> Self {
        let p = Self::unregistered(endpoint, session, role, actor_id);
        p.register().expect("register");
        p
    }

    fn register(&self) -> Result<pb::Welcome, Status> {
        let mut c = self.client.clone();
        let hello = pb::Hello {
            fleet: GrpcConfig::default().fleet,
            protocol: coadapt_grpc::PROTOCOL,
            role: self.role as i32,
            actor_id: self.actor_id,
            session: self.session,
        };
        rt().block_on(async move { c.register(hello).await.map(|r| r.into_inner()) })
    }

    fn beat(&self, role: pb::Role, leaving: bool) -> Result<pb::BeatReply, Status> {
        let mut c = self.client.clone();
        let beat = pb::Beat { session: self.session, role: role as i32, actor_id: self.actor_id, weights_version: 0, leaving, run_id: 0 };
        rt().block_on(async move { c.heartbeat(beat).await.map(|r| r.into_inner()) })
    }

    fn poll(&self, wait_ms: u32, received: u64, leaving: bool) -> pb::Poll {
        pb::Poll { session: self.session, received, wait_ms, leaving, run_id: 0 }
    }

    fn next_assignment(&self, wait_ms: u32, received: u64, leaving: bool) -> Result<pb::AssignmentDelivery, Status> {
        let mut c = self.client.clone();
        let poll = self.poll(wait_ms, received, leaving);
        rt().block_on(async move { c.next_assignment(poll).await.map(|r| r.into_inner()) })
    }

    fn next_design_request(&self, wait_ms: u32, received: u64, leaving: bool) -> Result<pb::DesignRequestDelivery, Status> {
        let mut c = self.client.clone();
        let poll = self.poll(wait_ms, received, leaving);
        rt().block_on(async move { c.next_design_request(poll).await.map(|r| r.into_inner()) })
    }

    fn with_session<T>(&self, body: T) -> tonic::Request<T> {
        let mut req = tonic::Request::new(body);
        req.metadata_mut().insert(SESSION_HEADER, self.session.to_string().parse().expect("ascii"));
        req
    }

    /// Streams `frames` on one PushExperience call and half-closes; returns every
    /// acknowledgement and the error that ended the stream, if one did.
    fn push(&self, frames: Vec<pb::ExperienceFrame>) -> (Vec<u64>, Option<Status>) {
        let mut c = self.client.clone();
        let req = self.with_session(tokio_stream::iter(frames));
        rt().block_on(async move { acks(c.push_experience(req).await).await })
    }

    fn push_replies(&self, frames: Vec<pb::DesignReplyFrame>) -> (Vec<u64>, Option<Status>) {
        let mut c = self.client.clone();
        let req = self.with_session(tokio_stream::iter(frames));
        rt().block_on(async move { acks(c.push_design_replies(req).await).await })
    }
}

fn assignment(id: u64, mode: EpisodeMode) -> Assignment {
    Assignment { id, design_index: 0, design: vec![1.0, 2.0], mode, seed: id, min_weights_version: 0 }
}

/// `rows` transitions of `assignment` (obs 3, act 2); `end` closes the episode with that length.
fn transitions(assignment: u64, rows: usize, first: bool, end: Option<u64>) -> pb::ExperienceChunk {
    ExperienceChunk {
        actor: 1,
        assignment,
        design_index: 0,
        weights_version: 0,
        first,
        obs: vec![0.5; rows * 3],
        actions: vec![0.25; rows * 2],
        rewards: vec![1.0; rows],
        next_obs: vec![0.5; rows * 3],
        terminated: vec![false; rows],
        end: end.map(|length| EpisodeEnd { episode_return: 1.0, length }),
    }
    .to_pb()
}

fn frame(sender: u64, seq: u64, chunk: pb::ExperienceChunk) -> pb::ExperienceFrame {
    pb::ExperienceFrame { sender, seq, chunk: Some(chunk), fin: false }
}

/// Everything the learner receives until it has been quiet for `quiet`.
fn drain(learner: &mut LearnerLinks, quiet: Duration) -> Vec<ExperienceChunk> {
    let mut got = Vec::new();
    while let Some(c) = learner.experience.recv_timeout(quiet).expect("recv") {
        got.push(c);
    }
    got
}

/// The stream must have ended with one of `codes`, its message naming `word`.
#[track_caller]
fn refused(what: &str, answer: (Vec<u64>, Option<Status>), codes: &[Code], word: &str) {
    let (acks, status) = answer;
    let Some(status) = status else { panic!("{what}: accepted (acks {acks:?}), expected a refusal") };
    assert!(codes.contains(&status.code()), "{what}: {:?} {:?}, expected one of {codes:?}", status.code(), status.message());
    assert!(status.message().contains(word), "{what}: {:?} does not name {word:?}", status.message());
}

#[track_caller]
fn refused_call<T: std::fmt::Debug>(what: &str, answer: Result<T, Status>, codes: &[Code], word: &str) {
    match answer {
        Ok(x) => panic!("{what}: accepted ({x:?}), expected a refusal"),
        Err(s) => {
            assert!(codes.contains(&s.code()), "{what}: {:?} {:?}, expected one of {codes:?}", s.code(), s.message());
            assert!(s.message().contains(word), "{what}: {:?} does not name {word:?}", s.message());
        }
    }
}

const DENIED: &[Code] = &[Code::PermissionDenied, Code::FailedPrecondition];

/// Attack 1: Experience for an assignment is accepted only from the session it was handed to.
#[test]
fn another_sessions_assignment_cannot_be_completed() {
    let (mut learner, server, endpoint) = common::learner();
    let holder = Peer::new(&endpoint, 0xA11CE, pb::Role::Actor, 1);
    let thief = Peer::new(&endpoint, 0xBAD, pb::Role::Actor, 2);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    let d = holder.next_assignment(1000, 0, false).expect("poll");
    assert_eq!(d.assignment.map(|a| a.id), Some(1));

    // A whole episode (start state, transitions, end) for assignment 1 from another session.
    let answer = thief.push(vec![frame(77, 1, transitions(1, 3, true, Some(3)))]);
    refused("the thief's episode", answer, DENIED, "assignment");
    assert!(drain(&mut learner, Duration::from_millis(300)).is_empty(), "the thief's chunk reached the learner");

    // The holder's own episode passes.
    let (acks, status) = holder.push(vec![frame(5, 1, transitions(1, 3, true, Some(3)))]);
    assert_eq!((acks, status.map(|s| s.code())), (vec![1], None));
    assert_eq!(drain(&mut learner, Duration::from_millis(300)).len(), 1);
    assert_eq!(server.refusals().foreign_assignment, 1);
}

/// Attack 2: Start states cannot be injected for an assignment one does not hold: not while it
/// waits to be handed out, nor by queueing chunks before the learner issues it.
#[test]
fn start_states_cannot_be_injected() {
    let (mut learner, server, endpoint) = common::learner();
    let thief = Peer::new(&endpoint, 0xBAD, pb::Role::Actor, 2);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    let answer = thief.push(vec![frame(77, 1, transitions(1, 1, true, None))]);
    refused("a start state for an assignment nobody holds yet", answer, DENIED, "assignment");

    // Sequential ids are guessable: chunks for the next one, queued before it is issued.
    let (acks, _) = thief.push(vec![frame(78, 1, transitions(2, 1, true, None))]);
    assert_eq!(acks, vec![1], "an assignment the learner never issued is the learner's to ignore");
    learner.assignments.send(assignment(2, EpisodeMode::Train)).expect("send");
    assert!(
        drain(&mut learner, Duration::from_millis(300)).iter().all(|c| c.assignment != 2),
        "a start state queued before assignment 2 was issued reached the learner after it was"
    );
    assert_eq!(server.refusals().purged, 1);
}

/// Attack 3: Work, heartbeats and queues need a registered session.
#[test]
fn sessions_that_never_registered_get_nothing() {
    let (mut learner, server, endpoint) = common::learner();
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    let req = DesignRequest {
        index: 0,
        kind: DesignKind::Explore,
        weights_version: 0,
        start_states: vec![0.5; 3],
        chosen: Vec::new(),
        rejected: Vec::new(),
    };
    learner.design_requests.send(req).expect("send");

    let ghost = Peer::unregistered(&endpoint, 0x6057, pb::Role::Actor, 9);
    refused_call("an assignment for an invented session", ghost.next_assignment(300, 0, false), &[Code::FailedPrecondition], "register");
    refused_call(
        "a design request for an invented session",
        ghost.next_design_request(300, 0, false),
        &[Code::FailedPrecondition],
        "register",
    );
    refused_call("a heartbeat of an invented session", ghost.beat(pb::Role::Actor, false), &[Code::FailedPrecondition], "register");
    let answer = ghost.push(vec![frame(1, 1, transitions(9, 1, false, None))]);
    refused("experience of an invented session", answer, &[Code::FailedPrecondition], "register");
    let reply = pb::DesignReply { index: 0, design: vec![1.0, 2.0], method: "x".into(), predicted_objective: None, design_rollouts: 0 };
    let answer = ghost.push_replies(vec![pb::DesignReplyFrame { sender: 1, seq: 1, reply: Some(reply), fin: false }]);
    refused("a design reply of an invented session", answer, &[Code::FailedPrecondition], "register");
    assert!(drain(&mut learner, Duration::from_millis(200)).is_empty());
    assert!(server.clients().is_empty(), "a ghost is listed: {:?}", server.clients());

    // The work is still there for registered clients.
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    let opt = Peer::new(&endpoint, 0x097, pb::Role::Optimizer, 0);
    assert_eq!(opt.next_design_request(1000, 0, false).expect("poll").request.map(|r| r.index), Some(0));
    assert!(server.refusals().unregistered >= 5);
}

/// Attack 4: A sender id belongs to the session that used it first: another session's frame
/// with seq u64::MAX does not turn the owner's next frames into "duplicates".
#[test]
fn a_sender_cannot_be_poisoned_by_another_session() {
    let (mut learner, server, endpoint) = common::learner();
    let owner = Peer::new(&endpoint, 0x0111, pb::Role::Actor, 1);
    let thief = Peer::new(&endpoint, 0xBAD, pb::Role::Actor, 2);
    assert_eq!(owner.push(vec![frame(42, 1, transitions(100, 1, false, None))]).0, vec![1]);
    refused(
        "a frame under another session's sender id",
        thief.push(vec![frame(42, u64::MAX, transitions(101, 1, false, None))]),
        DENIED,
        "sender",
    );
    assert_eq!(owner.push(vec![frame(42, 2, transitions(102, 1, false, None))]).0, vec![2]);
    let got: Vec<u64> = drain(&mut learner, Duration::from_millis(300)).iter().map(|c| c.assignment).collect();
    assert_eq!(got, vec![100, 102], "the owner's second frame was lost");
    assert_eq!(server.refusals().foreign_sender, 1);
}

/// Attack 4: A sequence number far beyond the send window is refused, naming `seq`.
#[test]
fn sequence_jumps_beyond_the_window_are_refused() {
    let cfg = common::cfg();
    let (mut learner, server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0x0111, pb::Role::Actor, 1);
    assert_eq!(actor.push(vec![frame(43, 1, transitions(100, 1, false, None))]).0, vec![1]);
    let jump = 1 + cfg.send_window as u64 + 1;
    refused("a jump past the window", actor.push(vec![frame(43, jump, transitions(101, 1, false, None))]), &[Code::InvalidArgument], "seq");
    assert_eq!(actor.push(vec![frame(43, 2, transitions(102, 1, false, None))]).0, vec![2]);
    let got: Vec<u64> = drain(&mut learner, Duration::from_millis(300)).iter().map(|c| c.assignment).collect();
    assert_eq!(got, vec![100, 102]);
    assert_eq!(server.refusals().seq_jump, 1);
}

/// Attack 5: Leaving is for the session itself: an unregistered session, or a session presented
/// with the other role, neither leaves nor hands back work.
#[test]
fn only_a_session_itself_can_leave() {
    let (mut learner, server, endpoint) = common::learner();
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    actor.beat(pb::Role::Actor, false).expect("beat");

    let ghost = Peer::unregistered(&endpoint, 0x6057, pb::Role::Actor, 1);
    refused_call("Poll{leaving} of an invented session", ghost.next_assignment(0, 0, true), &[Code::FailedPrecondition], "register");
    refused_call("Beat{leaving} of an invented session", ghost.beat(pb::Role::Actor, true), &[Code::FailedPrecondition], "register");
    // The actor's session with the optimiser's role.
    let imposter = Peer::unregistered(&endpoint, 0xAC7, pb::Role::Optimizer, 1);
    refused_call("Beat{leaving} with the wrong role", imposter.beat(pb::Role::Optimizer, true), DENIED, "role");
    refused_call("a design request poll of an actor's session", imposter.next_design_request(0, 0, true), DENIED, "role");

    assert!(server.actors().iter().all(|a| a.alive), "the actor was made to leave: {:?}", server.actors());
    let other = Peer::new(&endpoint, 0x07E, pb::Role::Actor, 2);
    assert_eq!(other.next_assignment(300, 0, false).expect("poll").assignment, None, "the actor's assignment was handed back");
    assert!(server.refusals().wrong_role >= 2);
}

/// Not an attack, a crash (issue 29): an optimiser killed while it searches holds the design
/// request unconfirmed. The optimiser restarted in its place (a new session) gets that request
/// at its first poll, not after the learner's resend deadline nor after the dead session is
/// forgotten; and it gets it once.
#[test]
fn a_new_optimiser_gets_the_request_a_dead_one_had_taken() {
    let (mut learner, _server, endpoint) = common::learner();
    let req = DesignRequest {
        index: 5,
        kind: DesignKind::Exploit,
        weights_version: 3,
        start_states: vec![0.5; 3],
        chosen: vec![1.0; 3],
        rejected: Vec::new(),
    };
    learner.design_requests.send(req).expect("send");
    let dead = Peer::new(&endpoint, 0x0DEAD, pb::Role::Optimizer, 0);
    let got = dead.next_design_request(1000, 0, false).expect("poll");
    assert_eq!(got.request.as_ref().map(|r| r.index), Some(5));
    // It never polls again (killed mid-search); its successor registers and asks.
    let t = Instant::now();
    let next = Peer::new(&endpoint, 0x0A11CE, pb::Role::Optimizer, 0);
    let got = next.next_design_request(5000, 0, false).expect("poll");
    assert_eq!(got.request.as_ref().map(|r| (r.index, r.weights_version)), Some((5, 3)), "{got:?}");
    assert!(t.elapsed() < Duration::from_secs(2), "waited {:?} for the request", t.elapsed());
    // Confirmed by the new one (it asks for the next): the copy was one item, not two.
    assert_eq!(next.next_design_request(300, got.seq, false).expect("poll").request, None);
}

/// Attack 6: Empty chunks (no transition, no end) reach the learner at most once per heartbeat
/// per episode, so they cannot be used to flood it; the episode's end still passes.
#[test]
fn empty_chunks_pass_at_most_once_per_heartbeat() {
    let cfg = common::cfg();
    let (mut learner, server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    learner.assignments.send(assignment(1, EpisodeMode::Eval)).expect("send");
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    let n = 50;
    let t = Instant::now();
    let (acks, status) = actor.push((1..=n).map(|seq| frame(7, seq, transitions(1, 0, false, None))).collect());
    let took = t.elapsed();
    assert_eq!((acks.len(), status.map(|s| s.code())), (n as usize, None), "empty chunks are acknowledged");
    let passed = drain(&mut learner, Duration::from_millis(200)).len();
    let allowed = 2 + (took.as_secs_f64() / cfg.heartbeat.as_secs_f64()) as usize;
    assert!(passed <= allowed, "{passed} of {n} empty chunks reached the learner in {took:?} (at most {allowed})");
    let (acks, _) = actor.push(vec![frame(7, n + 1, transitions(1, 0, false, Some(1000)))]);
    assert_eq!(acks, vec![n + 1]);
    let end = drain(&mut learner, Duration::from_millis(300));
    assert!(end.iter().any(|c| c.end.is_some()), "the episode's end did not pass");
    assert!(server.refusals().empty_dropped >= n - allowed as u64);
}

/// Attack 7: The learner's queue holds at most `inbox_max_bytes` of experience: beyond it,
/// frames wait unacknowledged until the learner takes some.
#[test]
fn the_inbox_holds_at_most_its_byte_cap() {
    let cfg = GrpcConfig { inbox_max_bytes: 64 << 10, ..common::cfg() };
    let (mut learner, _server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    let rows = 1000; // about 37 kB a chunk
    let n = 20u64;
    let (tx, rx) = tokio::sync::mpsc::channel(n as usize);
    for seq in 1..=n {
        tx.try_send(frame(8, seq, transitions(1000 + seq, rows, false, None))).expect("queue");
    }
    let req = actor.with_session(tokio_stream::wrappers::ReceiverStream::new(rx));
    let mut c = actor.client.clone();
    let mut acks = rt().block_on(async move { c.push_experience(req).await }).expect("open").into_inner();
    let read_acks = |acks: &mut tonic::Streaming<pb::Ack>, for_: Duration| {
        rt().block_on(async {
            let mut top = 0;
            let until = tokio::time::Instant::now() + for_;
            while let Ok(Ok(Some(a))) = tokio::time::timeout_at(until, acks.message()).await {
                top = top.max(a.acked);
            }
            top
        })
    };
    let held = read_acks(&mut acks, Duration::from_millis(800));
    assert!(held <= 3, "the learner's queue took {held} chunks of about 37 kB with a 64 KiB cap");
    for i in 1..=n {
        let c = learner.experience.recv_timeout(Duration::from_secs(10)).expect("recv").expect("a chunk");
        assert_eq!(c.assignment, 1000 + i);
    }
    assert_eq!(read_acks(&mut acks, Duration::from_millis(500)), n, "every chunk acknowledged once taken");
    drop(tx);
}

/// Attack 8: At most `max_sessions` sessions; silent ones are forgotten and make room.
#[test]
fn sessions_are_capped_and_silent_ones_forgotten() {
    let cfg = GrpcConfig { max_sessions: 8, session_idle_timeout: Duration::from_millis(300), ..common::cfg() };
    let (_learner, server, endpoint) = common::learner_with(&cfg);
    let peers: Vec<Peer> = (0..8).map(|i| Peer::new(&endpoint, 0x5E55 + i, pb::Role::Actor, i)).collect();
    peers[0].register().expect("registering again is not a new session");
    let late = Peer::unregistered(&endpoint, 0x1A7E, pb::Role::Actor, 100);
    refused_call("a session beyond the cap", late.register(), &[Code::ResourceExhausted], "sessions");
    assert_eq!(server.clients().len(), 8);
    std::thread::sleep(Duration::from_millis(900));
    assert!(server.clients().is_empty(), "silent sessions kept: {}", server.clients().len());
    refused_call("a forgotten session", peers[1].next_assignment(0, 0, false), &[Code::FailedPrecondition], "register");
    late.register().expect("room again");
    assert_eq!(server.refusals().sessions_full, 1);
}

/// Attack 9: A connection has at most `max_concurrent_streams` calls open at once.
#[test]
fn streams_per_connection_are_limited() {
    let cfg = GrpcConfig { max_concurrent_streams: 4, rpc_timeout: Duration::from_secs(3), ..common::cfg() };
    let (_learner, _server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    let polls: Vec<_> = (0..4)
        .map(|_| {
            let mut c = actor.client.clone();
            let poll = actor.poll(1500, 0, false);
            rt().spawn(async move { c.next_assignment(poll).await.map(|r| r.into_inner()) })
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    let mut c = actor.client.clone();
    let beat =
        pb::Beat { session: actor.session, role: pb::Role::Actor as i32, actor_id: 1, weights_version: 0, leaving: false, run_id: 0 };
    let fifth = rt().block_on(async move { tokio::time::timeout(Duration::from_millis(400), c.heartbeat(beat)).await });
    assert!(fifth.is_err(), "a fifth call ran beside four open ones on one connection: {fifth:?}");
    for p in polls {
        rt().block_on(p).expect("join").expect("the long polls end normally");
    }
    actor.beat(pb::Role::Actor, false).expect("room again");
}

/// Attack 10: `EpisodeEnd.length` must match what was streamed, and stay below the longest
/// episode.
#[test]
fn episode_lengths_are_checked() {
    let (mut learner, server, endpoint) = common::learner();
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    assert_eq!(actor.push(vec![frame(9, 1, transitions(1, 2, true, None))]).0, vec![1]);
    refused(
        "length u64::MAX",
        actor.push(vec![frame(9, 2, transitions(1, 1, false, Some(u64::MAX)))]),
        &[Code::InvalidArgument],
        "end.length",
    );
    refused(
        "length 7 for 3 transitions",
        actor.push(vec![frame(9, 2, transitions(1, 1, false, Some(7)))]),
        &[Code::InvalidArgument],
        "end.length",
    );
    assert_eq!(actor.push(vec![frame(9, 2, transitions(1, 1, false, Some(3)))]).0, vec![2]);
    let got = drain(&mut learner, Duration::from_millis(300));
    assert_eq!(got.iter().map(|c| c.len()).collect::<Vec<_>>(), vec![2, 1]);
    assert_eq!(got[1].end.map(|e| e.length), Some(3));
    // An assignment this learner never issued: still no more than the longest episode.
    let too_long = GrpcConfig::default().max_episode_steps + 1;
    refused(
        "an endless episode",
        actor.push(vec![frame(9, 3, transitions(500, 1, false, Some(too_long)))]),
        &[Code::InvalidArgument],
        "end.length",
    );
    assert_eq!(server.refusals().bad_length, 3);
}

/// What honest actors do (our client, as `actors::role` drives it) passes every check: a
/// training episode restarted from its first step, and an evaluation episode that sends empty
/// chunks for liveness, then its end.
#[test]
fn honest_actors_pass_every_check() {
    let (mut learner, server, endpoint) = common::learner();
    let mut actor = coadapt_grpc::actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    learner.assignments.send(assignment(2, EpisodeMode::Eval)).expect("send");
    let long = Duration::from_secs(10);
    let chunk =
        |a: u64, rows: usize, first: bool, end: Option<u64>| ExperienceChunk::from_pb(transitions(a, rows, first, end)).expect("chunk");
    assert_eq!(actor.assignments.recv_timeout(long).expect("recv").map(|a| a.id), Some(1));
    // A failed attempt, then the whole episode again from its start.
    actor.experience.send(chunk(1, 4, true, None)).expect("send");
    actor.experience.send(chunk(1, 3, true, None)).expect("send");
    actor.experience.send(chunk(1, 2, false, None)).expect("send");
    actor.experience.send(chunk(1, 0, false, Some(5))).expect("send");
    assert_eq!(actor.assignments.recv_timeout(long).expect("recv").map(|a| a.id), Some(2));
    for _ in 0..5 {
        actor.experience.send(chunk(2, 0, false, None)).expect("send");
    }
    actor.experience.send(chunk(2, 0, false, Some(40))).expect("send");
    let mut got = Vec::new();
    while got.iter().filter(|c: &&ExperienceChunk| c.end.is_some()).count() < 2 {
        got.push(learner.experience.recv_timeout(long).expect("recv").expect("a chunk"));
    }
    let train: Vec<usize> = got.iter().filter(|c| c.assignment == 1).map(|c| c.len()).collect();
    assert_eq!(train, vec![4, 3, 2, 0]);
    assert!(got.iter().filter(|c| c.assignment == 2).count() >= 2, "liveness and the end of the evaluation");
    let r = server.refusals();
    assert_eq!(coadapt_grpc::Refusals { empty_dropped: r.empty_dropped, ..Default::default() }, r, "an honest actor was refused");
}

/// A chunk of an assignment the learner gave to someone else (a late chunk of a predecessor
/// learner's episode whose id was issued again) is refused; our client drops that chunk and
/// its sender goes on working.
#[test]
fn a_refused_chunk_does_not_end_an_honest_sender() {
    let (mut learner, server, endpoint) = common::learner();
    let other = Peer::new(&endpoint, 0x07E, pb::Role::Actor, 2);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    assert_eq!(other.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    let mut actor = coadapt_grpc::actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    let chunk = |a: u64| ExperienceChunk::from_pb(transitions(a, 1, false, None)).expect("chunk");
    actor.experience.send(chunk(1)).expect("queued");
    actor.experience.send(chunk(50)).expect("queued");
    let got = learner.experience.recv_timeout(Duration::from_secs(10)).expect("recv").expect("a chunk");
    assert_eq!(got.assignment, 50, "the refused chunk was delivered, or the next one lost");
    actor.experience.send(chunk(51)).expect("the sender still works");
    assert_eq!(learner.experience.recv_timeout(Duration::from_secs(10)).expect("recv").map(|c| c.assignment), Some(51));
    assert_eq!(server.refusals().foreign_assignment, 1);
}

/// A restarted learner knows no session: our clients register again (same session) and go on,
/// the optimiser's replies included (those sent once it knows the new start: what it sent for
/// the old start is dropped, see run_id.rs).
#[test]
fn clients_register_again_with_a_restarted_learner() {
    let cfg = common::cfg();
    let (learner, server, endpoint) = common::learner();
    let addr = server.local_addr();
    let mut opt = coadapt_grpc::optimizer_links(&endpoint, &cfg).expect("optimizer");
    drop(server);
    drop(learner);
    let (mut learner, server) = coadapt_grpc::serve_learner(addr, &cfg).expect("a new learner on the same port");
    let t = Instant::now();
    while !server.clients().iter().any(|c| c.role == coadapt_grpc::ClientRole::Optimizer) {
        assert!(t.elapsed() < Duration::from_secs(10), "the optimiser did not register again");
        std::thread::sleep(Duration::from_millis(20));
    }
    // Its heartbeat has read the answer (and so the new run id).
    std::thread::sleep(Duration::from_millis(300));
    let reply = coadapt_transport::DesignReply {
        index: 0,
        design: vec![1.0, 2.0],
        method: "pso-q".into(),
        predicted_objective: None,
        design_rollouts: 0,
    };
    opt.replies.send(reply.clone()).expect("send");
    assert_eq!(learner.design_replies.recv_timeout(Duration::from_secs(10)).expect("recv"), Some(reply));
    assert!(server.clients().iter().any(|c| c.role == coadapt_grpc::ClientRole::Optimizer), "the optimiser registered again");
    // Whether a call reached the new learner under the old session first (refused as
    // unregistered) or the client registered as soon as its connection broke is a race; both
    // are right, so `refusals().unregistered` is not asserted (it made this test fail 1 run in 7).
}

/// Registers over a connection of its own, or says why not (the connection refused).
fn try_connect_and_register(endpoint: &str, session: u64) -> Result<Peer, String> {
    let e = endpoint.to_string();
    let client = rt()
        .block_on(async move { tokio::time::timeout(Duration::from_secs(3), FleetClient::connect(e)).await })
        .map_err(|_| "connect timed out".to_string())?
        .map_err(|e| format!("connect: {e}"))?;
    let p = Peer { client, session, role: pb::Role::Actor, actor_id: session };
    p.register().map_err(|s| format!("register: {:?} {}", s.code(), s.message()))?;
    Ok(p)
}

/// Attack 13: One host opens connections until the learner runs out of descriptors (tonic has
/// no limit of its own): beyond `max_connections_per_peer` from one address, and beyond
/// `max_connections` in all, a connection is closed as it is accepted and counted; a closed
/// connection gives its place back.
#[test]
fn connections_per_peer_and_in_all_are_limited() {
    let cfg = GrpcConfig { max_connections_per_peer: 3, ..common::cfg() };
    let (_learner, server, endpoint) = common::learner_with(&cfg);
    let mut held: Vec<Peer> = (0..3).map(|i| try_connect_and_register(&endpoint, 0x100 + i).expect("within the limit")).collect();
    let fourth = try_connect_and_register(&endpoint, 0x200);
    assert!(fourth.is_err(), "a fourth connection from one host was served");
    assert!(server.refusals().connections_per_peer >= 1, "{:?}", server.refusals());
    // The three already accepted still work.
    for p in &held {
        p.beat(pb::Role::Actor, false).expect("an accepted connection keeps working");
    }
    drop(held.pop());
    let deadline = Instant::now() + Duration::from_secs(5);
    let again = loop {
        match try_connect_and_register(&endpoint, 0x300) {
            Ok(p) => break p,
            Err(e) if Instant::now() > deadline => panic!("no room after a connection closed: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    };
    again.beat(pb::Role::Actor, false).expect("works");

    let cfg = GrpcConfig { max_connections: 2, ..common::cfg() };
    let (_learner, server, endpoint) = common::learner_with(&cfg);
    let _two: Vec<Peer> = (0..2).map(|i| try_connect_and_register(&endpoint, 0x400 + i).expect("within the limit")).collect();
    assert!(try_connect_and_register(&endpoint, 0x500).is_err(), "a third connection was served with max_connections = 2");
    assert!(server.refusals().connections_total >= 1, "{:?}", server.refusals());
}
