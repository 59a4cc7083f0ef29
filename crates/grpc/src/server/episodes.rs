//! The experience queue's gate: which session holds which assignment, and what each episode
//! has streamed so far. Experience for an assignment is accepted only from the session it was
//! handed to (ids are sequential, so guessable); chunks queued for an id before the learner
//! issued it are dropped when it does; `EpisodeEnd.length` must match the transitions
//! streamed; empty chunks (liveness of evaluation episodes) pass at most once a heartbeat.
//!
//! Entries are made by the learner (an issued assignment) and removed by the episode's end, so
//! the table grows with the learner's work, never with what clients send. An assignment
//! this learner never issued (a predecessor's, before a restart) is not tracked: the learner
//! ignores experience of assignments it does not have out.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use coadapt_transport::ExperienceChunk;

use super::queues::{Gate, Inbox, Reason, Refusal, Verdict};

#[derive(Debug)]
struct Episode {
    /// The session it was handed to; `None` while it waits in the queue.
    holder: Option<u64>,
    /// A training episode streams every transition, so its end's length is their number.
    train: bool,
    /// Transitions streamed since the attempt's first chunk.
    rows: u64,
    /// When a chunk of it was last passed on.
    last_passed: Option<Instant>,
}

#[derive(Debug)]
pub(crate) struct Episodes {
    table: HashMap<u64, Episode>,
    max_steps: u64,
    /// Empty chunks closer together than this are not passed on.
    empty_every: Duration,
}

impl Episodes {
    pub(crate) fn new(max_steps: u64, empty_every: Duration) -> Self {
        Self { table: HashMap::new(), max_steps, empty_every }
    }
}

fn refuse(reason: Reason, code: tonic::Code, message: String) -> Verdict {
    Verdict::Refuse(Refusal::new(reason, code, message))
}

impl Gate<ExperienceChunk> for Episodes {
    fn judge(&mut self, session: u64, c: &ExperienceChunk, now: Instant) -> Verdict {
        let id = c.assignment;
        if let Some(end) = c.end
            && end.length > self.max_steps
        {
            let why = format!(
                "chunk.end.length: {} is above the longest episode, {} steps (GrpcConfig::max_episode_steps)",
                end.length, self.max_steps
            );
            return refuse(Reason::BadLength, tonic::Code::InvalidArgument, why);
        }
        let Some(e) = self.table.get(&id) else { return Verdict::Forward };
        match e.holder {
            // An honest client meets this only with a late chunk of a predecessor learner's
            // assignment whose id this learner issued again: it drops the frame and goes on.
            None => {
                let why = format!("chunk.assignment: assignment {id} has not been handed to this session");
                return Verdict::Refuse(Refusal {
                    frame_only: true,
                    ..Refusal::new(Reason::ForeignAssignment, tonic::Code::PermissionDenied, why)
                });
            }
            Some(h) if h != session => {
                let why = format!("chunk.assignment: assignment {id} is held by another session");
                return Verdict::Refuse(Refusal {
                    frame_only: true,
                    ..Refusal::new(Reason::ForeignAssignment, tonic::Code::PermissionDenied, why)
                });
            }
            Some(_) => {}
        }
        let rows = c.len() as u64;
        let total = if c.first { 0 } else { e.rows }.saturating_add(rows);
        if total > self.max_steps {
            let why =
                format!("chunk.rows: assignment {id} would have {total} transitions, above the longest episode, {} steps", self.max_steps);
            return refuse(Reason::BadLength, tonic::Code::InvalidArgument, why);
        }
        if let Some(end) = c.end
            && e.train
            && end.length != total
        {
            let why = format!("chunk.end.length: {} but assignment {id} streamed {total} transitions", end.length);
            return refuse(Reason::BadLength, tonic::Code::InvalidArgument, why);
        }
        if rows == 0 && c.end.is_none() && e.last_passed.is_some_and(|t| now.duration_since(t) < self.empty_every) {
            return Verdict::Skip(Reason::EmptyDropped);
        }
        Verdict::Forward
    }

    fn commit(&mut self, session: u64, c: &ExperienceChunk, now: Instant) {
        let Some(e) = self.table.get_mut(&c.assignment) else { return };
        if e.holder != Some(session) {
            return;
        }
        if c.end.is_some() {
            self.table.remove(&c.assignment);
            return;
        }
        e.rows = if c.first { 0 } else { e.rows }.saturating_add(c.len() as u64);
        e.last_passed = Some(now);
    }
}

impl Inbox<ExperienceChunk, Episodes> {
    /// The learner issues assignment `id`: nobody holds it yet, and chunks already queued for
    /// it (sent before anyone could hold it) are dropped. Returns how many.
    pub(crate) fn issue(&self, id: u64, train: bool) -> usize {
        let Ok(mut s) = self.lock() else { return 0 };
        s.gate.table.insert(id, Episode { holder: None, train, rows: 0, last_passed: None });
        let purged = s.purge(|c| c.assignment == id);
        drop(s);
        if purged > 0 {
            self.wake_senders();
        }
        purged
    }

    /// Assignment `id` was handed to `session` (again, after a lost answer, or to another
    /// session after its holder gave it back unreceived).
    pub(crate) fn deliver(&self, id: u64, session: u64, train: bool) {
        let Ok(mut s) = self.lock() else { return };
        let e = s.gate.table.entry(id).or_insert(Episode { holder: None, train, rows: 0, last_passed: None });
        if e.holder != Some(session) {
            *e = Episode { holder: Some(session), train, rows: 0, last_passed: None };
        }
    }
}
