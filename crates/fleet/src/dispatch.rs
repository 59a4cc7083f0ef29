//! The learner's side of a fleet: hand out jobs (episodes, rollouts), hold each one's experience
//! until it is whole, and give it back exactly once.
//!
//! A job goes out as an [`Assignment`] under a fresh id. The actor that takes it streams
//! [`ExperienceChunk`]s tagged with that id; the dispatcher keeps them until the chunk with the
//! episode's end arrives, asks the experiment whether the whole episode is sound
//! ([`Check::episode`]) and returns it ([`Done`]). Meanwhile:
//! - **leases**: a job whose actor has sent nothing for `lease` goes out again under a new id
//!   (same job, same seed) to whichever actor is free, or, on real robots (`reissue = false`),
//!   is waited for and its silence reported once per lease;
//! - **exactly once**: chunks of an id no longer out (a silent copy that came back late, a job
//!   already done) are ignored, so no episode is returned twice or half;
//! - **restarts**: a chunk marked `first` after others of the same id means the actor ran the
//!   episode again from its start (its environment failed): what the failed attempt sent is
//!   forgotten;
//! - **bounds**: keep-alives (chunks with neither transitions nor an end) refresh a lease at most
//!   `max_steps` times, and a job past `max_steps` transitions without an end goes out again, so
//!   no actor can hold a job for ever; a malformed chunk ([`Check::chunk`]) sends its job out
//!   again;
//! - **giving up**: on shutdown (`None`), when no chunk at all arrived for `silence`, when a job
//!   is not back `deadline` after it first went out, or when `abort` says why (every actor
//!   process gone).

use std::fmt::Display;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_transport::{Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, LearnerLinks, TransportError};

/// How long one receive waits before the dispatcher looks at leases, deadlines and shutdown.
pub const POLL: Duration = Duration::from_millis(100);

/// What an actor is asked to do, without the id it goes out under.
#[derive(Clone, Debug, PartialEq)]
pub struct Job {
    pub design_index: u32,
    pub design: Vec<f32>,
    pub mode: EpisodeMode,
    /// Seeds the episode's reset (and whatever else the experiment derives from it).
    pub seed: u64,
    /// Act with weights of at least this version.
    pub min_weights_version: u64,
}

/// The dispatcher's knobs.
#[derive(Clone, Debug)]
pub struct DispatchConfig {
    /// A job whose actor sent nothing for this long goes out again (or is reported silent).
    pub lease: Duration,
    /// Send a silent job out again (simulated actors); false: wait for it (real robots, where a
    /// re-run costs wear), reporting the silence once per lease.
    pub reissue: bool,
    /// No chunk at all for this long fails (every actor gone); `None`: wait for ever.
    pub silence: Option<Duration>,
    /// A job not back this long after it first went out fails; `None`: no limit.
    pub deadline: Option<Duration>,
    /// Transitions an episode may have; keep-alives refresh a lease at most this often. 0: no
    /// bound.
    pub max_steps: usize,
}

impl Default for DispatchConfig {
    fn default() -> Self {
        Self { lease: Duration::from_secs(60), reissue: true, silence: None, deadline: None, max_steps: 0 }
    }
}

/// Counts and times for a run's summary; the caller may set them (a resumed run's).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DispatchStats {
    /// Jobs sent out again after their actor fell silent.
    pub reissued: u64,
    /// Episodes an actor ran again from the start after its environment failed.
    pub restarted: u64,
    /// Jobs sent out again because a chunk was malformed or the episode failed its check.
    pub refused: u64,
    /// Seconds blocked receiving.
    pub waiting: f64,
    /// Seconds sending assignments.
    pub sending: f64,
}

/// What the experiment says of a whole episode.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Verdict {
    Accept,
    /// Run it again (same job), saying why.
    Again(String),
    /// Fail the run, saying why.
    Fail(String),
}

/// The experiment's checks of what comes back.
pub trait Check<T> {
    /// A chunk as it arrives; an error sends its job out again.
    fn chunk(&mut self, _chunk: &ExperienceChunk) -> Result<(), String> {
        Ok(())
    }
    /// A whole episode.
    fn episode(&mut self, _done: &Done<T>) -> Verdict {
        Verdict::Accept
    }
}

/// Accepts every well-formed episode.
#[derive(Clone, Copy, Debug, Default)]
pub struct AcceptAll;
impl<T> Check<T> for AcceptAll {}

/// A job that is out.
#[derive(Debug)]
pub struct Out<T> {
    pub id: u64,
    pub job: Job,
    /// The experiment's own name for the job (its episode, rollout, ...).
    pub tag: T,
    chunks: Vec<ExperienceChunk>,
    heard: Instant,
    empties: u64,
    steps: usize,
    first_issued: Instant,
    reissued: u32,
}

/// A job whose whole episode came back.
#[derive(Debug)]
pub struct Done<T> {
    pub job: Job,
    pub tag: T,
    /// The id it came back under.
    pub id: u64,
    pub chunks: Vec<ExperienceChunk>,
    pub end: EpisodeEnd,
    /// The actor that sent the last chunk.
    pub actor: u64,
    /// The weights version acted with (the oldest, if the chunks disagree).
    pub weights_version: u64,
    /// Transitions streamed.
    pub steps: usize,
    /// Times the job went out again before this copy came back.
    pub reissued: u32,
    /// Seconds from its first issue.
    pub seconds: f64,
}

