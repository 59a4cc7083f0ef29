//! coadapt's roles across machines over gRPC (tonic): the learner process hosts the
//! `coadapt.v1.Fleet` service (`proto/coadapt/v1/fleet.proto`); actors and the design
//! optimiser connect to it and get the same [`ActorLinks`] / [`OptimizerLinks`] as over any other
//! transport.
//!
//! # Layout
//! - [`GrpcConfig`] (here): deadlines, message-size limit, heartbeat and reconnect backoff,
//!   and the learner's bounds on its clients (sessions, senders, queued bytes, episode length,
//!   HTTP/2 streams per connection).
//! - `frames`: the two client-to-learner queues (experience, design replies) share one
//!   protocol; `frames::Frame` is what differs between them.
//! - `server`: [`serve_learner`] and [`LearnerServer`]; `server::queues` holds the learner's
//!   queues (an inbox that drops duplicates by sender and sequence number, an outbox that hands
//!   each item to one consumer and redelivers a lost answer), `server::episodes` the gate that
//!   ties each assignment's experience to the session it was handed to, `server::topic` the
//!   weight topics, `server::service` the RPC handlers, `server::router` the server that carries
//!   them beside health and reflection behind the role gate. `server` documents the trust model:
//!   sessions are capability tokens, and what the learner refuses is counted in [`Refusals`].
//! - `client`: [`actor_links`] and [`optimizer_links`]: a shared tokio runtime drives every
//!   connection, and the sync channel ends wait on it (`client::upstream`: the pipelined
//!   sender; `client::poll`: the long-poll receiver; `client::weights`: the subscriber).
//!
//! # Failure model
//! A learner that goes away is retried with capped exponential backoff: receives return
//! `Ok(None)`, sends buffer up to a window of unacknowledged messages (resent after the
//! reconnect, the learner drops duplicates). `Err(Closed)` means the learner said the fleet is
//! finished (it dropped the assignment or design-request sender, or stopped publishing), which
//! is how a normal end of the learner ends its clients; a crash does not, so they wait for it.
//! Every RPC has a deadline; streams are kept honest by keep-alive messages every heartbeat.
//! A learner that does not know a client's session (it restarted, or forgot the client after
//! a long silence) says so, and the client registers the same session again and carries on.
//! Delivery is exactly once while the learner lives. Assignments still queued when the learner
//! ends are dropped with it (nobody would learn from them).
//!
//! Learner starts. Every start of the learner has a run id ([`GrpcConfig::run_id`], drawn if
//! not given; a learner resumed from a snapshot is a new start), which `Welcome` and
//! `BeatReply` carry and the answers of WatchWeights and the long polls name in their
//! `coadapt-run` metadata. A client remembers the run id of its registration and stamps with
//! it what it keeps of that start: heartbeats, polls (whose `received` numbers that start's
//! deliveries), weight watches (whose `min_version` is that start's) and push streams (whose
//! frames were sent for it). A learner refuses a call stamped with another start's run id like
//! one of an unknown session (counted in [`Refusals::other_run`]), and nothing reaches its role
//! code from it. When a registration comes back with another run id, the client drops
//! everything of the old start at once: its cached weights (a subscriber then waits for the new
//! start's, whatever their version numbers), every unacknowledged experience and design-reply
//! frame (their senders number afresh from 1), and what its long polls received; it says so in
//! one line on stderr ("learner restarted (run id X -> Y): dropping N unacknowledged frames and
//! weights version V"). The resumed learner issues the old start's unfinished episodes and
//! design requests again itself. So a message the old start had not acknowledged is lost with
//! it, and what the role code sends before its client has heard of the new start (at most a
//! heartbeat or a retry later) is dropped too. A server that comes back with the *same* run id
//! is the same start: clients keep what they hold and resend what it had not acknowledged (it
//! drops duplicates). Until the client has registered with the new start, receives return
//! `Ok(None)` as while the learner is away, never anything of the old start.

use std::time::Duration;

mod client;
mod frames;
mod server;

pub use client::{actor_links, optimizer_links};
pub use coadapt_auth::peers::{LimitedIncoming, LimitedStream, PeerLimits};
pub use coadapt_transport::{ActorLinks, LearnerLinks, OptimizerLinks, TransportError};
pub use server::{ActorStatus, ClientRole, HealthSwitch, LearnerServer, Refusals, serve_learner};

