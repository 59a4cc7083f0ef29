//! [`Outbox`]: the learner's work, long-polled by consumers.

use std::collections::{HashMap, VecDeque};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use coadapt_transport::TransportError;
use tokio::sync::{Notify, watch};

use super::poisoned;

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

    /// Forgets a consumer that fell silent; its unconfirmed delivery is dropped (the learner
    /// issues work again after its lease, as for a crashed client).
    pub(crate) fn forget(&self, consumer: u64) {
        if let Ok(mut s) = self.state.lock() {
            s.consumers.remove(&consumer);
        }
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
    /// A new consumer of a queue served by one consumer at a time (the design requests: one
    /// optimiser per fleet): a copy of what the others hold unconfirmed goes to the front for
    /// it. A consumer that was restarted gets the work its dead predecessor had taken at once,
    /// not after the learner's resend deadline nor after the dead session is forgotten; should
    /// the holder be alive after all, both answer and the learner takes the first answer.
    /// Returns how many items were offered.
    pub(crate) fn offer_held_to(&self, newcomer: u64) -> usize {
        let Ok(mut s) = self.state.lock() else { return 0 };
        let s = &mut *s;
        let mut held: Vec<(u64, T)> =
            s.consumers.iter().filter(|(c, _)| **c != newcomer).filter_map(|(_, d)| d.unconfirmed.clone().map(|x| (d.seq, x))).collect();
        held.sort_by_key(|(seq, _)| *seq);
        let n = held.len();
        for (_, x) in held.into_iter().rev() {
            s.items.push_front(x);
        }
        if n > 0 {
            self.ready.notify_waiters();
        }
        n
    }

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
