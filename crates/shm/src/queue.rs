//! Ordered, lossless queues: many senders, one receiver, over one publish-subscribe service
//! with safe overflow off, plus event services that wake whoever waits (`<name>/to-rx`: data
//! for the receiver, and a sender's departure; `<name>/to-tx`: "receiver here" and "space
//! freed" for blocked senders; `<name>/bye/<sender>`: "I have taken all you sent").
//!
//! Three iceoryx2 behaviours shape this:
//! - a publisher's samples are dropped while no subscriber is registered, so a sender's first
//!   send waits (bounded by the connect timeout) for the receiver;
//! - a subscriber registers before it connects (on its first receive); while it has not
//!   connected, a full buffer makes iceoryx2 drop the sample and report no recipient, so the
//!   sender waits for "space freed" and sends again;
//! - samples live in the sender's memory, which goes with its publisher: a receiver that has
//!   not mapped it yet would lose them. So a departing sender sends a goodbye sample and keeps
//!   its publisher until the receiver acknowledges it (in a background thread when the
//!   receiver is in this process, maybe on this very thread; bounded by the connect timeout).
//!
//! A full buffer blocks the sender inside iceoryx2's retry loop, whose backpressure handler
//! sleeps on "space freed" instead of spinning. The receiver counts live senders by their
//! notifiers on `to-rx`: a departing sender drops it at once, and dead-node cleanup removes a
//! killed sender's.

use std::marker::PhantomData;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_transport::{Receiver, Sender, TransportError};
use coadapt_wire::Limits;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo, SendError};
use iceoryx2::prelude::*;

use crate::codec::Codec;
use crate::ipc::{self, CLEANUP_EVERY, DATA, GOODBYE, Janitor, Listener, Notifier, PubSub, PubSubShape, Publisher, Subscriber, Svc, io};

/// Sizes shared by both ends of a queue; every process must use the same ones.
#[derive(Debug, Clone, Copy)]
pub(crate) struct QueueShape {
    /// Senders (and nodes) the service admits.
    pub peers: usize,
    /// Messages the receiver's buffer holds before senders block.
    pub depth: usize,
}

struct Services {
    data: PubSub,
    to_rx: ipc::Event,
    to_tx: ipc::Event,
}

fn open(node: &Node<Svc>, name: &str, s: QueueShape) -> Result<Services, TransportError> {
    let shape = PubSubShape { publishers: s.peers, subscribers: 1, nodes: s.peers + 2, buffer: s.depth, topic: false };
    Ok(Services {
        data: ipc::pubsub(node, name, shape)?,
        to_rx: ipc::event(node, &format!("{name}/to-rx"), s.peers + 2)?,
        to_tx: ipc::event(node, &format!("{name}/to-tx"), s.peers + 2)?,
    })
}

fn bye_name(queue: &str, sender: u128) -> String {
    format!("{queue}/bye/{sender:x}")
}

/// Samples start this small and grow by powers of two as messages need.
pub(crate) const INITIAL_SLICE: usize = 4096;

/// The sending end of a shared-memory queue.
#[derive(Debug)]
pub struct QueueSender<T> {
    /// Taken by `drop`, which may hand it to a thread that waits for the goodbye's receipt.
    publisher: Option<Publisher>,
    wake: Notifier,
    space: Arc<Listener>,
    bye: Option<Listener>,
    service: Arc<PubSub>,
    /// Makes a send blocked on a full buffer give up (set while dropping).
    leaving: Arc<AtomicBool>,
    name: String,
    connected: bool,
    sent: bool,
    connect_timeout: Duration,
    max_bytes: usize,
    janitor: Janitor,
    _msg: PhantomData<fn(T)>,
}