/// The protocol version in `Hello`/`Welcome`; a learner refuses clients of another one.
/// Version 2: every call names a registered session of the right role, push streams in their
/// `coadapt-session` metadata. Version 3: learner starts have run ids, and clients stamp what
/// they keep of one start with its run id (see the failure model).
pub const PROTOCOL: u32 = 3;

/// Settings of both ends; a fleet's learner and clients should use the same.
#[derive(Clone, Debug)]
pub struct GrpcConfig {
    /// A client of another fleet (a different name) is refused at registration.
    pub fleet: String,
    /// The deadline of every unary call; long polls wait somewhat less.
    pub rpc_timeout: Duration,
    /// Largest encoded message, enforced when encoding and decoding on both sides (weights are
    /// the large ones).
    pub max_message_bytes: usize,
    pub connect_timeout: Duration,
    /// Client heartbeats, server keep-alives on idle streams, HTTP/2 pings.
    pub heartbeat: Duration,
    /// Longest wait between reconnection attempts.
    pub reconnect_backoff_max: Duration,
    /// Messages a sender may have in flight unacknowledged before `send` waits. The learner
    /// refuses a frame whose sequence number is more than this beyond the sender's last one.
    pub send_window: usize,
    /// Most sessions the learner keeps registered at once; a `Register` beyond is refused with
    /// RESOURCE_EXHAUSTED (after forgetting the silent ones).
    pub max_sessions: usize,
    /// A session silent this long (no heartbeat, poll or frame) is forgotten with what the
    /// learner kept for it; it must register again. At least three heartbeats are allowed.
    pub session_idle_timeout: Duration,
    /// Sender ids one session may use on each queue to the learner (a client uses one per
    /// queue); a frame of another new sender is refused with RESOURCE_EXHAUSTED.
    pub max_senders_per_session: usize,
    /// Encoded bytes of experience (and, separately, of design replies) the learner's queue
    /// holds before the learner takes them; beyond it, frames wait unacknowledged (the senders'
    /// windows fill and `send` waits). One message larger than this still passes an empty queue.
    pub inbox_max_bytes: usize,
    /// The longest episode, in steps: an `EpisodeEnd.length` above it, or more transitions
    /// streamed for one assignment, is refused.
    pub max_episode_steps: u64,
    /// HTTP/2 streams (calls) one connection may have open at once on the learner.
    pub max_concurrent_streams: u32,
    /// TCP connections one remote address may hold open on the learner at once; one more is
    /// closed as it is accepted (a client needs one; a host of many actors one per actor).
    pub max_connections_per_peer: usize,
    /// TCP connections open on the learner at once, from all peers.
    pub max_connections: usize,
    /// Largest HTTP/2 header list (bytes) the learner accepts on a call.
    pub max_header_list_bytes: u32,
    /// Streams a connection may open and reset before the learner has served them (the HTTP/2
    /// rapid-reset guard); beyond it the connection is closed.
    pub max_pending_reset_streams: usize,
    /// The learner's only: the run id of this learner start (a resumed learner is a new start
    /// and needs a new one). `None` (or 0): [`serve_learner`] draws a random one, see
    /// [`LearnerServer::run_id`]. Clients ignore it; they learn the run id when they register.
    pub run_id: Option<u64>,
    /// The learner's: TLS and the accepted role tokens (actors and optimisers only; the
    /// population weights to optimisers and operators only).
    pub server_auth: coadapt_auth::ServerAuth,
    /// A client's: TLS (the CA, its own certificate for mutual TLS) and its token.
    pub client_auth: coadapt_auth::ClientAuth,
}

impl Default for GrpcConfig {
    fn default() -> Self {
        Self {
            fleet: "coadapt".into(),
            rpc_timeout: Duration::from_secs(10),
            max_message_bytes: 64 << 20,
            connect_timeout: Duration::from_secs(5),
            heartbeat: Duration::from_secs(1),
            reconnect_backoff_max: Duration::from_secs(5),
            send_window: 64,
            max_sessions: 1024,
            session_idle_timeout: Duration::from_secs(30),
            max_senders_per_session: 16,
            inbox_max_bytes: 256 << 20,
            max_episode_steps: 1_000_000,
            max_concurrent_streams: 64,
            max_connections_per_peer: 128,
            max_connections: 1024,
            max_header_list_bytes: 16 << 10,
            max_pending_reset_streams: 32,
            run_id: None,
            server_auth: coadapt_auth::ServerAuth::default(),
            client_auth: coadapt_auth::ClientAuth::default(),
        }
    }
}

