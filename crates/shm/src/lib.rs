//! coadapt's roles over iceoryx2 shared memory, for a fleet on one machine: weights are
//! published once into a loaned shared-memory sample that every actor reads (no copy per
//! actor), experience and design requests travel through lossless ordered queues, and readers
//! sleep on iceoryx2 events, never spinning.
//!
//! # Layout
//! - [`codec`]: the bytes of a sample: coadapt-wire's protobuf schema (the same as gRPC's),
//!   written straight into the loaned slice and validated on the way out ([`codec::Codec`]).
//! - `ipc`: iceoryx2 plumbing: thread-safe service flavour (links are `Send`), nodes, opening
//!   services with settings all parties agree on, dead-node cleanup.
//! - [`queue`]: [`QueueSender`]/[`QueueReceiver`]: many-to-one, lossless, ordered, with a
//!   connect handshake and blocking backpressure.
//! - [`topic`]: [`TopicPublisher`]/[`TopicSubscriber`]: newest value, history of one for late
//!   readers, versions only move forward.
//! - [`work`]: the work-sharing assignment queue (credits from actors, a pump in the learner).
//! - this file: [`ShmConfig`], the six channels of a fleet bundled per role
//!   ([`learner_links`], [`actor_links`], [`optimizer_links`]), single channels by name for tests
//!   and benchmarks, and [`cleanup_stale`].
//!
//! Every process of a fleet must use the same `fleet` name, `max_actors` and `queue_depth`:
//! iceoryx2 refuses to open a service with settings that differ from its creator's.

pub mod codec;
mod ipc;
pub mod queue;
pub mod topic;
pub mod work;

use std::time::Duration;

use coadapt_transport::traits::Versioned;
use coadapt_transport::{ActorLinks, LearnerLinks, OptimizerLinks, TransportError, Weights};
use coadapt_wire::Limits;

pub use codec::Codec;
pub use queue::{QueueReceiver, QueueSender};
pub use topic::{TopicPublisher, TopicSubscriber};
pub use work::{AssignmentReceiver, AssignmentSender};

/// How a fleet's processes find each other and size their shared memory.
#[derive(Debug, Clone)]
pub struct ShmConfig {
    /// Prefix of every service name: processes with the same prefix form one fleet.
    pub fleet: String,
    /// Largest message a receiver accepts (and a sender may send), in bytes.
    pub max_message_bytes: usize,
    /// How long a sender's first message waits for its receiver to appear, and an actor for
    /// the learner, before reporting [`TransportError::Closed`].
    pub connect_timeout: Duration,
    /// Most actors at once (sizes the services' port tables).
    pub max_actors: usize,
    /// Messages a queue's receiver buffers before its senders block.
    pub queue_depth: usize,
}

impl Default for ShmConfig {
    fn default() -> Self {
        Self {
            fleet: format!("coadapt-{}", std::process::id()),
            max_message_bytes: Limits::default().max_message_bytes,
            connect_timeout: Duration::from_secs(10),
            max_actors: 64,
            queue_depth: 1024,
        }
    }
}

impl ShmConfig {
    fn limits(&self) -> Limits {
        Limits { max_message_bytes: self.max_message_bytes }
    }

    fn name(&self, channel: &str) -> String {
        format!("{}/{channel}", self.fleet)
    }

    fn queue_shape(&self, depth: usize) -> queue::QueueShape {
        // Actors, the learner, the optimiser, and room for a restarted process.
        queue::QueueShape { peers: self.max_actors + 4, depth }
    }

    fn work_shape(&self) -> work::WorkShape {
        work::WorkShape {
            name: self.name("assignments"),
            actors: self.max_actors,
            connect_timeout: self.connect_timeout,
            max_bytes: self.max_message_bytes,
        }
    }
}

const EXPERIENCE: &str = "experience";
const ACTING_WEIGHTS: &str = "weights/acting";
const POPULATION_WEIGHTS: &str = "weights/population";
const DESIGN_REQUESTS: &str = "design/requests";
const DESIGN_REPLIES: &str = "design/replies";
/// Design requests and replies are one at a time; a few slots are plenty.
const DESIGN_DEPTH: usize = 8;
/// Readers of the population weights: the optimiser, and room for tools.
const POPULATION_READERS: usize = 4;

/// The learner's channels.
pub fn learner_links(cfg: &ShmConfig) -> Result<LearnerLinks, TransportError> {
    let node = ipc::node("coadapt-learner")?;
    Ok(LearnerLinks {
        experience: Box::new(QueueReceiver::open(&cfg.name(EXPERIENCE), cfg.queue_shape(cfg.queue_depth), cfg.limits())?),
        assignments: Box::new(AssignmentSender::open(cfg.work_shape())?),
        acting_weights: Box::new(TopicPublisher::<Weights>::open(
            &node,
            &cfg.name(ACTING_WEIGHTS),
            cfg.max_actors + 4,
            cfg.max_message_bytes,
        )?),
        population_weights: Box::new(TopicPublisher::<Weights>::open(
            &node,
            &cfg.name(POPULATION_WEIGHTS),
            POPULATION_READERS,
            cfg.max_message_bytes,
        )?),
        design_requests: Box::new(QueueSender::open(
            &node,
            &cfg.name(DESIGN_REQUESTS),
            cfg.queue_shape(DESIGN_DEPTH),
            cfg.connect_timeout,
            cfg.max_message_bytes,
        )?),
        design_replies: Box::new(QueueReceiver::open(&cfg.name(DESIGN_REPLIES), cfg.queue_shape(DESIGN_DEPTH), cfg.limits())?),
    })
}

