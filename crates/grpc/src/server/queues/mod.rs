//! The learner's queues. RPC handlers (async) meet the learner's threads (sync) here, so each
//! queue pairs a mutex-guarded deque with a condition variable for the sync side and a tokio
//! `Notify` for the async side.
//!
//! # Layout
//! - here: why a frame is refused ([`Reason`], [`Refusal`]) and the [`Gate`] an inbox asks;
//! - `inbox`: [`Inbox`], many senders towards the learner (experience, design replies);
//! - `outbox`: [`Outbox`], the learner's work long-polled by consumers (assignments, design
//!   requests), each delivery kept until confirmed.

use std::time::Instant;

use coadapt_transport::TransportError;

mod inbox;
mod outbox;
pub(crate) use inbox::{Inbox, InboxLimits, Incoming, Offer};
pub(crate) use outbox::{Outbox, Take};

fn poisoned() -> TransportError {
    TransportError::Io("queue lock poisoned".into())
}

/// Why a frame (or a call) was refused or dropped; counted in [`crate::Refusals`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reason {
    Unregistered,
    WrongRole,
    SessionsFull,
    ForeignSender,
    TooManySenders,
    SeqJump,
    ForeignAssignment,
    BadLength,
    EmptyDropped,
    Purged,
    OtherRun,
    PermissionDenied,
}

impl Reason {
    /// Its name in the refusal ledger and `/metrics` (the field of [`crate::Refusals`]).
    pub(crate) fn label(self) -> &'static str {
        match self {
            Reason::Unregistered => "unregistered",
            Reason::WrongRole => "wrong_role",
            Reason::SessionsFull => "sessions_full",
            Reason::ForeignSender => "foreign_sender",
            Reason::TooManySenders => "too_many_senders",
            Reason::SeqJump => "seq_jump",
            Reason::ForeignAssignment => "foreign_assignment",
            Reason::BadLength => "bad_length",
            Reason::EmptyDropped => "empty_dropped",
            Reason::Purged => "purged",
            Reason::OtherRun => "other_run",
            Reason::PermissionDenied => "permission_denied",
        }
    }

    /// Whether the first one from a peer is logged: not for what well-behaved clients cause in
    /// the normal course (a restart's stale calls, a resend's spare empty chunks, a purge).
    pub(crate) fn notice(self) -> coadapt_auth::refusals::Notice {
        use coadapt_auth::refusals::Notice;
        match self {
            Reason::EmptyDropped | Reason::Purged | Reason::OtherRun => Notice::CountOnly,
            _ => Notice::Log,
        }
    }
}

/// A frame refused: the stream ends with this status.
#[derive(Debug)]
pub(crate) struct Refusal {
    pub(crate) reason: Reason,
    pub(crate) code: tonic::Code,
    pub(crate) message: String,
    /// Only this frame is at fault (not the sender): the client may drop it and go on.
    pub(crate) frame_only: bool,
}

impl Refusal {
    pub(crate) fn new(reason: Reason, code: tonic::Code, message: impl Into<String>) -> Self {
        Self { reason, code, message: message.into(), frame_only: false }
    }
}

/// What a gate makes of an item before it joins the queue.
#[derive(Debug)]
pub(crate) enum Verdict {
    Forward,
    /// Acknowledged but not passed on.
    Skip(Reason),
    Refuse(Refusal),
}

/// Checks items against what the learner handed out (see `episodes`); runs under the queue's
/// lock, so a check and its commit see the same state.
pub(crate) trait Gate<T>: Send {
    fn judge(&mut self, session: u64, item: &T, now: Instant) -> Verdict;
    /// The item judged `Forward` joined the queue.
    fn commit(&mut self, session: u64, item: &T, now: Instant);
}

/// No checks beyond the sender's (design replies).
impl<T> Gate<T> for () {
    fn judge(&mut self, _: u64, _: &T, _: Instant) -> Verdict {
        Verdict::Forward
    }

    fn commit(&mut self, _: u64, _: &T, _: Instant) {}
}
