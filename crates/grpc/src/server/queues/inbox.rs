//! [`Inbox`]: a bounded queue towards the learner, fed by many senders.

use std::collections::{HashMap, VecDeque};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use coadapt_transport::TransportError;
use tokio::sync::Notify;

use super::{Gate, Reason, Refusal, Verdict, poisoned};

/// What became of an offered frame.
#[derive(Debug)]
pub(crate) enum Offer<T> {
    Accepted,
    /// Acknowledged, not passed on to the learner.
    Skipped(Reason),
    /// Already accepted from this sender (a resend after a reconnect).
    Duplicate,
    /// No room; try again later.
    Full(Option<T>),
    Refused(Refusal),
}

#[derive(Debug)]
struct SenderState {
    last_seq: u64,
    fin: bool,
    /// The session that used this sender id first; no other may.
    session: u64,
}

/// One offered frame: `item` is `None` for the sender's clean close; `bytes` its encoded size.
#[derive(Debug)]
pub(crate) struct Incoming<T> {
    pub(crate) sender: u64,
    pub(crate) session: u64,
    pub(crate) seq: u64,
    pub(crate) item: Option<T>,
    pub(crate) bytes: usize,
}

/// The bounds of an inbox.
#[derive(Clone, Copy, Debug)]
pub(crate) struct InboxLimits {
    /// Items held.
    pub(crate) capacity: usize,
    /// Encoded bytes held (one item larger than this passes an empty queue).
    pub(crate) max_bytes: usize,
    /// How far beyond a sender's last sequence number a frame may be.
    pub(crate) window: u64,
    /// Sender ids per session.
    pub(crate) max_senders: usize,
}

#[derive(Debug)]
pub(crate) struct InboxState<T, G> {
    items: VecDeque<(T, usize)>,
    bytes: usize,
    senders: HashMap<u64, SenderState>,
    /// Sender ids in use per session.
    per_session: HashMap<u64, usize>,
    /// Senders forgotten with their (silent) session, closed cleanly or not.
    forgotten_open: usize,
    forgotten_fin: usize,
    pub(crate) gate: G,
}

impl<T, G> InboxState<T, G> {
    fn record(&mut self, sender: u64, session: u64, seq: u64, fin: bool) {
        match self.senders.get_mut(&sender) {
            Some(st) => {
                st.last_seq = seq;
                st.fin = fin;
            }
            None => {
                self.senders.insert(sender, SenderState { last_seq: seq, fin, session });
                *self.per_session.entry(session).or_default() += 1;
            }
        }
    }

    /// Drops queued items `doomed` picks; returns how many.
    pub(crate) fn purge(&mut self, doomed: impl Fn(&T) -> bool) -> usize {
        let before = self.items.len();
        let mut bytes = 0usize;
        self.items.retain(|(x, b)| {
            let keep = !doomed(x);
            if keep {
                bytes = bytes.saturating_add(*b);
            }
            keep
        });
        self.bytes = bytes;
        before - self.items.len()
    }
}

/// A bounded queue towards the learner, fed by many senders. It remembers each sender's
/// highest sequence number, so a resend is dropped, and whether the sender has closed: once
/// every sender that ever sent has closed and the queue is drained, it reports `Closed`.
/// A sender that vanished without closing (a crash) keeps it open: it may come back.
///
/// A sender id is bound to the session that used it first; a frame more than the send window
/// beyond the sender's last one is refused (so no one can make a sender's future frames look
/// like resends). A sender's first frame here may have any number: after the server comes back
/// for the same learner start (same run id), clients resend their windows from where they were.
#[derive(Debug)]
pub(crate) struct Inbox<T, G = ()> {
    state: Mutex<InboxState<T, G>>,
    readable: Condvar,
    space: Notify,
    limits: InboxLimits,
}

impl<T, G: Gate<T>> Inbox<T, G> {
    pub(crate) fn new(limits: InboxLimits, gate: G) -> Self {
        Self {
            state: Mutex::new(InboxState {
                items: VecDeque::new(),
                bytes: 0,
                senders: HashMap::new(),
                per_session: HashMap::new(),
                forgotten_open: 0,
                forgotten_fin: 0,
                gate,
            }),
            readable: Condvar::new(),
            space: Notify::new(),
            limits: InboxLimits { capacity: limits.capacity.max(1), window: limits.window.max(1), ..limits },
        }
    }

