//! The learner's queues. RPC handlers (async) meet the learner's threads (sync) here, so each
//! queue pairs a mutex-guarded deque with a condition variable for the sync side and a tokio
//! `Notify` for the async side.

use std::collections::{HashMap, VecDeque};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use coadapt_transport::TransportError;
use tokio::sync::{Notify, watch};

fn poisoned() -> TransportError {
    TransportError::Io("queue lock poisoned".into())
}

/// What became of an offered frame.
#[derive(Debug)]
pub(crate) enum Offer<T> {
    Accepted,
    /// Already accepted from this sender (a resend after a reconnect).
    Duplicate,
    /// No room; try again later.
    Full(Option<T>),
}

#[derive(Debug, Default)]
struct SenderState {
    last_seq: u64,
    fin: bool,
}

#[derive(Debug)]
struct InboxState<T> {
    items: VecDeque<T>,
    senders: HashMap<u64, SenderState>,
}

/// A bounded queue towards the learner, fed by many senders. It remembers each sender's
/// highest sequence number, so a resend is dropped, and whether the sender has closed: once
/// every sender that ever sent has closed and the queue is drained, it reports `Closed`.
/// A sender that vanished without closing (a crash) keeps it open: it may come back.
#[derive(Debug)]
pub(crate) struct Inbox<T> {
    state: Mutex<InboxState<T>>,
    readable: Condvar,
    space: Notify,
    capacity: usize,
}