/// Actor `actor_id`'s channels; ids must be unique within the fleet.
pub fn actor_links(cfg: &ShmConfig, actor_id: u64) -> Result<ActorLinks, TransportError> {
    let node = ipc::node(&format!("coadapt-actor-{actor_id}"))?;
    Ok(ActorLinks {
        assignments: Box::new(AssignmentReceiver::open(&node, &cfg.work_shape(), actor_id)?),
        weights: Box::new(TopicSubscriber::<Weights>::open(&node, &cfg.name(ACTING_WEIGHTS), cfg.max_actors + 4, cfg.limits())?),
        experience: Box::new(QueueSender::open(
            &node,
            &cfg.name(EXPERIENCE),
            cfg.queue_shape(cfg.queue_depth),
            cfg.connect_timeout,
            cfg.max_message_bytes,
        )?),
    })
}

/// The design optimiser's channels.
pub fn optimizer_links(cfg: &ShmConfig) -> Result<OptimizerLinks, TransportError> {
    let node = ipc::node("coadapt-optimizer")?;
    Ok(OptimizerLinks {
        requests: Box::new(QueueReceiver::open(&cfg.name(DESIGN_REQUESTS), cfg.queue_shape(DESIGN_DEPTH), cfg.limits())?),
        replies: Box::new(QueueSender::open(
            &node,
            &cfg.name(DESIGN_REPLIES),
            cfg.queue_shape(DESIGN_DEPTH),
            cfg.connect_timeout,
            cfg.max_message_bytes,
        )?),
        weights: Box::new(TopicSubscriber::<Weights>::open(&node, &cfg.name(POPULATION_WEIGHTS), POPULATION_READERS, cfg.limits())?),
    })
}

/// The shared-memory services of fleet `fleet` that still exist (none, once every process of
/// the fleet has ended and the dead ones have been cleaned up).
pub fn fleet_services(fleet: &str) -> Result<Vec<String>, TransportError> {
    ipc::services_named(&format!("{fleet}/"))
}

/// Removes resources left by killed processes (iceoryx2 dead-node cleanup); returns how many
/// nodes were cleaned. Call it at the start of every role.
pub fn cleanup_stale() -> Result<usize, TransportError> {
    ipc::cleanup_dead_nodes()
}

/// The sending end of queue `channel` of `cfg.fleet` (any message type), for tests and
/// benchmarks; any number of senders, in any processes, may open the same channel.
pub fn queue_sender<T: Codec>(cfg: &ShmConfig, channel: &str) -> Result<QueueSender<T>, TransportError> {
    let node = ipc::node("coadapt-queue-sender")?;
    QueueSender::open(&node, &cfg.name(channel), cfg.queue_shape(cfg.queue_depth), cfg.connect_timeout, cfg.max_message_bytes)
}

/// The receiving end of queue `channel` of `cfg.fleet`; one per channel.
pub fn queue_receiver<T: Codec>(cfg: &ShmConfig, channel: &str) -> Result<QueueReceiver<T>, TransportError> {
    QueueReceiver::open(&cfg.name(channel), cfg.queue_shape(cfg.queue_depth), cfg.limits())
}

/// The publisher of topic `channel` of `cfg.fleet` (up to `cfg.max_actors + 4` readers).
pub fn topic_publisher<T: Codec + Versioned>(cfg: &ShmConfig, channel: &str) -> Result<TopicPublisher<T>, TransportError> {
    let node = ipc::node("coadapt-topic-publisher")?;
    TopicPublisher::open(&node, &cfg.name(channel), cfg.max_actors + 4, cfg.max_message_bytes)
}

/// A reader of topic `channel` of `cfg.fleet`.
pub fn topic_subscriber<T: Codec + Versioned>(cfg: &ShmConfig, channel: &str) -> Result<TopicSubscriber<T>, TransportError> {
    let node = ipc::node("coadapt-topic-subscriber")?;
    TopicSubscriber::open(&node, &cfg.name(channel), cfg.max_actors + 4, cfg.limits())
}

/// The learner's end of a work-sharing assignment queue named `channel` (each assignment goes
/// to exactly one [`assignment_receiver`]).
pub fn assignment_sender(cfg: &ShmConfig, channel: &str) -> Result<AssignmentSender, TransportError> {
    AssignmentSender::open(work::WorkShape { name: cfg.name(channel), ..cfg.work_shape() })
}

/// Actor `actor_id`'s end of the work-sharing assignment queue `channel`.
pub fn assignment_receiver(cfg: &ShmConfig, channel: &str, actor_id: u64) -> Result<AssignmentReceiver, TransportError> {
    let node = ipc::node(&format!("coadapt-actor-{actor_id}"))?;
    AssignmentReceiver::open(&node, &work::WorkShape { name: cfg.name(channel), ..cfg.work_shape() }, actor_id)
}
