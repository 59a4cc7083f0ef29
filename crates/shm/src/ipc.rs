//! The iceoryx2 plumbing every channel shares: the service flavour, nodes, how services are
//! opened (every party opens them with the same settings, or iceoryx2 refuses), dead-node
//! cleanup.

use std::fmt::Debug;
use std::time::{Duration, Instant};

use coadapt_transport::TransportError;
use iceoryx2::node::{NodeCleanupFailure, NodeView};
use iceoryx2::prelude::*;

/// Thread-safe ports, because links are boxed `Send` trait objects (ports of `ipc::Service`
/// are `!Send`).
pub(crate) type Svc = ipc_threadsafe::Service;
/// Samples are encoded messages; the user header says what kind of sample it is ([`DATA`] or
/// [`GOODBYE`]).
pub(crate) type PubSub = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, [u8], u64>;
pub(crate) type Event = iceoryx2::service::port_factory::event::PortFactory<Svc>;
pub(crate) type Publisher = iceoryx2::port::publisher::Publisher<Svc, [u8], u64>;
pub(crate) type Subscriber = iceoryx2::port::subscriber::Subscriber<Svc, [u8], u64>;
pub(crate) type Listener = iceoryx2::port::listener::Listener<Svc>;
pub(crate) type Notifier = iceoryx2::port::notifier::Notifier<Svc>;

/// How often a waiting port looks for peers killed without saying goodbye (their ports stay
/// registered until some node runs dead-node cleanup).
pub(crate) const CLEANUP_EVERY: Duration = Duration::from_millis(500);

/// A message.
pub(crate) const DATA: u64 = 0;
/// A sender's last sample: everything it sent is ahead of it in the buffer.
pub(crate) const GOODBYE: u64 = 1;

/// Event ids on a channel's wake-up services.
pub(crate) const EV_DATA: usize = 0;
const EV_PEER_DROPPED: usize = 1;
const EV_PEER_DEAD: usize = 2;

pub(crate) fn io(what: &str, e: impl Debug) -> TransportError {
    TransportError::Io(format!("{what}: {e:?}"))
}

/// A node for one role's (or one test's) ports. Signal handling stays off: iceoryx2 would
/// otherwise install SIGINT/SIGTERM handlers and the CLI's Ctrl-C would stop working.
/// iceoryx2 warns on every start that it found no config file; its defaults are ours.
/// `IOX2_LOG_LEVEL` still lowers the level for debugging.
fn quiet_logs() {
    static QUIET: std::sync::Once = std::sync::Once::new();
    QUIET.call_once(|| set_log_level_from_env_or(LogLevel::Error));
}

pub(crate) fn node(name: &str) -> Result<Node<Svc>, TransportError> {
    quiet_logs();
    let name = NodeName::new(name).map_err(|e| io("node name", e))?;
    NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Svc>()
        .map_err(|e| io("creating an iceoryx2 node", e))
}

pub(crate) fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(|e| TransportError::Invalid(format!("service name {name:?}: {e:?}")))
}

/// Opening races with other processes creating the same service; iceoryx2 reports that as a
/// transient error, so startup retries for a moment.
fn retry<T, E: Debug>(what: &str, mut f: impl FnMut() -> Result<T, E>) -> Result<T, TransportError> {
    let start = Instant::now();
    loop {
        match f() {
            Ok(v) => return Ok(v),
            Err(e) if start.elapsed() > Duration::from_secs(2) => return Err(io(what, e)),
            Err(_) => std::thread::sleep(Duration::from_millis(10)),
        }
    }
}

/// The settings of one publish-subscribe service.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PubSubShape {
    pub publishers: usize,
    pub subscribers: usize,
    pub nodes: usize,
    pub buffer: usize,
    /// Latest-value topics keep one sample for late joiners and overwrite; queues keep none
    /// and push back on a full buffer.
    pub topic: bool,
}

pub(crate) fn pubsub(node: &Node<Svc>, name: &str, s: PubSubShape) -> Result<PubSub, TransportError> {
    let sname = service_name(name)?;
    retry(&format!("opening publish-subscribe service {name}"), || {
        node.service_builder(&sname)
            .publish_subscribe::<[u8]>()
            .user_header::<u64>()
            .max_publishers(s.publishers)
            .max_subscribers(s.subscribers)
            .max_nodes(s.nodes)
            .subscriber_max_buffer_size(s.buffer)
            .subscriber_max_borrowed_samples(2)
            .history_size(usize::from(s.topic))
            .enable_safe_overflow(s.topic)
            .open_or_create()
    })
}