impl<T: Codec> QueueSender<T> {
    pub(crate) fn open(
        node: &Node<Svc>,
        name: &str,
        shape: QueueShape,
        connect_timeout: Duration,
        max_bytes: usize,
    ) -> Result<Self, TransportError> {
        let s = open(node, name, shape)?;
        let service = Arc::new(s.data);
        let space = Arc::new(ipc::listener(&s.to_tx)?);
        let leaving = Arc::new(AtomicBool::new(false));
        let (svc, wait_on, give_up) = (service.clone(), space.clone(), leaving.clone());
        // Called by iceoryx2 while the receiver's buffer is full: sleep until the receiver
        // frees space; give up only when it has gone (a killed one after cleanup), or when
        // this sender is being dropped and has waited long enough.
        let handler = move |info: &BackpressureInfo| {
            if info.retries % 10 == 9 {
                svc.try_cleanup_dead_nodes();
                if svc.dynamic_config().number_of_subscribers() == 0
                    || give_up.load(Ordering::Relaxed) && info.elapsed_time > connect_timeout
                {
                    return BackpressureAction::DiscardDataAndFail;
                }
            }
            let _ = wait_on.timed_wait(|_| {}, CLEANUP_EVERY / 10);
            BackpressureAction::Retry
        };
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(INITIAL_SLICE)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(handler)
            .create()
            .map_err(|e| io(&format!("creating a publisher on {name}"), e))?;
        let bye = ipc::listener(&ipc::event(node, &bye_name(name, publisher.id().value()), 4)?)?;
        Ok(Self {
            publisher: Some(publisher),
            wake: ipc::notifier(&s.to_rx)?,
            space,
            bye: Some(bye),
            service,
            leaving,
            name: name.to_owned(),
            connected: false,
            sent: false,
            connect_timeout,
            max_bytes,
            janitor: Janitor::new(),
            _msg: PhantomData,
        })
    }

    /// Waits up to `wait` for the receiver to be there and connects to it; `false` if it did
    /// not come.
    pub(crate) fn try_connect(&mut self, wait: Duration) -> Result<bool, TransportError> {
        let deadline = Instant::now() + wait;
        loop {
            if self.service.dynamic_config().number_of_subscribers() > 0 {
                self.publisher()?.update_connections().map_err(|e| io(&format!("connecting to the receiver of {}", self.name), e))?;
                self.connected = true;
                return Ok(true);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(false);
            }
            ipc::wait(&self.space, left.min(CLEANUP_EVERY))?;
        }
    }

    /// Whether the receiver, once connected, has gone (killed ones included, after cleanup).
    pub(crate) fn receiver_gone(&mut self) -> bool {
        self.janitor.sweep(self.service.as_ref());
        self.connected && self.service.dynamic_config().number_of_subscribers() == 0
    }

    pub(crate) fn is_connected(&self) -> bool {
        self.connected
    }
}

// Needs no `T: Codec`: `drop` sends a goodbye through it.
impl<T> QueueSender<T> {
    fn publisher(&self) -> Result<&Publisher, TransportError> {
        self.publisher.as_ref().ok_or(TransportError::Closed)
    }

    /// Loans a sample, lets `msg` encode itself into it and sends it; the number of receivers
    /// that got it.
    fn send_once(&self, msg: &impl Codec, kind: u64) -> Result<usize, TransportError> {
        let mut sample = ipc::loan_encoded(self.publisher()?, msg, self.max_bytes)?;
        *sample.user_header_mut() = kind;
        match sample.send() {
            Ok(n) => Ok(n),
            Err(SendError::UnableToDeliver) => Ok(0),
            Err(e) => Err(io(&format!("sending on {}", self.name), e)),
        }
    }

    fn deliver(&mut self, msg: &impl Codec, kind: u64) -> Result<(), TransportError> {
        loop {
            if self.send_once(msg, kind)? > 0 {
                self.sent = true;
                return self.wake.notify().map(|_| ()).map_err(|e| io("waking the receiver", e));
            }
            // Not delivered: the receiver has gone, or has registered but not yet connected
            // and its buffer is full; then wait until it takes something.
            self.janitor.sweep(self.service.as_ref());
            if self.service.dynamic_config().number_of_subscribers() == 0 || self.leaving.load(Ordering::Relaxed) {
                return Err(TransportError::Closed);
            }
            ipc::wait(&self.space, CLEANUP_EVERY / 10)?;
        }
    }
}

/// The goodbye sample: one byte, no message (its kind is in the header).
struct Goodbye;

impl Codec for Goodbye {
    fn write_with<'a>(&self, loan: impl FnOnce(usize) -> Result<&'a mut [u8], TransportError>) -> Result<(), TransportError> {
        loan(1).map(|b| b.fill(0))
    }

    fn decode_from(_: &[u8], _: &Limits) -> Result<Self, coadapt_wire::WireError> {
        Ok(Goodbye)
    }
}

