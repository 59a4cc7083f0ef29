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
