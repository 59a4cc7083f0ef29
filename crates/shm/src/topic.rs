//! Latest-value topics over one publish-subscribe service with safe overflow on, a history of
//! one and a one-sample buffer per reader: a publish overwrites what a slow reader has not
//! taken, and one loaned sample serves every reader (no copy per reader).
//!
//! Two event services: `<name>/ev` wakes readers (new value; the publisher's goodbye or, after
//! cleanup, its death), `<name>/join` tells the publisher a reader has arrived. iceoryx2 hands
//! a late reader the history only when the publisher next updates its connections, so the
//! publisher keeps a small thread that does that on every `join`.

use std::marker::PhantomData;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use coadapt_transport::traits::Versioned;
use coadapt_transport::{Publisher, Subscriber, TransportError};
use coadapt_wire::Limits;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

use crate::codec::Codec;
use crate::ipc::{self, CLEANUP_EVERY, Janitor, Listener, Notifier, PubSub, PubSubShape, Svc, io};
use crate::queue::INITIAL_SLICE;

fn open(node: &Node<Svc>, name: &str, readers: usize) -> Result<(PubSub, ipc::Event, ipc::Event), TransportError> {
    // Two publishers: a restarted publisher can take over before the dead one is cleaned up.
    let shape = PubSubShape { publishers: 2, subscribers: readers, nodes: readers + 4, buffer: 1, topic: true };
    Ok((
        ipc::pubsub(node, name, shape)?,
        ipc::event(node, &format!("{name}/ev"), readers + 4)?,
        ipc::event(node, &format!("{name}/join"), readers + 4)?,
    ))
}

#[derive(Debug)]
struct Shared {
    // Drop order: the publisher before the notifier whose goodbye wakes the readers.
    publisher: ipc::Publisher,
    wake: Notifier,
}

/// The writing end of a shared-memory topic.
#[derive(Debug)]
pub struct TopicPublisher<T> {
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    nudge: Notifier,
    helper: Option<JoinHandle<()>>,
    name: String,
    last_version: Option<u64>,
    max_bytes: usize,
    _msg: PhantomData<fn(T)>,
}

impl<T: Codec + Versioned> TopicPublisher<T> {
    pub(crate) fn open(node: &Node<Svc>, name: &str, readers: usize, max_bytes: usize) -> Result<Self, TransportError> {
        let (service, ev, join) = open(node, name, readers)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(INITIAL_SLICE)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| io(&format!("creating the publisher of {name} (is another one running?)"), e))?;
        let shared = Arc::new(Shared { publisher, wake: ipc::notifier(&ev)? });
        let joins = ipc::listener(&join)?;
        let stop = Arc::new(AtomicBool::new(false));
        let (s, st) = (shared.clone(), stop.clone());
        let helper = std::thread::Builder::new()
            .name(format!("shm-join:{name}"))
            .spawn(move || {
                while !st.load(Ordering::Acquire) {
                    if joins.timed_wait(|_| {}, Duration::from_secs(1)).is_err() || st.load(Ordering::Acquire) {
                        continue;
                    }
                    // Delivers the history (the current value) to readers that just arrived.
                    if s.publisher.update_connections().is_ok() {
                        let _ = s.wake.notify();
                    }
                }
            })
            .map_err(|e| io("starting the topic's join thread", e))?;
        Ok(Self {
            shared,
            stop,
            nudge: ipc::notifier(&join)?,
            helper: Some(helper),
            name: name.to_owned(),
            last_version: None,
            max_bytes,
            _msg: PhantomData,
        })
    }
}

impl<T> Drop for TopicPublisher<T> {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        let _ = self.nudge.notify();
        if let Some(h) = self.helper.take() {
            let _ = h.join();
        }
    }
}

impl<T: Codec + Versioned> Publisher<T> for TopicPublisher<T> {
    fn publish(&mut self, msg: T) -> Result<(), TransportError> {
        let v = msg.version();
        if let Some(last) = self.last_version
            && v <= last
        {
            return Err(TransportError::Invalid(format!("{}: version {v} after {last}", self.name)));
        }
        let sample = ipc::loan_encoded(&self.shared.publisher, &msg, self.max_bytes)?;
        sample.send().map_err(|e| io(&format!("publishing on {}", self.name), e))?;
        self.last_version = Some(v);
        self.shared.wake.notify().map_err(|e| io("waking readers", e))?;
        Ok(())
    }
}

/// A reader of a shared-memory topic; it decodes each new version once and shares it.
#[derive(Debug)]
pub struct TopicSubscriber<T> {
    subscriber: ipc::Subscriber,
    ev: Listener,
    service: PubSub,
    name: String,
    limits: Limits,
    newest: Option<Arc<T>>,
    seen_publisher: bool,
    janitor: Janitor,
}

impl<T: Codec + Versioned> TopicSubscriber<T> {
    pub(crate) fn open(node: &Node<Svc>, name: &str, readers: usize, limits: Limits) -> Result<Self, TransportError> {
        let (service, ev, join) = open(node, name, readers)?;
        let subscriber = service.subscriber_builder().create().map_err(|e| io(&format!("creating a reader of {name}"), e))?;
        let ev = ipc::listener(&ev)?;
        // A publisher that is already there delivers the current value when it hears this.
        ipc::notifier(&join)?.notify().map_err(|e| io("announcing a reader", e))?;
        Ok(Self {
            seen_publisher: service.dynamic_config().number_of_publishers() > 0,
            subscriber,
            ev,
            service,
            name: name.to_owned(),
            limits,
            newest: None,
            janitor: Janitor::new(),
        })
    }

    /// Takes what has arrived, decoding only the newest sample and only if it is newer.
    fn take_newest(&mut self) -> Result<(), TransportError> {
        let mut last = None;
        while let Some(s) = self.subscriber.receive().map_err(|e| io(&format!("receiving on {}", self.name), e))? {
            last = Some(s);
        }
        let Some(sample) = last else { return Ok(()) };
        match T::decode_from(sample.payload(), &self.limits) {
            Ok(m) if self.newest.as_ref().is_none_or(|n| m.version() > n.version()) => self.newest = Some(Arc::new(m)),
            Ok(_) => {}
            Err(e) => coadapt_log::logln!("coadapt-shm: dropped a malformed message on {}: {e}", self.name),
        }
        Ok(())
    }
}

impl<T: Codec + Versioned + Sync> Subscriber<T> for TopicSubscriber<T> {
    fn wait_for(&mut self, min_version: u64, timeout: Duration) -> Result<Option<Arc<T>>, TransportError> {
        let deadline = Instant::now() + timeout;
        loop {
            let publishers = self.service.dynamic_config().number_of_publishers();
            self.seen_publisher |= publishers > 0;
            self.take_newest()?;
            if let Some(n) = &self.newest
                && n.version() >= min_version
            {
                return Ok(Some(n.clone()));
            }
            if publishers == 0 && self.seen_publisher {
                return Err(TransportError::Closed);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.janitor.sweep(&self.service);
            ipc::wait(&self.ev, left.min(CLEANUP_EVERY))?;
        }
    }
}
