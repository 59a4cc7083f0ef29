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
//!   weight topics, `server::service` the RPC handlers. `server` documents the trust model:
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
//! Delivery is exactly once while the learner lives; across a learner crash, messages it had
//! stored but whose acknowledgement was lost with it go again to its successor. Assignments
//! still queued when the learner ends are dropped with it (nobody would learn from them).

use std::time::Duration;

mod client;
mod frames;
mod server;

pub use client::{actor_links, optimizer_links};
pub use coadapt_transport::{ActorLinks, LearnerLinks, OptimizerLinks, TransportError};
pub use server::{ActorStatus, ClientRole, LearnerServer, Refusals, serve_learner};

/// The protocol version in `Hello`/`Welcome`; a learner refuses clients of another one.
/// Version 2: every call names a registered session of the right role, push streams in their
/// `coadapt-session` metadata.
pub const PROTOCOL: u32 = 2;

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
    /// Largest HTTP/2 header list (bytes) the learner accepts on a call.
    pub max_header_list_bytes: u32,
    /// Streams a connection may open and reset before the learner has served them (the HTTP/2
    /// rapid-reset guard); beyond it the connection is closed.
    pub max_pending_reset_streams: usize,
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
            max_header_list_bytes: 16 << 10,
            max_pending_reset_streams: 32,
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
/// Metadata of a FAILED_PRECONDITION: the session is not registered (the learner restarted or
/// forgot it); the client registers again and retries.
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

pub(crate) fn status_error(status: &tonic::Status) -> TransportError {
    if is_permanent(status) {
        TransportError::Invalid(format!("{:?}: {}", status.code(), status.message()))
    } else {
        TransportError::Io(format!("{:?}: {}", status.code(), status.message()))
    }
}
