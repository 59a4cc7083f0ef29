//! The sending end of a queue to the learner (experience, design replies). `send` puts the
//! frame in a window of unacknowledged frames and returns; a background task streams the
//! window and drops what the learner acknowledges. After a reconnect it sends the whole
//! window again (the learner drops what it already has), so an accepted message survives a
//! lost connection, and `send` only waits when the window is full. The window belongs to one
//! learner start: streams name its run id, and when the learner restarts as another start the
//! window is dropped and numbered afresh (the new start issues that work again itself).

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, Weak};
use std::time::Instant;

use coadapt_transport::{Sender, TransportError};
use coadapt_wire::Wire;
use tokio::sync::{Notify, mpsc};
use tokio_stream::wrappers::ReceiverStream;

use super::{Conn, Dropped, Session, StartBound, runtime};
use crate::frames::Frame;
use crate::{Backoff, RUN_HEADER, SESSION_HEADER, is_permanent, is_unregistered, random_u64, refused_frame, status_error};

#[derive(Debug)]
struct Window<F> {
    /// Unacknowledged frames, in sequence order.
    pending: VecDeque<F>,
    next_seq: u64,
    /// The sender was dropped: close cleanly once `pending` is empty.
    closing: bool,
    /// The task has ended (clean close acknowledged, or given up).
    done: bool,
    /// Why sends are refused from now on.
    fatal: Option<Fatal>,
    /// The learner start the frames belong to.
    run_id: u64,
}

#[derive(Clone, Debug)]
enum Fatal {
    Closed,
    Invalid(String),
}

impl Fatal {
    fn error(&self) -> TransportError {
        match self {
            Fatal::Closed => TransportError::Closed,
            Fatal::Invalid(s) => TransportError::Invalid(s.clone()),
        }
    }
}

#[derive(Debug)]
struct Shared<F> {
    window: Mutex<Window<F>>,
    /// Room in the window, or the task ended.
    room: Condvar,
    /// New frames, or closing.
    work: Notify,
}

impl<F: Frame> StartBound for Shared<F> {
    fn restart(&self, run_id: u64) -> Dropped {
        let Ok(mut w) = self.window.lock() else { return Dropped::default() };
        if w.run_id == run_id {
            return Dropped::default();
        }
        let frames = w.pending.len();
        w.pending.clear();
        w.next_seq = 1;
        w.run_id = run_id;
        drop(w);
        self.room.notify_all();
        // The stream of the old start ends.
        self.work.notify_one();
        Dropped { frames, weights_version: None }
    }
}

impl<F> Shared<F> {
    fn lock(&self) -> Result<MutexGuard<'_, Window<F>>, TransportError> {
        self.window.lock().map_err(|_| TransportError::Io("send window lock poisoned".into()))
    }

    fn end(&self, fatal: Option<Fatal>) {
        if let Ok(mut w) = self.window.lock() {
            w.done = true;
            if fatal.is_some() {
                w.fatal = fatal;
            }
        }
        self.room.notify_all();
    }
}

#[derive(Debug)]
pub(crate) struct UpstreamSender<F: Frame> {
    shared: Arc<Shared<F>>,
    sender: u64,
    task: tokio::task::AbortHandle,
    session: Arc<Session>,
}

impl<F: Frame> UpstreamSender<F> {
    pub(crate) fn start(session: Arc<Session>) -> Result<Self, TransportError> {
        let shared = Arc::new(Shared {
            window: Mutex::new(Window { pending: VecDeque::new(), next_seq: 1, closing: false, done: false, fatal: None, run_id: 0 }),
            room: Condvar::new(),
            work: Notify::new(),
        });
        session.conn.attach(Arc::downgrade(&shared) as Weak<dyn StartBound>);
        let sender = random_u64();
        let task = runtime()?.spawn(run::<F>(session.conn.clone(), sender, shared.clone())).abort_handle();
        Ok(Self { shared, sender, task, session })
    }
}

