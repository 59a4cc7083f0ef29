//! The two channel shapes: a reliable ordered queue and a newest-value topic.

use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// Every peer on the other side has gone (and will not come back on this channel).
    #[error("the other side of the channel has closed")]
    Closed,
    /// A message arrived but is malformed; it was dropped.
    #[error("invalid message: {0}")]
    Invalid(String),
    #[error("transport failure: {0}")]
    Io(String),
}

/// The sending end of an ordered queue. A message is *accepted* once `send` returns `Ok`:
/// from then on it is delivered exactly once, in order, unless the receiver is gone.
pub trait Sender<T>: Send {
    fn send(&mut self, msg: T) -> Result<(), TransportError>;
}

/// The receiving end of an ordered queue.
pub trait Receiver<T>: Send {
    /// The next message, or `Ok(None)` when none came within `timeout`.
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<T>, TransportError>;

    /// How many senders have left (closed or died) since the receiver opened, as far as
    /// `recv_timeout` has seen. A receiver waiting for the reply to a request its only peer had
    /// taken learns from it that the request may be lost, even when a restarted peer took the
    /// old one's place before the receiver ever saw zero senders. Transports where peers do
    /// not come and go under one receiver say 0.
    fn departures(&self) -> u64 {
        0
    }
}

/// A message with a version: a topic's readers only ever move forward.
pub trait Versioned {
    fn version(&self) -> u64;
}

/// The writing end of a latest-value topic: each publish replaces the previous value for all
/// readers (versions must increase).
pub trait Publisher<T>: Send {
    fn publish(&mut self, msg: T) -> Result<(), TransportError>;
}

/// A reader of a latest-value topic: a slow reader skips versions, it never queues them.
pub trait Subscriber<T>: Send {
    /// The newest value whose version is at least `min_version`, waiting up to `timeout` for
    /// one; `Ok(None)` on timeout.
    fn wait_for(&mut self, min_version: u64, timeout: Duration) -> Result<Option<Arc<T>>, TransportError>;
}

/// How often [`next_or_stop`] and [`newest_or_stop`] look at the stop flag.
pub const STOP_POLL: Duration = Duration::from_millis(100);

/// The next message, waiting as long as it takes; `Ok(None)` once `stop` is set or every
/// sender has gone (a role's normal end).
pub fn next_or_stop<T>(rx: &mut dyn Receiver<T>, stop: &std::sync::atomic::AtomicBool) -> Result<Option<T>, TransportError> {
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        match rx.recv_timeout(STOP_POLL) {
            Ok(Some(m)) => return Ok(Some(m)),
            Ok(None) => continue,
            Err(TransportError::Closed) => return Ok(None),
            Err(e) => return Err(e),
        }
    }
    Ok(None)
}

/// The newest value of at least `min_version`, waiting as long as it takes; `Ok(None)` once
/// `stop` is set or the publisher has gone.
pub fn newest_or_stop<T>(
    sub: &mut dyn Subscriber<T>,
    min_version: u64,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<Option<Arc<T>>, TransportError> {
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        match sub.wait_for(min_version, STOP_POLL) {
            Ok(Some(w)) => return Ok(Some(w)),
            Ok(None) => continue,
            Err(TransportError::Closed) => return Ok(None),
            Err(e) => return Err(e),
        }
    }
    Ok(None)
}
