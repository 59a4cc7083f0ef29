//! The work-sharing assignment queue: each assignment goes to exactly one actor.
//!
//! Publish-subscribe delivers to every subscriber, so work is shared by credits: an actor that
//! wants an episode sends its id on `<name>/ready` (one credit outstanding at a time), and a
//! pump thread behind the learner's [`AssignmentSender`] pairs each assignment with one credit
//! and sends it on that actor's own queue `<name>/to/<id>`. An actor's queue admits one
//! receiver, so two actors with the same id cannot both take an assignment. An assignment
//! handed to an actor that then dies is lost (the learner re-issues it after a lease); one
//! whose actor vanished before it was sent goes to the next credit.

use std::collections::{HashMap, VecDeque};
use std::sync::mpsc::{self, RecvTimeoutError, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use coadapt_transport::{Assignment, Receiver, Sender, TransportError};
use coadapt_wire::Limits;
use iceoryx2::prelude::*;

use crate::codec::Credit;
use crate::ipc::{self, Svc};
use crate::queue::{QueueReceiver, QueueSender, QueueShape};

/// Settings both sides must agree on.
#[derive(Debug, Clone)]
pub(crate) struct WorkShape {
    pub name: String,
    pub actors: usize,
    pub connect_timeout: Duration,
    pub max_bytes: usize,
}

impl WorkShape {
    fn ready(&self) -> (String, QueueShape) {
        // Every actor has at most one credit outstanding, so credit senders never block.
        (format!("{}/ready", self.name), QueueShape { peers: self.actors, depth: self.actors + 4 })
    }

    fn inbox(&self, actor: u64) -> (String, QueueShape) {
        (format!("{}/to/{actor}", self.name), QueueShape { peers: 2, depth: 4 })
    }
}

/// The learner's end: `send` hands the assignment to the pump and returns at once.
#[derive(Debug)]
pub struct AssignmentSender {
    tx: mpsc::Sender<Assignment>,
    failure: Arc<Mutex<Option<String>>>,
}

impl AssignmentSender {
    pub(crate) fn open(shape: WorkShape) -> Result<Self, TransportError> {
        let (ready, qs) = shape.ready();
        // Created here, not in the pump, so actors can connect as soon as this returns.
        let credits = QueueReceiver::<Credit>::open(&ready, qs, Limits { max_message_bytes: 8 })?;
        let (tx, rx) = mpsc::channel();
        let failure = Arc::new(Mutex::new(None));
        let fail = failure.clone();
        std::thread::Builder::new()
            .name(format!("shm-pump:{}", shape.name))
            .spawn(move || {
                if let Err(e) = pump(rx, credits, &shape)
                    && let Ok(mut f) = fail.lock()
                {
                    coadapt_log::logln!("coadapt-shm: assignment pump of {} stopped: {e}", shape.name);
                    *f = Some(e.to_string());
                }
            })
            .map_err(|e| ipc::io("starting the assignment pump", e))?;
        Ok(Self { tx, failure })
    }
}

impl Sender<Assignment> for AssignmentSender {
    fn send(&mut self, msg: Assignment) -> Result<(), TransportError> {
        if let Ok(f) = self.failure.lock()
            && let Some(e) = f.as_ref()
        {
            return Err(TransportError::Io(format!("assignment pump failed: {e}")));
        }
        self.tx.send(msg).map_err(|_| TransportError::Closed)
    }
}

/// Pairs assignments with credits until the learner has dropped its sender and everything it
/// sent is handed out (or no actor asks for `connect_timeout`).
fn pump(rx: mpsc::Receiver<Assignment>, mut credits: QueueReceiver<Credit>, shape: &WorkShape) -> Result<(), TransportError> {
    let node = ipc::node("coadapt-assignment-pump")?;
    let mut pending: VecDeque<Assignment> = VecDeque::new();
    let mut ready: VecDeque<u64> = VecDeque::new();
    let mut inboxes: HashMap<u64, QueueSender<Assignment>> = HashMap::new();
    let mut learner_open = true;
    let mut last_credit = Instant::now();
    loop {
        loop {
            match rx.try_recv() {
                Ok(a) => pending.push_back(a),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    learner_open = false;
                    break;
                }
            }
        }
        if pending.is_empty() {
            if !learner_open {
                return Ok(());
            }
            // Credits wait in their queue meanwhile; only new work can change anything.
            match rx.recv_timeout(Duration::from_secs(1)) {
                Ok(a) => pending.push_back(a),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => learner_open = false,
            }
            continue;
        }
        let Some(actor) = ready.pop_front() else {
            if !learner_open && last_credit.elapsed() > shape.connect_timeout {
                return Ok(());
            }
            // Waiting for new work is pointless while there is some; wait for an actor.
            if let Some(Credit(id)) = credits.next(Duration::from_millis(200), false)? {
                ready.push_back(id);
                last_credit = Instant::now();
            }
            continue;
        };
        let (name, qs) = shape.inbox(actor);
        let inbox = match inboxes.entry(actor) {
            std::collections::hash_map::Entry::Occupied(o) => o.into_mut(),
            std::collections::hash_map::Entry::Vacant(v) => {
                v.insert(QueueSender::open(&node, &name, qs, shape.connect_timeout, shape.max_bytes)?)
            }
        };
        let Some(a) = pending.pop_front() else { continue };
        // The actor's receiver was created before it sent its credit, so it is either there
        // now or gone for good: no waiting.
        let sent =
            if inbox.is_connected() || inbox.try_connect(Duration::ZERO)? { inbox.send(a.clone()) } else { Err(TransportError::Closed) };
        match sent {
            Ok(()) => {}
            Err(TransportError::Closed) => {
                pending.push_front(a);
                inboxes.remove(&actor);
            }
            Err(e) => return Err(e),
        }
    }
}

/// An actor's end: asks for one assignment at a time.
#[derive(Debug)]
pub struct AssignmentReceiver {
    inbox: QueueReceiver<Assignment>,
    credits: QueueSender<Credit>,
    actor: u64,
    asked: bool,
    created: Instant,
    connect_timeout: Duration,
}

impl AssignmentReceiver {
    pub(crate) fn open(node: &Node<Svc>, shape: &WorkShape, actor: u64) -> Result<Self, TransportError> {
        let (name, qs) = shape.inbox(actor);
        let inbox = QueueReceiver::open(&name, qs, Limits { max_message_bytes: shape.max_bytes })
            .map_err(|e| TransportError::Invalid(format!("actor id {actor} is already in use? {e}")))?;
        let (ready, rs) = shape.ready();
        let credits = QueueSender::open(node, &ready, rs, shape.connect_timeout, 8)?;
        Ok(Self { inbox, credits, actor, asked: false, created: Instant::now(), connect_timeout: shape.connect_timeout })
    }
}

impl Receiver<Assignment> for AssignmentReceiver {
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<Assignment>, TransportError> {
        let deadline = Instant::now() + timeout;
        if !self.asked {
            if !self.credits.is_connected() && !self.credits.try_connect(timeout)? {
                // No learner yet: the caller retries, until the connect timeout says it is not coming.
                return if self.created.elapsed() > self.connect_timeout { Err(TransportError::Closed) } else { Ok(None) };
            }
            self.credits.send(Credit(self.actor))?;
            self.asked = true;
        }
        match self.inbox.recv_timeout(deadline.saturating_duration_since(Instant::now()))? {
            Some(a) => {
                self.asked = false;
                Ok(Some(a))
            }
            None if self.credits.receiver_gone() => Err(TransportError::Closed),
            None => Ok(None),
        }
    }
}
