//! What every hostile test uses: raw peers, frames and chunks, and how a refusal reads.

pub(crate) use crate::common;
pub use std::sync::OnceLock;
pub use std::time::{Duration, Instant};

pub use coadapt_grpc::{GrpcConfig, LearnerLinks};
pub use coadapt_transport::{Assignment, DesignKind, DesignRequest, EpisodeEnd, EpisodeMode, ExperienceChunk};
pub use coadapt_wire::Wire;
pub use coadapt_wire::pb;
pub use coadapt_wire::pb::fleet_client::FleetClient;
pub use tokio::runtime::Runtime;
pub use tonic::transport::Channel;
pub use tonic::{Code, Status};

/// The request metadata that names the session of a push stream.
pub const SESSION_HEADER: &str = "coadapt-session";

pub fn rt() -> &'static Runtime {
    static RT: OnceLock<Runtime> = OnceLock::new();
    RT.get_or_init(|| tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().expect("runtime"))
}

/// Every acknowledgement of a push stream until it ends, and the error that ended it (a stream
/// that says nothing for 5 s ends with DEADLINE_EXCEEDED).
pub async fn acks(opened: Result<tonic::Response<tonic::Streaming<pb::Ack>>, Status>) -> (Vec<u64>, Option<Status>) {
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
pub struct Peer {
    pub client: FleetClient<Channel>,
    pub session: u64,
    pub role: pb::Role,
    pub actor_id: u64,
}

impl Peer {
    /// Connects without registering.
    pub fn unregistered(endpoint: &str, session: u64, role: pb::Role, actor_id: u64) -> Self {
        let endpoint = endpoint.to_string();
        let client = rt().block_on(async move { FleetClient::connect(endpoint).await.expect("connect") });
        Self { client, session, role, actor_id }
    }

    /// Connects and registers.
    pub fn new(endpoint: &str, session: u64, role: pb::Role, actor_id: u64) -> Self {
        let p = Self::unregistered(endpoint, session, role, actor_id);
        p.register().expect("register");
        p
    }

    pub fn register(&self) -> Result<pb::Welcome, Status> {
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

    pub fn beat(&self, role: pb::Role, leaving: bool) -> Result<pb::BeatReply, Status> {
        let mut c = self.client.clone();
        let beat = pb::Beat { session: self.session, role: role as i32, actor_id: self.actor_id, weights_version: 0, leaving, run_id: 0 };
        rt().block_on(async move { c.heartbeat(beat).await.map(|r| r.into_inner()) })
    }

    pub fn poll(&self, wait_ms: u32, received: u64, leaving: bool) -> pb::Poll {
        pb::Poll { session: self.session, received, wait_ms, leaving, run_id: 0 }
    }

    pub fn next_assignment(&self, wait_ms: u32, received: u64, leaving: bool) -> Result<pb::AssignmentDelivery, Status> {
        let mut c = self.client.clone();
        let poll = self.poll(wait_ms, received, leaving);
        rt().block_on(async move { c.next_assignment(poll).await.map(|r| r.into_inner()) })
    }

    pub fn next_design_request(&self, wait_ms: u32, received: u64, leaving: bool) -> Result<pb::DesignRequestDelivery, Status> {
        let mut c = self.client.clone();
        let poll = self.poll(wait_ms, received, leaving);
        rt().block_on(async move { c.next_design_request(poll).await.map(|r| r.into_inner()) })
    }

    pub fn with_session<T>(&self, body: T) -> tonic::Request<T> {
        let mut req = tonic::Request::new(body);
        req.metadata_mut().insert(SESSION_HEADER, self.session.to_string().parse().expect("ascii"));
        req
    }

    /// Streams `frames` on one PushExperience call and half-closes; returns every
    /// acknowledgement and the error that ended the stream, if one did.
    pub fn push(&self, frames: Vec<pb::ExperienceFrame>) -> (Vec<u64>, Option<Status>) {
        let mut c = self.client.clone();
        let req = self.with_session(tokio_stream::iter(frames));
        rt().block_on(async move { acks(c.push_experience(req).await).await })
    }

    pub fn push_replies(&self, frames: Vec<pb::DesignReplyFrame>) -> (Vec<u64>, Option<Status>) {
        let mut c = self.client.clone();
        let req = self.with_session(tokio_stream::iter(frames));
        rt().block_on(async move { acks(c.push_design_replies(req).await).await })
    }
}

pub fn assignment(id: u64, mode: EpisodeMode) -> Assignment {
    Assignment { id, design_index: 0, design: vec![1.0, 2.0], mode, seed: id, min_weights_version: 0 }
}

/// `rows` transitions of `assignment` (obs 3, act 2); `end` closes the episode with that length.
pub fn transitions(assignment: u64, rows: usize, first: bool, end: Option<u64>) -> pb::ExperienceChunk {
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

pub fn frame(sender: u64, seq: u64, chunk: pb::ExperienceChunk) -> pb::ExperienceFrame {
    pb::ExperienceFrame { sender, seq, chunk: Some(chunk), fin: false }
}

/// Everything the learner receives until it has been quiet for `quiet`.
pub fn drain(learner: &mut LearnerLinks, quiet: Duration) -> Vec<ExperienceChunk> {
    let mut got = Vec::new();
    while let Some(c) = learner.experience.recv_timeout(quiet).expect("recv") {
        got.push(c);
    }
    got
}

/// The stream must have ended with one of `codes`, its message naming `word`.
#[track_caller]
pub fn refused(what: &str, answer: (Vec<u64>, Option<Status>), codes: &[Code], word: &str) {
    let (acks, status) = answer;
    let Some(status) = status else { panic!("{what}: accepted (acks {acks:?}), expected a refusal") };
    assert!(codes.contains(&status.code()), "{what}: {:?} {:?}, expected one of {codes:?}", status.code(), status.message());
    assert!(status.message().contains(word), "{what}: {:?} does not name {word:?}", status.message());
}

#[track_caller]
pub fn refused_call<T: std::fmt::Debug>(what: &str, answer: Result<T, Status>, codes: &[Code], word: &str) {
    match answer {
        Ok(x) => panic!("{what}: accepted ({x:?}), expected a refusal"),
        Err(s) => {
            assert!(codes.contains(&s.code()), "{what}: {:?} {:?}, expected one of {codes:?}", s.code(), s.message());
            assert!(s.message().contains(word), "{what}: {:?} does not name {word:?}", s.message());
        }
    }
}

pub const DENIED: &[Code] = &[Code::PermissionDenied, Code::FailedPrecondition];

/// Registers over a connection of its own, or says why not (the connection refused).
pub fn try_connect_and_register(endpoint: &str, session: u64) -> Result<Peer, String> {
    let e = endpoint.to_string();
    let client = rt()
        .block_on(async move { tokio::time::timeout(Duration::from_secs(3), FleetClient::connect(e)).await })
        .map_err(|_| "connect timed out".to_string())?
        .map_err(|e| format!("connect: {e}"))?;
    let p = Peer { client, session, role: pb::Role::Actor, actor_id: session };
    p.register().map_err(|s| format!("register: {:?} {}", s.code(), s.message()))?;
    Ok(p)
}