impl<T> Drop for QueueSender<T> {
    fn drop(&mut self) {
        if self.publisher.is_none() || !self.sent || self.service.dynamic_config().number_of_subscribers() == 0 {
            return;
        }
        self.leaving.store(true, Ordering::Relaxed);
        let local = ipc::subscribers_are_local(&self.service);
        let said = self.deliver(&Goodbye, GOODBYE);
        let (Some(publisher), Some(bye)) = (self.publisher.take(), self.bye.take()) else { return };
        if said.is_err() {
            return;
        }
        let (service, timeout) = (self.service.clone(), self.connect_timeout);
        let linger = move || {
            let deadline = Instant::now() + timeout;
            while Instant::now() < deadline && service.dynamic_config().number_of_subscribers() > 0 {
                match bye.timed_wait(|_| {}, CLEANUP_EVERY) {
                    Ok(n) if n > 0 => break,
                    Ok(_) => service.try_cleanup_dead_nodes(),
                    Err(_) => break,
                };
            }
            drop(publisher);
        };
        if local {
            // The receiver may be this very thread, once this drop has returned.
            if std::thread::Builder::new().name("shm-linger".into()).spawn(linger).is_err() {
                coadapt_log::logln!("coadapt-shm: no thread to keep {}'s last messages until they are taken; they may be lost", self.name);
            }
        } else {
            linger();
        }
    }
}

impl<T: Codec> Sender<T> for QueueSender<T> {
    fn send(&mut self, msg: T) -> Result<(), TransportError> {
        if !self.connected && !self.try_connect(self.connect_timeout)? {
            return Err(TransportError::Closed);
        }
        self.deliver(&msg, DATA)
    }
}

/// The receiving end of a shared-memory queue.
#[derive(Debug)]
pub struct QueueReceiver<T> {
    subscriber: Subscriber,
    data: Listener,
    space: Notifier,
    service: PubSub,
    senders: ipc::Event,
    /// Opens the services that acknowledge goodbyes.
    node: Node<Svc>,
    name: String,
    limits: Limits,
    /// A sender has been seen; before that, no sender means "not started yet", not "closed".
    seen_sender: bool,
    /// The senders' notifier ids at the last look, and how many have gone from that list
    /// since the receiver opened (a sender killed and restarted between two looks still
    /// counts: its id is new).
    sender_ids: Vec<u128>,
    sender_ids_now: Vec<u128>,
    departures: u64,
    unannounced: usize,
    announce_every: usize,
    janitor: Janitor,
    _msg: PhantomData<fn() -> T>,
}

impl<T: Codec> QueueReceiver<T> {
    pub(crate) fn open(name: &str, shape: QueueShape, limits: Limits) -> Result<Self, TransportError> {
        let node = ipc::node("coadapt-receiver")?;
        let s = open(&node, name, shape)?;
        let subscriber = s
            .data
            .subscriber_builder()
            .buffer_size(shape.depth)
            .create()
            .map_err(|e| io(&format!("creating the receiver of {name} (is another receiver running?)"), e))?;
        let data = ipc::listener(&s.to_rx)?;
        let space = ipc::notifier(&s.to_tx)?;
        // Senders waiting to connect learn that the receiver is here.
        space.notify().map_err(|e| io("announcing the receiver", e))?;
        Ok(Self {
            seen_sender: s.to_rx.dynamic_config().number_of_notifiers() > 0,
            sender_ids: notifier_ids(&s.to_rx, Vec::with_capacity(shape.peers)),
            sender_ids_now: Vec::with_capacity(shape.peers),
            departures: 0,
            subscriber,
            data,
            space,
            service: s.data,
            senders: s.to_rx,
            node,
            name: name.to_owned(),
            limits,
            unannounced: 0,
            announce_every: (shape.depth / 4).max(1),
            janitor: Janitor::new(),
            _msg: PhantomData,
        })
    }

    /// Tells blocked senders there is room.
    fn announce_space(&mut self) -> Result<(), TransportError> {
        self.unannounced = 0;
        self.space.notify().map(|_| ()).map_err(|e| io("waking blocked senders", e))
    }

    fn acknowledge_goodbye(&self, sender: u128) {
        let ack = ipc::event(&self.node, &bye_name(&self.name, sender), 4).and_then(|ev| ipc::notifier(&ev));
        if let Err(e) = ack.and_then(|n| n.notify().map_err(|e| io("acknowledging a goodbye", e))) {
            coadapt_log::logln!("coadapt-shm: {}: {e}", self.name);
        }
    }

    /// The live senders now, counting those gone since the last look as departures.
    fn count_senders(&mut self) -> usize {
        let now = notifier_ids(&self.senders, std::mem::take(&mut self.sender_ids_now));
        self.departures += self.sender_ids.iter().filter(|id| !now.contains(id)).count() as u64;
        self.sender_ids_now = std::mem::replace(&mut self.sender_ids, now);
        self.sender_ids.len()
    }

