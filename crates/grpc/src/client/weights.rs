//! A weight subscriber: a background task keeps a WatchWeights stream open (reopening it
//! after a failure, asking only for versions newer than it has) and stores the newest decoded
//! version; `wait_for` reads it like the in-process topic. What it stores belongs to one
//! learner start: a restarted learner (another run id) numbers its versions afresh, so the
//! stored version is dropped and the subscriber waits for the new start's, whatever its number.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Condvar, Mutex, Weak};
use std::time::{Duration, Instant};

use coadapt_transport::{Subscriber, TransportError, Weights};
use coadapt_wire::Wire;
use coadapt_wire::pb;

use super::{Conn, Dropped, Session, StartBound, block, runtime};
use crate::{Backoff, is_permanent, run_of};

#[derive(Debug, Default)]
struct Latest {
    weights: Option<Arc<Weights>>,
    /// The learner stopped publishing.
    closed: bool,
    /// A version that failed validation, reported once.
    error: Option<String>,
    /// The learner start `weights` belongs to.
    run_id: u64,
}

#[derive(Debug, Default)]
struct Shared {
    latest: Mutex<Latest>,
    changed: Condvar,
}

impl Shared {
    fn update(&self, f: impl FnOnce(&mut Latest)) {
        if let Ok(mut l) = self.latest.lock() {
            f(&mut l);
        }
        self.changed.notify_all();
    }

    fn version(&self) -> Option<u64> {
        self.latest.lock().ok().and_then(|l| l.weights.as_ref().map(|w| w.version))
    }
}

impl StartBound for Shared {
    fn restart(&self, run_id: u64) -> Dropped {
        let Ok(mut l) = self.latest.lock() else { return Dropped::default() };
        if l.run_id == run_id {
            return Dropped::default();
        }
        l.run_id = run_id;
        let old = l.weights.take().map(|w| w.version);
        drop(l);
        self.changed.notify_all();
        Dropped { frames: 0, weights_version: old }
    }
}

#[derive(Debug)]
pub(crate) struct WeightsSubscriber {
    shared: Arc<Shared>,
    task: tokio::task::AbortHandle,
    session: Arc<Session>,
    topic: pb::WeightsTopic,
}

impl WeightsSubscriber {
    pub(crate) fn start(session: Arc<Session>, topic: pb::WeightsTopic) -> Result<Self, TransportError> {
        let shared = Arc::new(Shared::default());
        session.conn.attach(Arc::downgrade(&shared) as Weak<dyn StartBound>);
        let task = runtime()?.spawn(follow(session.conn.clone(), topic, shared.clone())).abort_handle();
        Ok(Self { shared, task, session, topic })
    }
}