/// Why the dispatcher gave up.
#[derive(Debug, thiserror::Error)]
pub enum DispatchError {
    // The cause in the message, not as a source: `{:#}` would print it twice.
    #[error("transport: {0}")]
    Transport(TransportError),
    #[error("no actor has sent anything for {after:?} ({outstanding} job(s) outstanding): are the actors running?")]
    Silence { after: Duration, outstanding: usize },
    #[error("{what} not back after {after:?}: are the actors running?")]
    Deadline { what: String, after: Duration },
    #[error("{0}")]
    Aborted(String),
    /// The experiment's check failed the run.
    #[error("{0}")]
    Refused(String),
}

/// The learner's side of a fleet (see the module doc). `T` names a job for the experiment.
pub struct Dispatcher<T> {
    /// Names the dispatcher in log lines (`learner`, `search`, ...).
    name: &'static str,
    pub cfg: DispatchConfig,
    out: Vec<Out<T>>,
    next_id: u64,
    pub stats: DispatchStats,
    /// Asked while waiting: `Some(why)` gives up (every actor process gone).
    pub abort: Option<Box<dyn Fn() -> Option<String> + Send + Sync>>,
}

impl<T> std::fmt::Debug for Dispatcher<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dispatcher")
            .field("name", &self.name)
            .field("out", &self.out.len())
            .field("next_id", &self.next_id)
            .finish_non_exhaustive()
    }
}

impl<T: Display> Dispatcher<T> {
    pub fn new(name: &'static str, cfg: DispatchConfig) -> Self {
        Self { name, cfg, out: Vec::new(), next_id: 0, stats: DispatchStats::default(), abort: None }
    }

    /// Jobs out and not yet back.
    pub fn outstanding(&self) -> usize {
        self.out.len()
    }

    /// The last assignment id used (ids count up from 1).
    pub fn last_id(&self) -> u64 {
        self.next_id
    }

    /// Continues the ids after `last` (a resumed run's).
    pub fn set_last_id(&mut self, last: u64) {
        self.next_id = last;
    }

    /// Starts every lease again (the learner itself was busy, e.g. waiting for an operator:
    /// the actors were not silent).
    pub fn renew_leases(&mut self) {
        let now = Instant::now();
        self.out.iter_mut().for_each(|o| o.heard = now);
    }

    /// Forgets every job out (their late chunks will be ignored).
    pub fn forget_all(&mut self) {
        self.out.clear();
    }

    /// Sends `job` out; returns its assignment id.
    pub fn issue(&mut self, links: &mut LearnerLinks, job: Job, tag: T) -> Result<u64, DispatchError> {
        let now = Instant::now();
        self.send(links, Out { id: 0, job, tag, chunks: Vec::new(), heard: now, empties: 0, steps: 0, first_issued: now, reissued: 0 })
    }

    fn send(&mut self, links: &mut LearnerLinks, mut o: Out<T>) -> Result<u64, DispatchError> {
        let t = Instant::now();
        self.next_id += 1;
        o.id = self.next_id;
        o.heard = Instant::now();
        o.chunks.clear();
        (o.empties, o.steps) = (0, 0);
        let j = &o.job;
        let a = Assignment {
            id: o.id,
            design_index: j.design_index,
            design: j.design.clone(),
            mode: j.mode,
            seed: j.seed,
            min_weights_version: j.min_weights_version,
        };
        links.assignments.send(a)?;
        self.out.push(o);
        self.stats.sending += t.elapsed().as_secs_f64();
        Ok(self.next_id)
    }

    /// Sends out again every job whose actor has fallen silent (or reports it).
    fn expire(&mut self, links: &mut LearnerLinks) -> Result<(), DispatchError> {
        let lease = self.cfg.lease;
        if !self.cfg.reissue {
            for o in self.out.iter_mut().filter(|o| o.heard.elapsed() > lease) {
                coadapt_log::logln!("{}: assignment {} ({}) silent for {lease:?}; waiting for it", self.name, o.id, o.tag);
                o.heard = Instant::now();
            }
            return Ok(());
        }
        while let Some(i) = self.out.iter().position(|o| o.heard.elapsed() > lease) {
            let mut o = self.out.swap_remove(i);
            let old = o.id;
            o.reissued += 1;
            self.stats.reissued += 1;
            let new = self.send(links, o)?;
            let tag = &self.out[self.out.len() - 1].tag;
            coadapt_log::logln!("{}: assignment {old} ({tag}) silent for {lease:?}: issued again as {new}", self.name);
        }
        Ok(())
    }

    /// Sends the job at `i` out again because of `why`.
    fn again(&mut self, links: &mut LearnerLinks, i: usize, why: &str) -> Result<(), DispatchError> {
        let mut o = self.out.swap_remove(i);
        let actor = o.chunks.last().map_or(0, |c| c.actor);
        coadapt_log::logln!("{}: {} (assignment {}, actor {actor}): {why}; issued again", self.name, o.tag, o.id);
        o.reissued += 1;
        self.stats.refused += 1;
        self.send(links, o).map(|_| ())
    }