/// An event service used to wake the ports waiting on a channel; a dropped or dead notifier
/// also wakes the listeners, so a reader learns its peer has gone without polling.
pub(crate) fn event(node: &Node<Svc>, name: &str, peers: usize) -> Result<Event, TransportError> {
    let sname = service_name(name)?;
    retry(&format!("opening event service {name}"), || {
        node.service_builder(&sname)
            .event()
            .max_listeners(peers)
            .max_notifiers(peers)
            .max_nodes(peers)
            .notifier_dropped_event(EventId::new(EV_PEER_DROPPED))
            .notifier_dead_event(EventId::new(EV_PEER_DEAD))
            .open_or_create()
    })
}

pub(crate) fn listener(ev: &Event) -> Result<Listener, TransportError> {
    ev.listener_builder().create().map_err(|e| io("creating a listener", e))
}

pub(crate) fn notifier(ev: &Event) -> Result<Notifier, TransportError> {
    ev.notifier_builder().default_event_id(EventId::new(EV_DATA)).create().map_err(|e| io("creating a notifier", e))
}

/// A sample loaned from `publisher` with `msg` encoded straight into it (one copy), refusing
/// messages above `max` bytes.
pub(crate) fn loan_encoded(
    publisher: &Publisher,
    msg: &impl crate::codec::Codec,
    max: usize,
) -> Result<iceoryx2::sample_mut::SampleMut<Svc, [u8], u64>, TransportError> {
    let mut slot = None;
    msg.write_with(|n| {
        if n > max {
            return Err(TransportError::Invalid(format!("{n} bytes exceeds max_message_bytes ({max})")));
        }
        let sample = publisher.loan_slice(n).map_err(|e| io("loaning a shared-memory sample", e))?;
        Ok(slot.insert(sample).payload_mut())
    })?;
    slot.ok_or_else(|| TransportError::Io("the encoder wrote no sample".into()))
}

/// Blocks until something is notified or `timeout` passes, consuming every pending event.
pub(crate) fn wait(listener: &Listener, timeout: Duration) -> Result<(), TransportError> {
    match listener.timed_wait(|_| {}, timeout) {
        // A signal (Ctrl-C, SIGTERM) cut the wait short: the caller looks at its stop flag.
        Ok(_) | Err(iceoryx2::port::listener::ListenerWaitError::InterruptSignal) => Ok(()),
        Err(e) => Err(io("waiting on an event", e)),
    }
}

/// Removes the resources of every dead node (processes killed without cleaning up); returns
/// how many were removed.
pub(crate) fn cleanup_dead_nodes() -> Result<usize, TransportError> {
    quiet_logs();
    let (cleaned, stuck) = cleanup_pass(None)?;
    // iceoryx2 0.10 stops short on a dead node killed while it wrote a port's tag: the tag
    // file keeps the permissions of a file being created, which iceoryx2's listing skips, so
    // its cleanup removes the node's details, fails on the non-empty directory, and the node
    // stays dead on the machine for good, tried (and reported) by every process after. Remove
    // those leftover tags and try once more.
    let mut retry = Vec::new();
    for id in stuck {
        match remove_orphan_port_tags(id) {
            Ok(0) => report_stuck(id, "InternalError"),
            Ok(_) => retry.push(id),
            Err(e) => report_stuck(id, &format!("InternalError, then removing its leftover port tags: {e}")),
        }
    }
    if retry.is_empty() {
        return Ok(cleaned);
    }
    let (again, still) = cleanup_pass(Some(&retry))?;
    for id in still {
        report_stuck(id, "InternalError, even without its leftover port tags");
    }
    Ok(cleaned + again)
}