    pub(crate) fn lock(&self) -> Result<MutexGuard<'_, InboxState<T, G>>, TransportError> {
        self.state.lock().map_err(|_| poisoned())
    }

    /// Wakes senders waiting for room (after items were purged).
    pub(crate) fn wake_senders(&self) {
        self.space.notify_waiters();
    }

    fn offer(&self, f: &mut Incoming<T>) -> Result<Offer<T>, TransportError> {
        let mut s = self.lock()?;
        let s = &mut *s;
        let now = Instant::now();
        let (sender, session, seq) = (f.sender, f.session, f.seq);
        match s.senders.get(&sender) {
            Some(st) if st.session != session => {
                return Ok(Offer::Refused(Refusal::new(
                    Reason::ForeignSender,
                    tonic::Code::PermissionDenied,
                    format!("sender: {sender} is another session's sender id"),
                )));
            }
            Some(st) if seq <= st.last_seq => return Ok(Offer::Duplicate),
            Some(st) if seq > st.last_seq.saturating_add(self.limits.window) => {
                return Ok(Offer::Refused(Refusal::new(
                    Reason::SeqJump,
                    tonic::Code::InvalidArgument,
                    format!("seq: {seq} is more than the send window ({}) beyond {}", self.limits.window, st.last_seq),
                )));
            }
            Some(_) => {}
            None if seq == 0 => return Ok(Offer::Duplicate),
            None if s.per_session.get(&session).copied().unwrap_or(0) >= self.limits.max_senders => {
                return Ok(Offer::Refused(Refusal::new(
                    Reason::TooManySenders,
                    tonic::Code::ResourceExhausted,
                    format!(
                        "sender: this session already uses {} sender ids (GrpcConfig::max_senders_per_session)",
                        self.limits.max_senders
                    ),
                )));
            }
            None => {}
        }
        let Some(item) = f.item.take() else {
            s.record(sender, session, seq, true);
            self.readable.notify_all();
            return Ok(Offer::Accepted);
        };
        match s.gate.judge(session, &item, now) {
            Verdict::Refuse(r) => return Ok(Offer::Refused(r)),
            Verdict::Skip(reason) => {
                s.record(sender, session, seq, false);
                return Ok(Offer::Skipped(reason));
            }
            Verdict::Forward => {}
        }
        let full =
            s.items.len() >= self.limits.capacity || (!s.items.is_empty() && s.bytes.saturating_add(f.bytes) > self.limits.max_bytes);
        if full {
            return Ok(Offer::Full(Some(item)));
        }
        s.gate.commit(session, &item, now);
        s.record(sender, session, seq, false);
        s.bytes = s.bytes.saturating_add(f.bytes);
        s.items.push_back((item, f.bytes));
        self.readable.notify_all();
        Ok(Offer::Accepted)
    }

    /// Like `offer`, waiting up to `patience` for room. A `Full` hands the item back.
    pub(crate) async fn offer_wait(&self, mut f: Incoming<T>, patience: Duration) -> Result<(Offer<T>, Incoming<T>), TransportError> {
        let deadline = tokio::time::Instant::now() + patience;
        loop {
            // Registered before looking, so a pop between the look and the wait still wakes us.
            let space = self.space.notified();
            tokio::pin!(space);
            space.as_mut().enable();
            match self.offer(&mut f)? {
                Offer::Full(back) => f.item = back,
                done => return Ok((done, f)),
            }
            tokio::select! {
                _ = space => {}
                _ = tokio::time::sleep_until(deadline) => return Ok((Offer::Full(None), f)),
            }
        }
    }

    /// The highest sequence number accepted from `sender`.
    pub(crate) fn acked(&self, sender: u64) -> u64 {
        self.lock().ok().and_then(|s| s.senders.get(&sender).map(|st| st.last_seq)).unwrap_or(0)
    }

    /// Forgets the senders of a session that fell silent (memory stays bounded); a sender that
    /// had not closed still keeps the queue open, as a crashed one does.
    pub(crate) fn forget_session(&self, session: u64) {
        let Ok(mut s) = self.state.lock() else { return };
        let s = &mut *s;
        if s.per_session.remove(&session).is_none() {
            return;
        }
        let (mut open, mut fin) = (0usize, 0usize);
        s.senders.retain(|_, st| {
            let keep = st.session != session;
            if !keep {
                if st.fin {
                    fin += 1;
                } else {
                    open += 1;
                }
            }
            keep
        });
        s.forgotten_open = s.forgotten_open.saturating_add(open);
        s.forgotten_fin = s.forgotten_fin.saturating_add(fin);
    }

    pub(crate) fn pop_timeout(&self, timeout: Duration) -> Result<Option<T>, TransportError> {
        let deadline = Instant::now() + timeout;
        let mut s = self.lock()?;
        loop {
            if let Some((x, bytes)) = s.items.pop_front() {
                s.bytes = s.bytes.saturating_sub(bytes);
                drop(s);
                self.space.notify_waiters();
                return Ok(Some(x));
            }
            let ever = !s.senders.is_empty() || s.forgotten_fin > 0;
            if ever && s.forgotten_open == 0 && s.senders.values().all(|st| st.fin) {
                return Err(TransportError::Closed);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            s = self.readable.wait_timeout(s, left).map_err(|_| poisoned())?.0;
        }
    }
}