impl Drop for WeightsSubscriber {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl WeightsSubscriber {
    /// The newest version the learner has published, if it answers within `patience`.
    fn newest_published(&self, patience: Duration) -> Option<u64> {
        let conn = self.session.conn.clone();
        let topic = self.topic;
        let reply = block(async move { conn.beat_once(patience).await }).ok()??;
        Some(match topic {
            pb::WeightsTopic::Population => reply.population_version,
            _ => reply.acting_version,
        })
    }
}

impl Subscriber<Weights> for WeightsSubscriber {
    fn wait_for(&mut self, min_version: u64, timeout: Duration) -> Result<Option<Arc<Weights>>, TransportError> {
        let deadline = Instant::now() + timeout;
        // What we hold (or the first version to arrive) may trail the learner by what is in
        // flight; unless we already know it is too old, ask the learner for its newest version
        // and wait for that one instead.
        let held = self.shared.version();
        let mut want = min_version;
        if !timeout.is_zero()
            && held.is_none_or(|v| v >= min_version)
            && let Some(newest) = self.newest_published(timeout.min(self.session.conn.cfg.rpc_timeout))
            && held.is_none_or(|v| newest > v)
        {
            want = want.max(newest);
        }
        let Ok(mut l) = self.shared.latest.lock() else { return Err(TransportError::Io("weights lock poisoned".into())) };
        loop {
            if let Some(e) = l.error.take() {
                return Err(TransportError::Invalid(e));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            // The newest on its way did not come in time: what we hold still satisfies the reader.
            let enough = if left.is_zero() || l.closed { min_version } else { want };
            if let Some(w) = l.weights.as_ref().filter(|w| w.version >= enough) {
                self.session.conn.weights_version.fetch_max(w.version, Ordering::Relaxed);
                return Ok(Some(w.clone()));
            }
            if l.closed {
                return Err(TransportError::Closed);
            }
            if left.is_zero() {
                return Ok(None);
            }
            l = self.shared.changed.wait_timeout(l, left).map_err(|_| TransportError::Io("weights lock poisoned".into()))?.0;
        }
    }
}

/// Keeps the newest version of `topic` in `shared` until the learner closes the topic (or
/// finishes the fleet and goes away).
async fn follow(conn: Arc<Conn>, topic: pb::WeightsTopic, shared: Arc<Shared>) {
    let cfg = conn.cfg.clone();
    // Silence longer than this (keep-alives come every heartbeat) means the stream is dead.
    let idle = cfg.heartbeat * 2 + cfg.rpc_timeout;
    let mut backoff = Backoff::new(cfg.reconnect_backoff_max);
    loop {
        // Versions of the start we hold weights of (the learner ignores them if it is another).
        let (min_version, run_id) = match shared.latest.lock() {
            Ok(l) => (l.weights.as_ref().map_or(0, |w| w.version + 1), l.run_id),
            Err(_) => return,
        };
        let mut req = tonic::Request::new(pb::WatchRequest { topic: topic as i32, min_version, run_id });
        req.set_timeout(cfg.rpc_timeout);
        let mut client = conn.client.clone();
        match tokio::time::timeout(cfg.rpc_timeout, client.watch_weights(req)).await {
            Ok(Ok(stream)) => {
                // (0: not stamped, taken as the start we registered with.)
                let run = match run_of(stream.metadata()) {
                    0 => conn.run_id(),
                    run => run,
                };
                if run != conn.run_id() {
                    // Another learner start than the one we registered with: learn its run id
                    // (dropping the old start's weights) before taking any of its versions.
                    let _ = conn.register_once().await;
                    if run != conn.run_id() {
                        tokio::time::sleep(backoff.next_delay()).await;
                    }
                    continue;
                }
                let mut stream = stream.into_inner();
                loop {
                    let update = match tokio::time::timeout(idle, stream.message()).await {
                        Ok(Ok(Some(update))) => update,
                        Ok(Err(s)) if is_permanent(&s) => {
                            refused(&shared, &s);
                            break;
                        }
                        _ => break,
                    };
                    backoff.reset();
                    if let Some(w) = update.weights {
                        match Weights::from_pb(w) {
                            Ok(w) => shared.update(|l| {
                                // Checked under the lock a restart takes: never a version of
                                // a start we no longer belong to.
                                if l.run_id == run && l.weights.as_ref().is_none_or(|old| old.version < w.version) {
                                    l.weights = Some(Arc::new(w));
                                }
                            }),
                            Err(e) => shared.update(|l| l.error = Some(format!("weights from the learner: {e}"))),
                        }
                    }
                    if update.publisher_closed {
                        shared.update(|l| l.closed = true);
                        return;
                    }
                }
            }
            Ok(Err(s)) if is_permanent(&s) => refused(&shared, &s),
            _ => {}
        }
        if conn.is_finished() {
            // The learner finished the fleet and is gone: nothing newer will come.
            shared.update(|l| l.closed = true);
            return;
        }
        tokio::time::sleep(backoff.next_delay()).await;
    }
}

/// A stream the learner or our own limits refused (an oversized version, say): reported to
/// the reader once, then retried, since the next version may fit.
fn refused(shared: &Shared, s: &tonic::Status) {
    let why = format!("weights stream refused: {:?}: {}", s.code(), s.message());
    shared.update(|l| l.error = Some(why));
}