impl<F: Frame> Sender<F::Item> for UpstreamSender<F> {
    fn send(&mut self, msg: F::Item) -> Result<(), TransportError> {
        let cfg = &self.session.conn.cfg;
        let pb = msg.to_pb();
        // Refuse here what the learner would refuse, so an accepted message is never dropped.
        F::Item::from_pb(pb.clone()).map_err(|e| TransportError::Invalid(format!("{}.{e}", F::PAYLOAD)))?;
        let mut frame = F::build(self.sender, 0, Some(pb));
        let bytes = frame.encoded_len();
        if bytes > cfg.max_message_bytes {
            return Err(TransportError::Invalid(format!(
                "{} of {bytes} bytes is above the message limit of {} bytes",
                F::PAYLOAD,
                cfg.max_message_bytes
            )));
        }
        let deadline = Instant::now() + cfg.rpc_timeout;
        let mut w = self.shared.lock()?;
        loop {
            if let Some(f) = &w.fatal {
                return Err(f.error());
            }
            if w.pending.len() < cfg.send_window.max(1) {
                break;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(TransportError::Io(format!(
                    "{} messages unacknowledged for {:?}: the learner is unreachable or not keeping up",
                    w.pending.len(),
                    cfg.rpc_timeout
                )));
            }
            w = self.shared.room.wait_timeout(w, left).map_err(|_| TransportError::Io("send window lock poisoned".into()))?.0;
        }
        frame.set_seq(w.next_seq);
        w.next_seq += 1;
        w.pending.push_back(frame);
        drop(w);
        self.shared.work.notify_one();
        Ok(())
    }
}

impl<F: Frame> Drop for UpstreamSender<F> {
    /// Flushes the window and closes cleanly, waiting up to the RPC deadline.
    fn drop(&mut self) {
        let deadline = Instant::now() + self.session.conn.cfg.rpc_timeout;
        if let Ok(mut w) = self.shared.window.lock() {
            w.closing = true;
            drop(w);
            self.shared.work.notify_one();
        }
        if let Ok(mut w) = self.shared.window.lock() {
            while !w.done {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    break;
                }
                match self.shared.room.wait_timeout(w, left) {
                    Ok((g, _)) => w = g,
                    Err(_) => break,
                }
            }
        }
        self.task.abort();
    }
}

/// What the task should send next on the current stream.
fn next_frame<F: Frame>(w: &Window<F>, sender: u64, sent: u64) -> Option<F> {
    let first = w.pending.front().map(|f| f.seq());
    match first {
        Some(first) => {
            let i = (sent + 1).saturating_sub(first) as usize;
            w.pending.get(i).cloned()
        }
        None if w.closing && sent < w.next_seq => Some(F::build(sender, w.next_seq, None)),
        None => None,
    }
}

/// One stream at a time, reopened with backoff until the sender closes cleanly or a
/// message is refused.
async fn run<F: Frame>(conn: Arc<Conn>, sender: u64, shared: Arc<Shared<F>>) {
    let cfg = conn.cfg.clone();
    let mut backoff = Backoff::new(cfg.reconnect_backoff_max);
    loop {
        let result = match stream_once(&conn, sender, &shared, &mut backoff).await {
            Ok(Streamed::Closed) => Ok(()),
            // The window was dropped for a new learner start: stream the new one at once.
            Ok(Streamed::Restarted) => continue,
            Err(s) => Err(s),
        };
        if let Err(s) = &result
            && let Some(seq) = refused_frame(s)
        {
            // One frame refused (a chunk of an assignment we do not hold, say one a restarted
            // learner issued again): drop it and go on with the rest.
            let dropped = shared.lock().is_ok_and(|mut w| {
                let front = w.pending.front().is_some_and(|f| f.seq() == seq);
                if front {
                    w.pending.pop_front();
                }
                front
            });
            if dropped {
                coadapt_log::logln!("coadapt-grpc: the learner refused {} {seq}: {}; dropped", F::PAYLOAD, s.message());
                shared.room.notify_all();
                continue;
            }
        }
        match result {
            Ok(()) => return shared.end(None),
            // The learner restarted or forgot us: register again (same session), then resend.
            Err(s) if is_unregistered(&s) => match conn.register_once().await {
                Err(s) if is_permanent(&s) => return shared.end(Some(Fatal::Invalid(status_error(&s).to_string()))),
                Ok(()) => {}
                Err(_) => tokio::time::sleep(backoff.next_delay()).await,
            },
            Err(s) if is_permanent(&s) => return shared.end(Some(Fatal::Invalid(status_error(&s).to_string()))),
            Err(_) if conn.is_finished() => return shared.end(Some(Fatal::Closed)),
            // Closing with nothing left to deliver: the clean close is a courtesy that can
            // wait for no one (the learner then counts us as vanished, not finished).
            Err(_) if shared.lock().is_ok_and(|w| w.closing && w.pending.is_empty()) => return shared.end(None),
            Err(_) => tokio::time::sleep(backoff.next_delay()).await,
        }
    }
}