impl<T> Inbox<T> {
    pub(crate) fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(InboxState { items: VecDeque::new(), senders: HashMap::new() }),
            readable: Condvar::new(),
            space: Notify::new(),
            capacity: capacity.max(1),
        }
    }

    fn lock(&self) -> Result<MutexGuard<'_, InboxState<T>>, TransportError> {
        self.state.lock().map_err(|_| poisoned())
    }

    /// Offers frame `seq` of `sender`: an item, or `None` for the sender's close.
    fn offer(&self, sender: u64, seq: u64, item: Option<T>) -> Result<Offer<T>, TransportError> {
        let mut s = self.lock()?;
        let full = s.items.len() >= self.capacity;
        let st = s.senders.entry(sender).or_default();
        if seq <= st.last_seq {
            return Ok(Offer::Duplicate);
        }
        match item {
            None => {
                st.last_seq = seq;
                st.fin = true;
            }
            Some(_) if full => return Ok(Offer::Full(item)),
            Some(x) => {
                st.last_seq = seq;
                st.fin = false;
                s.items.push_back(x);
            }
        }
        drop(s);
        self.readable.notify_all();
        Ok(Offer::Accepted)
    }

    /// Like `offer`, waiting up to `patience` for room.
    pub(crate) async fn offer_wait(
        &self,
        sender: u64,
        seq: u64,
        mut item: Option<T>,
        patience: Duration,
    ) -> Result<Offer<T>, TransportError> {
        let deadline = tokio::time::Instant::now() + patience;
        loop {
            // Registered before looking, so a pop between the look and the wait still wakes us.
            let space = self.space.notified();
            tokio::pin!(space);
            space.as_mut().enable();
            match self.offer(sender, seq, item)? {
                Offer::Full(back) => item = back,
                done => return Ok(done),
            }
            tokio::select! {
                _ = space => {}
                _ = tokio::time::sleep_until(deadline) => return Ok(Offer::Full(item)),
            }
        }
    }

    /// The highest sequence number accepted from `sender`.
    pub(crate) fn acked(&self, sender: u64) -> u64 {
        self.lock().ok().and_then(|s| s.senders.get(&sender).map(|st| st.last_seq)).unwrap_or(0)
    }

    pub(crate) fn pop_timeout(&self, timeout: Duration) -> Result<Option<T>, TransportError> {
        let deadline = Instant::now() + timeout;
        let mut s = self.lock()?;
        loop {
            if let Some(x) = s.items.pop_front() {
                drop(s);
                self.space.notify_waiters();
                return Ok(Some(x));
            }
            if !s.senders.is_empty() && s.senders.values().all(|st| st.fin) {
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

/// The consumer's last delivery, kept until the consumer confirms it by asking for the next.
#[derive(Debug)]
struct Delivery<T> {
    seq: u64,
    unconfirmed: Option<T>,
}

#[derive(Debug)]
struct OutboxState<T> {
    items: VecDeque<T>,
    finished: bool,
    consumers: HashMap<u64, Delivery<T>>,
}

/// What a long poll gets.
#[derive(Debug)]
pub(crate) enum Take<T> {
    Item(u64, T),
    /// Drained, and the learner will send nothing more.
    Finished,
    Empty,
}

/// A queue from the learner to consumers that long-poll for work. Each item goes to one
/// consumer; each poll says which delivery the consumer last received, so an answer lost on
/// the way (a deadline, a dropped connection) is delivered again to the same consumer rather
/// than lost or given to a second one.
#[derive(Debug)]
pub(crate) struct Outbox<T> {
    state: Mutex<OutboxState<T>>,
    ready: Notify,
}

impl<T> Outbox<T> {
    pub(crate) fn new() -> Self {
        Self { state: Mutex::new(OutboxState { items: VecDeque::new(), finished: false, consumers: HashMap::new() }), ready: Notify::new() }
    }

    fn lock(&self) -> Result<MutexGuard<'_, OutboxState<T>>, TransportError> {
        self.state.lock().map_err(|_| poisoned())
    }

    pub(crate) fn push(&self, item: T) -> Result<(), TransportError> {
        self.lock()?.items.push_back(item);
        self.ready.notify_waiters();
        Ok(())
    }

    /// The learner will send nothing more.
    pub(crate) fn finish(&self) {
        if let Ok(mut s) = self.state.lock() {
            s.finished = true;
        }
        self.ready.notify_waiters();
    }

    pub(crate) fn is_finished(&self) -> bool {
        self.state.lock().map(|s| s.finished).unwrap_or(true)
    }

    /// The consumer leaves: a delivery it did not receive goes back to the front.
    pub(crate) fn release(&self, consumer: u64, received: u64) {
        let Ok(mut s) = self.state.lock() else { return };
        if let Some(d) = s.consumers.remove(&consumer)
            && let Some(x) = d.unconfirmed
            && received < d.seq
        {
            s.items.push_front(x);
            drop(s);
            self.ready.notify_waiters();
        }
    }
}

impl<T: Clone> Outbox<T> {
    fn try_take(&self, consumer: u64, received: u64) -> Result<Take<T>, TransportError> {
        let mut s = self.lock()?;
        let s = &mut *s;
        // A consumer we do not know (new, or we restarted) numbers on from what it has seen.
        let d = s.consumers.entry(consumer).or_insert(Delivery { seq: received, unconfirmed: None });
        if let Some(x) = &d.unconfirmed {
            if received < d.seq {
                return Ok(Take::Item(d.seq, x.clone()));
            }
            d.unconfirmed = None;
        }
        if let Some(x) = s.items.pop_front() {
            d.seq += 1;
            d.unconfirmed = Some(x.clone());
            return Ok(Take::Item(d.seq, x));
        }
        Ok(if s.finished { Take::Finished } else { Take::Empty })
    }

    /// The next item for `consumer`, waiting up to `wait` (or until `stop` turns true).
    pub(crate) async fn take(
        &self,
        consumer: u64,
        received: u64,
        wait: Duration,
        mut stop: watch::Receiver<bool>,
    ) -> Result<Take<T>, TransportError> {
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            let ready = self.ready.notified();
            tokio::pin!(ready);
            ready.as_mut().enable();
            match self.try_take(consumer, received)? {
                Take::Empty => {}
                got => return Ok(got),
            }
            if *stop.borrow_and_update() {
                return Ok(Take::Empty);
            }
            tokio::select! {
                _ = ready => {}
                _ = stop.changed() => {}
                _ = tokio::time::sleep_until(deadline) => return Ok(Take::Empty),
            }
        }
    }
}
