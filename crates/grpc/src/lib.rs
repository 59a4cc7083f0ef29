//! coadapt's roles across machines over gRPC (tonic): the learner process hosts the
//! `coadapt.v1.Fleet` service (`proto/coadapt/v1/fleet.proto`); actors and the design
//! optimiser connect to it and get the same [`ActorLinks`] / [`OptimizerLinks`] as over any other
//! transport.
//!
//! # Layout
//! - [`GrpcConfig`] (here): deadlines, message-size limit, heartbeat and reconnect backoff.
//! - `frames`: the two client-to-learner queues (experience, design replies) share one
//!   protocol; `frames::Frame` is what differs between them.
//! - `server`: [`serve_learner`] and [`LearnerServer`]; `server::queues` holds the learner's
//!   queues (an inbox that drops duplicates by sender and sequence number, an outbox that hands
//!   each item to one consumer and redelivers a lost answer), `server::topic` the weight topics,
//!   `server::service` the RPC handlers.
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
//! Delivery is exactly once while the learner lives; across a learner crash, messages it had
//! stored but whose acknowledgement was lost with it go again to its successor. Assignments
//! still queued when the learner ends are dropped with it (nobody would learn from them).

use std::time::Duration;

mod client;
mod frames;
mod server;

pub use client::{actor_links, optimizer_links};
pub use coadapt_transport::{ActorLinks, LearnerLinks, OptimizerLinks, TransportError};
pub use server::{ActorStatus, ClientRole, LearnerServer, serve_learner};

/// The protocol version in `Hello`/`Welcome`; a learner refuses clients of another one.
pub const PROTOCOL: u32 = 1;

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
    /// Messages a sender may have in flight unacknowledged before `send` waits.
    pub send_window: usize,
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

/// Statuses that will not go away by retrying: a malformed or oversized message, or a client
/// that belongs to another fleet.
pub(crate) fn is_permanent(status: &tonic::Status) -> bool {
    use tonic::Code;
    matches!(status.code(), Code::InvalidArgument | Code::OutOfRange | Code::ResourceExhausted | Code::FailedPrecondition)
}

pub(crate) fn status_error(status: &tonic::Status) -> TransportError {
    if is_permanent(status) {
        TransportError::Invalid(format!("{:?}: {}", status.code(), status.message()))
    } else {
        TransportError::Io(format!("{:?}: {}", status.code(), status.message()))
    }
}