    /// The next message within `timeout`. With `report_closed`, `Err(Closed)` once every
    /// sender has gone and the buffer is drained; without, it keeps waiting for new senders.
    pub(crate) fn next(&mut self, timeout: Duration, report_closed: bool) -> Result<Option<T>, TransportError> {
        let deadline = Instant::now() + timeout;
        loop {
            // Senders are counted before looking at the buffer: whatever a sender that has
            // gone by now sent (its goodbye included) is already in it.
            let senders = self.count_senders();
            self.seen_sender |= senders > 0;
            let received = self.subscriber.receive().map_err(|e| io(&format!("receiving on {}", self.name), e))?;
            if let Some(sample) = received {
                self.seen_sender = true;
                self.unannounced += 1;
                if self.unannounced >= self.announce_every {
                    self.announce_space()?;
                }
                if *sample.user_header() == GOODBYE {
                    let origin = sample.origin().value();
                    drop(sample);
                    self.acknowledge_goodbye(origin);
                    continue;
                }
                let decoded = T::decode_from(sample.payload(), &self.limits);
                drop(sample);
                match decoded {
                    Ok(m) => return Ok(Some(m)),
                    Err(e) => {
                        coadapt_log::logln!("coadapt-shm: dropped a malformed message on {}: {e}", self.name);
                        continue;
                    }
                }
            }
            if self.unannounced > 0 {
                self.announce_space()?;
            }
            if report_closed && senders == 0 && self.seen_sender {
                return Err(TransportError::Closed);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.janitor.sweep(&self.service);
            ipc::wait(&self.data, left.min(CLEANUP_EVERY))?;
        }
    }
}

impl<T: Codec> Receiver<T> for QueueReceiver<T> {
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<T>, TransportError> {
        self.next(timeout, true)
    }

    fn departures(&self) -> u64 {
        self.departures
    }
}

/// The ids of the notifiers on an event service (a queue's senders on its `to-rx`), into
/// `ids` (cleared first; its capacity is reused, so a poll does not allocate).
fn notifier_ids(event: &ipc::Event, mut ids: Vec<u128>) -> Vec<u128> {
    ids.clear();
    event.dynamic_config().list_notifiers(|d| {
        ids.push(d.notifier_id.value());
        CallbackProgression::Continue
    });
    ids
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::Credit;
    use coadapt_transport::ExperienceChunk;
    use coadapt_transport::conformance::chunk;

    #[test]
    fn a_malformed_message_is_dropped_and_the_receiver_goes_on() {
        let name = format!("coadapt-test-{}-malformed/q", std::process::id());
        let shape = QueueShape { peers: 4, depth: 8 };
        let mut rx = QueueReceiver::<ExperienceChunk>::open(&name, shape, Limits::default()).expect("receiver");
        let node = ipc::node("coadapt-test").expect("node");
        let wait = Duration::from_secs(5);
        // Eight 0xff bytes are no protobuf message (an unterminated varint).
        let mut garbage = QueueSender::<Credit>::open(&node, &name, shape, wait, 1024).expect("sender");
        let mut good = QueueSender::<ExperienceChunk>::open(&node, &name, shape, wait, 1024).expect("sender");
        garbage.send(Credit(u64::MAX)).expect("send");
        good.send(chunk(3)).expect("send");
        assert_eq!(rx.recv_timeout(wait).expect("receive"), Some(chunk(3)));
    }

    /// A sender replaced between two receives (a restarted peer) never shows as zero senders,
    /// so the receiver does not report the queue closed; it counts the departure instead.
    #[test]
    fn a_sender_replaced_between_two_receives_counts_as_a_departure() {
        let name = format!("coadapt-test-{}-replaced/q", std::process::id());
        let shape = QueueShape { peers: 4, depth: 8 };
        let mut rx = QueueReceiver::<ExperienceChunk>::open(&name, shape, Limits::default()).expect("receiver");
        let node = ipc::node("coadapt-test").expect("node");
        let wait = Duration::from_secs(5);
        let mut first = QueueSender::<ExperienceChunk>::open(&node, &name, shape, wait, 1024).expect("sender");
        first.send(chunk(3)).expect("send");
        assert_eq!(rx.recv_timeout(wait).expect("receive"), Some(chunk(3)));
        assert_eq!(rx.departures(), 0);
        drop(first);
        let mut second = QueueSender::<ExperienceChunk>::open(&node, &name, shape, wait, 1024).expect("sender");
        second.send(chunk(4)).expect("send");
        assert_eq!(rx.recv_timeout(wait).expect("receive"), Some(chunk(4)));
        assert_eq!(rx.departures(), 1);
        assert_eq!(rx.recv_timeout(Duration::from_millis(50)).expect("still open"), None);
        assert_eq!(rx.departures(), 1);
    }
}