/// One pass of iceoryx2's cleanup over the dead nodes (only those in `only`, if given): how many
/// it removed, and the ids of those it failed on with an internal error.
fn cleanup_pass(only: Option<&[u128]>) -> Result<(usize, Vec<u128>), TransportError> {
    let mut cleaned = 0;
    let mut stuck = Vec::new();
    Node::<Svc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            let id = view.id().value();
            if only.is_some_and(|ids| !ids.contains(&id)) {
                return CallbackProgression::Continue;
            }
            match view.try_remove_stale_resources() {
                Ok(()) => cleaned += 1,
                // Someone else is at it, or was first: not ours to count.
                Err(NodeCleanupFailure::ResourcesAlreadyCleanedUp | NodeCleanupFailure::AnotherInstanceIsCleaningUpTheNode) => {}
                Err(NodeCleanupFailure::InternalError) => stuck.push(id),
                Err(e) => report_stuck(id, &format!("{e:?}")),
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| io("listing iceoryx2 nodes", e))?;
    Ok((cleaned, stuck))
}

/// The directory iceoryx2 keeps dead node `id`'s details and tags in.
fn node_details_dir(id: u128) -> std::path::PathBuf {
    std::path::PathBuf::from(Config::global_config().global.node_dir().to_string()).join(id.to_string())
}

/// Removes the port tags left in dead node `id`'s directory, but only when nothing else is left
/// there: iceoryx2 removes a node's details last, after its ports' and services' resources, so
/// a directory of bare tags is one whose cleanup got as far as it can. Returns how many it removed.
fn remove_orphan_port_tags(id: u128) -> std::io::Result<usize> {
    let suffix = Config::global_config().global.node.port_tag_suffix.to_string();
    let dir = node_details_dir(id);
    let entries = match std::fs::read_dir(&dir) {
        Ok(entries) => entries.map(|e| e.map(|e| e.path())).collect::<Result<Vec<_>, _>>()?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let is_tag = |p: &std::path::PathBuf| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.ends_with(&suffix));
    if entries.is_empty() || !entries.iter().all(is_tag) {
        return Ok(0);
    }
    for path in &entries {
        match std::fs::remove_file(path) {
            // Another process's cleanup was first.
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
            _ => {}
        }
    }
    Ok(entries.len())
}

/// Says once per process (every role of an in-process fleet cleans up as it starts, and so may
/// a caller's retry loop) that dead node `id` could not be cleaned up, and where its files are.
fn report_stuck(id: u128, why: &str) {
    static REPORTED: std::sync::Mutex<Vec<u128>> = std::sync::Mutex::new(Vec::new());
    let mut reported = REPORTED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if reported.contains(&id) {
        return;
    }
    reported.push(id);
    let nodes = Config::global_config().global.node_dir().to_string();
    coadapt_log::logln!(
        "coadapt-shm: could not clean up dead node {id}: {why}; its files are {} and {nodes}/*{id}*, safe to delete by hand (its process is gone)",
        node_details_dir(id).display()
    );
}

/// The names of every service on this machine whose name starts with `prefix`.
pub(crate) fn services_named(prefix: &str) -> Result<Vec<String>, TransportError> {
    quiet_logs();
    let mut names = Vec::new();
    Svc::list(Config::global_config(), |details| {
        let name = details.static_details.name().to_string();
        if name.starts_with(prefix) {
            names.push(name);
        }
        CallbackProgression::Continue
    })
    .map_err(|e| io("listing iceoryx2 services", e))?;
    Ok(names)
}

/// Runs dead-node cleanup on a service at most every [`CLEANUP_EVERY`].
#[derive(Debug)]
pub(crate) struct Janitor(Instant);

impl Janitor {
    pub fn new() -> Self {
        Self(Instant::now())
    }

    pub fn sweep<F: PortFactory>(&mut self, service: &F) {
        if self.0.elapsed() >= CLEANUP_EVERY {
            service.try_cleanup_dead_nodes();
            self.0 = Instant::now();
        }
    }
}

/// Whether every subscriber of `service` lives in this process.
pub(crate) fn subscribers_are_local(service: &PubSub) -> bool {
    let me = std::process::id();
    let mut local = true;
    service.dynamic_config().list_subscribers(|d| {
        let here = match Node::<Svc>::state_of(Config::global_config(), d.node_id) {
            Ok(Some(NodeState::Alive(view))) => view.details().as_ref().is_some_and(|x| u32::try_from(x.process_id().value()) == Ok(me)),
            _ => false,
        };
        local &= here;
        CallbackProgression::Continue
    });
    local
}