impl GrpcConfig {
    /// How long a long poll may hold a call: its deadline less a margin for the answer to
    /// travel back before the client gives up.
    pub(crate) fn long_poll_cap(&self) -> Duration {
        self.rpc_timeout.saturating_sub(self.poll_margin())
    }

    pub(crate) fn poll_margin(&self) -> Duration {
        (self.rpc_timeout / 5).min(Duration::from_secs(1))
    }
}

/// HTTP/2 flow-control windows: the 64 KiB default caps a stream at one window per round trip,
/// far below what multi-megabyte weights need.
pub(crate) const STREAM_WINDOW: u32 = 8 << 20;
pub(crate) const CONNECTION_WINDOW: u32 = 16 << 20;

/// Doubling waits between reconnection attempts, capped.
#[derive(Debug)]
pub(crate) struct Backoff {
    next: Duration,
    max: Duration,
}

impl Backoff {
    const FIRST: Duration = Duration::from_millis(50);

    pub(crate) fn new(max: Duration) -> Self {
        Self { next: Self::FIRST.min(max), max }
    }

    pub(crate) fn reset(&mut self) {
        self.next = Self::FIRST.min(self.max);
    }

    pub(crate) fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }
}

/// The request metadata naming the session of a push stream (decimal).
pub(crate) const SESSION_HEADER: &str = "coadapt-session";
/// The request metadata of a push stream naming the learner start its frames belong to, and the
/// response metadata of WatchWeights and the long polls naming the start that answers (decimal).
pub(crate) const RUN_HEADER: &str = "coadapt-run";
/// Metadata of a FAILED_PRECONDITION: the session is not registered (the learner restarted or
/// forgot it), or the call is stamped with another learner start's run id; the client registers
/// again (and so learns the current run id) and retries.
pub(crate) const REGISTER_HEADER: &str = "coadapt-register";

/// Metadata of a PERMISSION_DENIED that refuses one frame only (a chunk of an assignment this
/// client does not hold): its sequence number. The client drops that frame and goes on.
pub(crate) const REFUSED_HEADER: &str = "coadapt-refused-seq";

/// The one frame the learner refused, if the status says so (see [`REFUSED_HEADER`]).
pub(crate) fn refused_frame(status: &tonic::Status) -> Option<u64> {
    if status.code() != tonic::Code::PermissionDenied {
        return None;
    }
    status.metadata().get(REFUSED_HEADER)?.to_str().ok()?.parse().ok()
}

/// The run id in a response's `coadapt-run` metadata (0: none).
pub(crate) fn run_of(md: &tonic::metadata::MetadataMap) -> u64 {
    md.get(RUN_HEADER).and_then(|v| v.to_str().ok()).and_then(|v| v.parse().ok()).unwrap_or(0)
}

/// The learner does not know our session (see [`REGISTER_HEADER`]).
pub(crate) fn is_unregistered(status: &tonic::Status) -> bool {
    status.code() == tonic::Code::FailedPrecondition && status.metadata().get(REGISTER_HEADER).is_some()
}

/// Statuses that will not go away by retrying: a malformed or oversized message, a client
/// that belongs to another fleet, or one refused what it is not allowed (another session's
/// sender or assignment). An unknown session is not one: the client registers again.
pub(crate) fn is_permanent(status: &tonic::Status) -> bool {
    use tonic::Code;
    !is_unregistered(status)
        && matches!(
            status.code(),
            Code::InvalidArgument | Code::OutOfRange | Code::ResourceExhausted | Code::FailedPrecondition | Code::PermissionDenied
        )
}

/// 64 random bits, never 0 (sessions, sender ids, run ids).
pub(crate) fn random_u64() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(COUNTER.fetch_add(1, Ordering::Relaxed));
    h.write_u32(std::process::id());
    h.write_u128(std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0));
    h.finish().max(1)
}

pub(crate) fn status_error(status: &tonic::Status) -> TransportError {
    if is_permanent(status) {
        TransportError::Invalid(format!("{:?}: {}", status.code(), status.message()))
    } else {
        TransportError::Io(format!("{:?}: {}", status.code(), status.message()))
    }
}
