//! The receiving end of a queue from the learner (assignments, design requests): long polls
//! that each confirm the previous delivery. Delivery numbers belong to one learner start: polls
//! name its run id, and when the learner restarts as another start the receiver forgets what it
//! received from the old one (so no number of the old start confirms a delivery of the new).

use std::future::Future;
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use coadapt_transport::{Assignment, DesignRequest, Receiver, TransportError};
use coadapt_wire::Wire;
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;

use super::{Session, block};
use crate::{Backoff, is_permanent, is_unregistered, run_of, status_error};

/// (payload, seq, finished, the run id of the learner start that answered)
type Delivery<P> = (Option<P>, u64, bool, u64);
type Call<P> = Pin<Box<dyn Future<Output = Result<Delivery<P>, tonic::Status>> + Send>>;

/// A message handed out by long poll.
pub(crate) trait Polled: Wire<Pb: Send> + Send + 'static {
    fn call(client: FleetClient<coadapt_auth::AuthChannel>, poll: tonic::Request<pb::Poll>) -> Call<Self::Pb>;
}

impl Polled for Assignment {
    fn call(mut client: FleetClient<coadapt_auth::AuthChannel>, poll: tonic::Request<pb::Poll>) -> Call<pb::Assignment> {
        Box::pin(async move {
            let d = client.next_assignment(poll).await?;
            let run = run_of(d.metadata());
            let d = d.into_inner();
            Ok((d.assignment, d.seq, d.finished, run))
        })
    }
}

impl Polled for DesignRequest {
    fn call(mut client: FleetClient<coadapt_auth::AuthChannel>, poll: tonic::Request<pb::Poll>) -> Call<pb::DesignRequest> {
        Box::pin(async move {
            let d = client.next_design_request(poll).await?;
            let run = run_of(d.metadata());
            let d = d.into_inner();
            Ok((d.request, d.seq, d.finished, run))
        })
    }
}

#[derive(Debug)]
pub(crate) struct PollReceiver<T: Polled> {
    session: Arc<Session>,
    /// The last delivery received; every poll confirms it.
    received: u64,
    /// The learner start whose delivery `received` numbers.
    run_id: u64,
    backoff: Backoff,
    _t: PhantomData<fn() -> T>,
}

impl<T: Polled> PollReceiver<T> {
    pub(crate) fn new(session: Arc<Session>) -> Self {
        let backoff = Backoff::new(session.conn.cfg.reconnect_backoff_max);
        let run_id = session.conn.run_id();
        Self { session, received: 0, run_id, backoff, _t: PhantomData }
    }

    /// Polls as a consumer of the learner start we are registered with: a new start has
    /// delivered nothing to us yet.
    fn poll_once(&mut self, wait: Duration, leaving: bool) -> Result<Result<Delivery<T::Pb>, tonic::Status>, TransportError> {
        let conn = &self.session.conn;
        let current = conn.run_id();
        if current != self.run_id {
            self.run_id = current;
            self.received = 0;
        }
        let deadline = wait + conn.cfg.poll_margin();
        let mut req = tonic::Request::new(pb::Poll {
            session: conn.session,
            received: self.received,
            wait_ms: u32::try_from(wait.as_millis()).unwrap_or(u32::MAX),
            leaving,
            run_id: self.run_id,
        });
        req.set_timeout(deadline);
        let call = T::call(conn.client.clone(), req);
        block(async move {
            match tokio::time::timeout(deadline, call).await {
                Ok(r) => r,
                Err(_) => Err(tonic::Status::deadline_exceeded("long poll")),
            }
        })
    }
}

impl<T: Polled> Receiver<T> for PollReceiver<T> {
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<T>, TransportError> {
        let deadline = Instant::now() + timeout;
        let cfg = self.session.conn.cfg.clone();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.poll_once(left.min(cfg.long_poll_cap()), false)? {
                // (0: not stamped, taken as the start polled.)
                Ok((_, _, _, run)) if run != 0 && run != self.run_id => {
                    // Answered by another start than the one polled (we cannot have received
                    // from it yet): learn its run id, then ask it afresh.
                    let conn = self.session.conn.clone();
                    let learned = block(async move { conn.register_once().await })?.is_ok() && self.session.conn.run_id() == run;
                    if !learned {
                        std::thread::sleep(self.backoff.next_delay().min(deadline.saturating_duration_since(Instant::now())));
                    }
                }
                Ok((Some(pb), seq, _, _)) => {
                    self.received = seq;
                    self.backoff.reset();
                    return T::from_pb(pb).map(Some).map_err(|e| TransportError::Invalid(e.to_string()));
                }
                Ok((None, _, true, _)) => {
                    self.session.conn.finished.store(true, Ordering::Relaxed);
                    return Err(TransportError::Closed);
                }
                Ok((None, _, false, _)) => self.backoff.reset(),
                Err(s) if is_unregistered(&s) => {
                    // The learner restarted or forgot us: register again (same session) and ask again.
                    let conn = self.session.conn.clone();
                    match block(async move { conn.register_once().await })? {
                        Ok(()) => self.backoff.reset(),
                        Err(s) if is_permanent(&s) => return Err(status_error(&s)),
                        Err(_) => std::thread::sleep(self.backoff.next_delay().min(deadline.saturating_duration_since(Instant::now()))),
                    }
                }
                Err(s) if is_permanent(&s) => return Err(status_error(&s)),
                Err(_) if self.session.conn.is_finished() => return Err(TransportError::Closed),
                // The learner is away: wait, then try again (the channel reconnects).
                Err(_) => std::thread::sleep(self.backoff.next_delay().min(deadline.saturating_duration_since(Instant::now()))),
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
        }
    }
}

impl<T: Polled> Drop for PollReceiver<T> {
    fn drop(&mut self) {
        // Hand back a delivery that may have been lost on its way to us (once only: if the
        // learner is away, so is the delivery).
        let _ = self.poll_once(Duration::ZERO, true);
    }
}