    /// Waits for the next whole episode; `None` on shutdown.
    pub fn next_done(
        &mut self,
        links: &mut LearnerLinks,
        shutdown: &AtomicBool,
        check: &mut dyn Check<T>,
    ) -> Result<Option<Done<T>>, DispatchError> {
        self.next_done_while(links, &|| !shutdown.load(Ordering::Relaxed), check)
    }

    /// Waits for the next whole episode while `wait()` holds (asked every poll interval);
    /// `None` once it does not. A learner stopping uses it to let the episodes already out
    /// come back, up to a deadline, so it can snapshot with nothing out.
    pub fn next_done_while(
        &mut self,
        links: &mut LearnerLinks,
        wait: &dyn Fn() -> bool,
        check: &mut dyn Check<T>,
    ) -> Result<Option<Done<T>>, DispatchError> {
        let mut heard = Instant::now();
        loop {
            if !wait() {
                return Ok(None);
            }
            if let Some(why) = self.abort.as_ref().and_then(|f| f()) {
                return Err(DispatchError::Aborted(why));
            }
            if let Some(after) = self.cfg.deadline
                && let Some(o) = self.out.iter().find(|o| o.first_issued.elapsed() > after)
            {
                return Err(DispatchError::Deadline { what: o.tag.to_string(), after });
            }
            // Every time round, not only when the queue is quiet: with many actors it rarely is.
            self.expire(links)?;
            let t = Instant::now();
            let got = match links.experience.recv_timeout(POLL) {
                Ok(got) => got,
                // Every actor has gone for now; restarted or new ones may join.
                Err(TransportError::Closed) => {
                    std::thread::sleep(POLL);
                    None
                }
                Err(e) => return Err(e.into()),
            };
            self.stats.waiting += t.elapsed().as_secs_f64();
            let Some(chunk) = got else {
                if let Some(after) = self.cfg.silence
                    && heard.elapsed() > after
                {
                    return Err(DispatchError::Silence { after, outstanding: self.out.len() });
                }
                continue;
            };
            heard = Instant::now();
            // A late chunk of a job already sent out again, or already done.
            let Some(i) = self.out.iter().position(|o| o.id == chunk.assignment) else { continue };
            if let Err(why) = check.chunk(&chunk) {
                self.again(links, i, &format!("a malformed chunk ({why})"))?;
                continue;
            }
            let max = self.cfg.max_steps;
            let o = &mut self.out[i];
            let progress = !chunk.is_empty() || chunk.end.is_some();
            // Keep-alives refresh the lease at most once per step of an episode.
            if progress || max == 0 || o.empties < max as u64 {
                o.heard = Instant::now();
            }
            if !progress {
                o.empties += 1;
                continue;
            }
            if chunk.first && !o.chunks.is_empty() {
                coadapt_log::logln!(
                    "{}: actor {} restarted assignment {} ({}): dropping {} chunk(s) of its failed attempt",
                    self.name,
                    chunk.actor,
                    o.id,
                    o.tag,
                    o.chunks.len()
                );
                o.chunks.clear();
                o.steps = 0;
                self.stats.restarted += 1;
            }
            o.steps += chunk.len();
            let end = chunk.end;
            o.chunks.push(chunk);
            if max > 0 && o.steps > max {
                let why = format!("{} transitions and no end (at most {max})", o.steps);
                self.again(links, i, &why)?;
                continue;
            }
            let Some(end) = end else { continue };
            let o = self.out.swap_remove(i);
            let weights_version = o.chunks.iter().map(|c| c.weights_version).min().unwrap_or(o.job.min_weights_version);
            let done = Done {
                actor: o.chunks.last().map_or(0, |c| c.actor),
                weights_version,
                steps: o.steps,
                reissued: o.reissued,
                seconds: o.first_issued.elapsed().as_secs_f64(),
                id: o.id,
                end,
                chunks: o.chunks,
                job: o.job,
                tag: o.tag,
            };
            match check.episode(&done) {
                Verdict::Accept => return Ok(Some(done)),
                Verdict::Fail(why) => return Err(DispatchError::Refused(why)),
                Verdict::Again(why) => {
                    let now = Instant::now();
                    coadapt_log::logln!("{}: {} (assignment {}, actor {}): {why}; issued again", self.name, done.tag, done.id, done.actor);
                    self.stats.refused += 1;
                    let o = Out {
                        id: 0,
                        job: done.job,
                        tag: done.tag,
                        chunks: Vec::new(),
                        heard: now,
                        empties: 0,
                        steps: 0,
                        first_issued: now.checked_sub(Duration::from_secs_f64(done.seconds)).unwrap_or(now),
                        reissued: done.reissued + 1,
                    };
                    self.send(links, o)?;
                }
            }
        }
    }
}

impl From<TransportError> for DispatchError {
    fn from(e: TransportError) -> Self {
        Self::Transport(e)
    }
}
