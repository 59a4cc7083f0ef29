//! Channels between threads of one process: queues over `std::sync::mpsc`, topics over a
//! mutex-guarded `Arc` and a condition variable (a publish is one pointer swap; every reader
//! shares the same buffer).

use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use crate::links::{ActorLinks, LearnerLinks, OptimizerLinks};
use crate::messages::Weights;
use crate::traits::{Publisher, Receiver, Sender, Subscriber, TransportError, Versioned};

/// The sending end of an in-process queue; clone it for several producers.
#[derive(Debug)]
pub struct QueueSender<T>(mpsc::Sender<T>);

impl<T> Clone for QueueSender<T> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

/// The receiving end; clone it for several consumers sharing the work (each message goes to
/// one of them).
#[derive(Debug)]
pub struct QueueReceiver<T>(Arc<Mutex<mpsc::Receiver<T>>>);

impl<T> Clone for QueueReceiver<T> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

/// An ordered in-process queue.
pub fn queue<T>() -> (QueueSender<T>, QueueReceiver<T>) {
    let (tx, rx) = mpsc::channel();
    (QueueSender(tx), QueueReceiver(Arc::new(Mutex::new(rx))))
}

impl<T: Send> Sender<T> for QueueSender<T> {
    fn send(&mut self, msg: T) -> Result<(), TransportError> {
        self.0.send(msg).map_err(|_| TransportError::Closed)
    }
}

impl<T: Send> Receiver<T> for QueueReceiver<T> {
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<T>, TransportError> {
        let deadline = Instant::now() + timeout;
        // Consumers sharing the queue take turns; the lock is held only while waiting.
        let Ok(rx) = self.0.lock() else { return Err(TransportError::Io("queue lock poisoned".into())) };
        match rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            Ok(m) => Ok(Some(m)),
            Err(mpsc::RecvTimeoutError::Timeout) => Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(TransportError::Closed),
        }
    }
}

#[derive(Debug)]
struct Slot<T> {
    value: Option<Arc<T>>,
    publishers: usize,
}

#[derive(Debug)]
struct TopicShared<T> {
    slot: Mutex<Slot<T>>,
    changed: Condvar,
}

/// The writing end of an in-process latest-value topic.
#[derive(Debug)]
pub struct TopicPublisher<T>(Arc<TopicShared<T>>);

/// A reader of an in-process topic; clone for more readers.
#[derive(Debug)]
pub struct TopicSubscriber<T>(Arc<TopicShared<T>>);

impl<T> Clone for TopicSubscriber<T> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

/// A latest-value topic.
pub fn topic<T>() -> (TopicPublisher<T>, TopicSubscriber<T>) {
    let shared = Arc::new(TopicShared { slot: Mutex::new(Slot { value: None, publishers: 1 }), changed: Condvar::new() });
    (TopicPublisher(shared.clone()), TopicSubscriber(shared))
}

impl<T> Drop for TopicPublisher<T> {
    fn drop(&mut self) {
        if let Ok(mut s) = self.0.slot.lock() {
            s.publishers -= 1;
        }
        self.0.changed.notify_all();
    }
}

impl<T: Versioned + Send + Sync> Publisher<T> for TopicPublisher<T> {
    fn publish(&mut self, msg: T) -> Result<(), TransportError> {
        let Ok(mut s) = self.0.slot.lock() else { return Err(TransportError::Io("topic lock poisoned".into())) };
        if let Some(old) = &s.value
            && msg.version() <= old.version()
        {
            return Err(TransportError::Invalid(format!("version {} after {}", msg.version(), old.version())));
        }
        s.value = Some(Arc::new(msg));
        drop(s);
        self.0.changed.notify_all();
        Ok(())
    }
}

impl<T: Versioned + Send + Sync> Subscriber<T> for TopicSubscriber<T> {
    fn wait_for(&mut self, min_version: u64, timeout: Duration) -> Result<Option<Arc<T>>, TransportError> {
        let deadline = Instant::now() + timeout;
        let Ok(mut s) = self.0.slot.lock() else { return Err(TransportError::Io("topic lock poisoned".into())) };
        loop {
            if let Some(v) = &s.value
                && v.version() >= min_version
            {
                return Ok(Some(v.clone()));
            }
            if s.publishers == 0 {
                return Err(TransportError::Closed);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            s = match self.0.changed.wait_timeout(s, left) {
                Ok((g, _)) => g,
                Err(_) => return Err(TransportError::Io("topic lock poisoned".into())),
            };
        }
    }
}

/// The channels of a whole in-process fleet: one learner, `actors` actors sharing one
/// assignment queue, one optimiser.
pub fn fleet(actors: usize) -> (LearnerLinks, Vec<ActorLinks>, OptimizerLinks) {
    let (exp_tx, exp_rx) = queue();
    let (asg_tx, asg_rx) = queue();
    let (acting_pub, acting_sub) = topic::<Weights>();
    let (pop_pub, pop_sub) = topic::<Weights>();
    let (req_tx, req_rx) = queue();
    let (rep_tx, rep_rx) = queue();
    let learner = LearnerLinks {
        experience: Box::new(exp_rx),
        assignments: Box::new(asg_tx),
        acting_weights: Box::new(acting_pub),
        population_weights: Box::new(pop_pub),
        design_requests: Box::new(req_tx),
        design_replies: Box::new(rep_rx),
    };
    let actors = (0..actors)
        .map(|_| ActorLinks {
            assignments: Box::new(asg_rx.clone()),
            weights: Box::new(acting_sub.clone()),
            experience: Box::new(exp_tx.clone()),
        })
        .collect();
    let optimizer = OptimizerLinks { requests: Box::new(req_rx), replies: Box::new(rep_tx), weights: Box::new(pop_sub) };
    (learner, actors, optimizer)
}