/// How a stream of the window ended well.
enum Streamed {
    /// The clean close was acknowledged.
    Closed,
    /// The window now belongs to another learner start.
    Restarted,
}

/// Streams the window until the clean close is acknowledged or the window is dropped for a new
/// learner start (`Ok`), or the stream fails.
async fn stream_once<F: Frame>(conn: &Conn, sender: u64, shared: &Shared<F>, backoff: &mut Backoff) -> Result<Streamed, tonic::Status> {
    let cfg = &conn.cfg;
    let (tx, rx) = mpsc::channel::<F>(cfg.send_window.max(1));
    let mut req = tonic::Request::new(ReceiverStream::new(rx));
    let session = conn.session.to_string().parse().map_err(|_| tonic::Status::internal("session metadata"))?;
    req.metadata_mut().insert(SESSION_HEADER, session);
    // The learner refuses the stream if it is another start than the window's.
    let run = shared.window.lock().map_err(|_| tonic::Status::internal("send window lock poisoned"))?.run_id;
    req.metadata_mut().insert(RUN_HEADER, run.into());
    let opened = tokio::time::timeout(cfg.rpc_timeout, F::open(conn.client.clone(), req))
        .await
        .map_err(|_| tonic::Status::deadline_exceeded("opening the stream"))??;
    let mut acks = opened.into_inner();
    let mut sent = 0u64;
    let mut last_ack = tokio::time::Instant::now();
    loop {
        let work = shared.work.notified();
        tokio::pin!(work);
        work.as_mut().enable();
        let (next, outstanding) = {
            let w = shared.window.lock().map_err(|_| tonic::Status::internal("send window lock poisoned"))?;
            if w.run_id != run {
                return Ok(Streamed::Restarted);
            }
            let acked = w.pending.front().map_or(w.next_seq - 1, |f| f.seq() - 1);
            (next_frame(&w, sender, sent.max(acked)), sent > acked)
        };
        let idle_deadline = last_ack + cfg.rpc_timeout;
        tokio::select! {
            permit = tx.reserve(), if next.is_some() => {
                let permit = permit.map_err(|_| tonic::Status::unavailable("the stream closed"))?;
                if let Some(f) = next {
                    if !outstanding {
                        // The deadline for an acknowledgement starts with the first frame.
                        last_ack = tokio::time::Instant::now();
                    }
                    sent = f.seq();
                    permit.send(f);
                }
            }
            ack = acks.message() => {
                let ack = ack?.ok_or_else(|| tonic::Status::unavailable("the learner ended the stream"))?;
                last_ack = tokio::time::Instant::now();
                backoff.reset();
                if let Ok(mut w) = shared.window.lock() {
                    if w.run_id != run {
                        return Ok(Streamed::Restarted);
                    }
                    while w.pending.front().is_some_and(|f| f.seq() <= ack.acked) {
                        w.pending.pop_front();
                    }
                    if w.closing && w.pending.is_empty() && ack.acked >= w.next_seq {
                        return Ok(Streamed::Closed);
                    }
                }
                shared.room.notify_all();
            }
            _ = &mut work, if next.is_none() => {}
            _ = tokio::time::sleep_until(idle_deadline), if outstanding => {
                return Err(tonic::Status::deadline_exceeded("no acknowledgement within the RPC deadline"));
            }
        }
    }
}
