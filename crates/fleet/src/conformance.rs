//! What the fleet must do over every transport, as functions over a learner's and its actors'
//! links; `tests/conformance.rs` calls each over in-process channels, shared memory and gRPC.
//! They panic (assert) on a violation, like any test.
//!
//! The episodes are a fake experiment's ([`Counting`]): assignment seed `s` is an episode of
//! `3 + s % 7` steps whose rewards are `s + t`, so what comes back can be checked exactly.

use std::any::Any;
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use coadapt_core::Transition;
use coadapt_transport::{
    ActorLinks, Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, LearnerLinks, Weights, newest_or_stop, next_or_stop,
};

use crate::actor::{self, ActorConfig, ActorSummary, Failure, Stream, Worker};
use crate::dispatch::{AcceptAll, Check, DispatchConfig, DispatchError, Dispatcher, Done, Job, Verdict};

/// Observation and action widths of the fake episodes.
pub const OBS: usize = 3;
pub const ACT: usize = 2;

/// A learner's links and its actors', with whatever keeps the transport up (a server).
pub struct FleetUnderTest {
    pub learner: LearnerLinks,
    pub actors: Vec<ActorLinks>,
    pub guard: Box<dyn Any + Send>,
}

impl std::fmt::Debug for FleetUnderTest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FleetUnderTest").field("actors", &self.actors.len()).finish_non_exhaustive()
    }
}

/// Steps of the episode seeded `seed`.
pub fn steps_of(seed: u64) -> usize {
    3 + (seed % 7) as usize
}

/// The return of the episode seeded `seed`.
pub fn return_of(seed: u64) -> f32 {
    (0..steps_of(seed)).map(|t| (seed + t as u64) as f32).sum()
}

/// The fake experiment: counts. Seeds in `fail_once` fail in their environment at step 2 the
/// first time they run on this actor.
#[derive(Debug, Default)]
pub struct Counting {
    pub fail_once: Vec<u64>,
    pub version: u64,
}

impl Worker for Counting {
    type Error = String;

    fn set_weights(&mut self, w: &Arc<Weights>) -> Result<(), String> {
        self.version = w.version;
        Ok(())
    }

    fn run(&mut self, a: &Assignment, stream: &mut Stream<'_>) -> Result<Option<EpisodeEnd>, Failure<String>> {
        let (mut obs, mut next) = ([0.0f32; OBS], [0.0f32; OBS]);
        let mut ret = 0.0;
        let n = steps_of(a.seed);
        for t in 0..n {
            if t == 2
                && let Some(i) = self.fail_once.iter().position(|&s| s == a.seed)
            {
                self.fail_once.swap_remove(i);
                return Err(Failure::Env(format!("seed {} failed at step 2 (on purpose)", a.seed)));
            }
            let r = (a.seed + t as u64) as f32;
            next[0] = r;
            ret += r;
            let tr = Transition { obs: &obs, action: &[0.5; ACT], reward: r, next_obs: &next, terminated: t + 1 == n };
            if stream.push(&tr).is_break() {
                break;
            }
            obs = next;
        }
        Ok(Some(EpisodeEnd { episode_return: ret, length: n as u64 }))
    }
}

/// Starts `worker`s on `actors` (ids from 1) until their queue closes.
pub fn start_actors(actors: Vec<ActorLinks>, cfg: ActorConfig, stop: &Arc<AtomicBool>) -> Vec<JoinHandle<ActorSummary>> {
    actors
        .into_iter()
        .enumerate()
        .map(|(i, mut links)| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut w = Counting::default();
                actor::run(&mut w, i as u64 + 1, &mut links, &cfg, &stop).expect("the actor loop")
            })
        })
        .collect()
}

fn dispatcher(lease: Duration) -> Dispatcher<u64> {
    Dispatcher::new("test", DispatchConfig { lease, deadline: Some(Duration::from_secs(60)), max_steps: 20, ..DispatchConfig::default() })
}

fn job(seed: u64, version: u64) -> Job {
    Job { design_index: 0, design: vec![], mode: EpisodeMode::Train, seed, min_weights_version: version }
}

fn publish(links: &mut LearnerLinks, version: u64) {
    links.acting_weights.publish(Weights { version, policy: vec![1.0; 4], q1: vec![], q2: vec![], heads: vec![] }).expect("publish");
}

/// The episode's transitions as they came back, checked against its seed.
fn assert_whole(d: &Done<u64>) {
    let s = d.tag;
    let rewards: Vec<f32> = d.chunks.iter().flat_map(|c| c.rewards.iter().copied()).collect();
    let want: Vec<f32> = (0..steps_of(s)).map(|t| (s + t as u64) as f32).collect();
    assert_eq!(rewards, want, "episode {s} came back with other transitions");
    assert_eq!(d.end, EpisodeEnd { episode_return: return_of(s), length: steps_of(s) as u64 });
    assert_eq!(d.steps, steps_of(s));
    assert!(d.chunks[0].first, "episode {s}: its first chunk is not marked first");
}

/// Twenty episodes on two actors: each comes back once, whole, in chunks of at most
/// `chunk_len`; the actors ran exactly twenty.
pub fn every_job_comes_back_exactly_once(f: FleetUnderTest) {
    let FleetUnderTest { mut learner, actors, guard } = f;
    let stop = Arc::new(AtomicBool::new(false));
    let threads = start_actors(actors, ActorConfig { chunk_len: 4, ..ActorConfig::default() }, &stop);
    let mut d = dispatcher(Duration::from_secs(30));
    publish(&mut learner, 1);
    for s in 0..20 {
        d.issue(&mut learner, job(s, 1), s).expect("issue");
    }
    let mut back = HashMap::new();
    while back.len() < 20 {
        let done = d.next_done(&mut learner, &stop, &mut AcceptAll).expect("next").expect("not stopped");
        assert_whole(&done);
        assert!(done.chunks.iter().all(|c| c.len() <= 4), "a chunk longer than chunk_len");
        assert_eq!(done.reissued, 0);
        assert!(back.insert(done.tag, done.actor).is_none(), "episode {} came back twice", done.tag);
    }
    assert_eq!(d.outstanding(), 0);
    drop(learner);
    drop(guard);
    let ran: u64 = threads.into_iter().map(|t| t.join().expect("actor thread").episodes).sum();
    assert_eq!(ran, 20, "the actors ran {ran} episodes for 20 assignments");
}

/// An actor takes an episode and goes silent: after the lease it goes to the other actor, comes
/// back once, and the silent actor's late chunk is ignored.
pub fn a_silent_actors_job_goes_to_another_after_its_lease(f: FleetUnderTest) {
    let FleetUnderTest { mut learner, mut actors, guard } = f;
    let stop = Arc::new(AtomicBool::new(false));
    let mut hung = actors.remove(0);
    let mut d = dispatcher(Duration::from_millis(400));
    publish(&mut learner, 1);
    d.issue(&mut learner, job(5, 1), 5).expect("issue");
    let taken = next_or_stop(hung.assignments.as_mut(), &stop).expect("receive").expect("the hung actor takes the episode");
    let healthy = start_actors(actors, ActorConfig::default(), &stop);
    let t = Instant::now();
    let done = d.next_done(&mut learner, &stop, &mut AcceptAll).expect("next").expect("not stopped");
    assert!(t.elapsed() >= Duration::from_millis(300), "issued again before the lease ran out ({:?})", t.elapsed());
    assert_whole(&done);
    assert_eq!((done.reissued, d.stats.reissued), (1, 1));
    assert_ne!(done.id, taken.id, "it came back under the silent actor's assignment");
    // The silent actor wakes up and sends its whole episode: nobody wants it any more.
    let late = ExperienceChunk {
        actor: 99,
        assignment: taken.id,
        weights_version: 1,
        first: true,
        obs: vec![0.0; OBS],
        actions: vec![0.0; ACT],
        rewards: vec![7.0],
        next_obs: vec![0.0; OBS],
        terminated: vec![true],
        end: Some(EpisodeEnd { episode_return: 7.0, length: 1 }),
        ..ExperienceChunk::default()
    };
    let _ = hung.experience.send(late);
    d.issue(&mut learner, job(6, 1), 6).expect("issue");
    let next = d.next_done(&mut learner, &stop, &mut AcceptAll).expect("next").expect("not stopped");
    assert_eq!(next.tag, 6, "the late chunk of the silent copy was taken for an episode");
    assert_whole(&next);
    drop(learner);
    drop(guard);
    drop(hung);
    for t in healthy {
        t.join().expect("actor thread");
    }
}

/// An episode whose environment fails at step 2 is run again by its actor: the learner forgets
/// the failed attempt and gets the episode whole, once.
pub fn a_restarted_episode_comes_back_whole(f: FleetUnderTest) {
    let FleetUnderTest { mut learner, mut actors, guard } = f;
    let stop = Arc::new(AtomicBool::new(false));
    let mut links = actors.remove(0);
    // Chunks of one step: the failed attempt has sent two before it fails.
    let cfg = ActorConfig { chunk_len: 1, env_retries: 1, ..ActorConfig::default() };
    let stop2 = stop.clone();
    let thread = std::thread::spawn(move || {
        let mut w = Counting { fail_once: vec![4], ..Counting::default() };
        actor::run(&mut w, 1, &mut links, &cfg, &stop2).expect("the actor loop")
    });
    let mut d = dispatcher(Duration::from_secs(30));
    publish(&mut learner, 1);
    d.issue(&mut learner, job(4, 1), 4).expect("issue");
    let done = d.next_done(&mut learner, &stop, &mut AcceptAll).expect("next").expect("not stopped");
    assert_whole(&done);
    assert_eq!((d.stats.restarted, done.reissued), (1, 0));
    drop(learner);
    drop(guard);
    let s = thread.join().expect("actor thread");
    assert_eq!((s.episodes, s.failed_episodes), (1, 1));
}

/// A check that refuses the first copy of every episode, and fails the run on seed 13.
#[derive(Debug, Default)]
struct Picky {
    refused: Vec<u64>,
}

impl Check<u64> for Picky {
    fn chunk(&mut self, c: &ExperienceChunk) -> Result<(), String> {
        if c.obs.len() != c.len() * OBS { Err(format!("{} obs values for {} steps", c.obs.len(), c.len())) } else { Ok(()) }
    }

    fn episode(&mut self, d: &Done<u64>) -> Verdict {
        if d.tag == 13 {
            return Verdict::Fail("seed 13 is unlucky".into());
        }
        if self.refused.contains(&d.tag) {
            return Verdict::Accept;
        }
        self.refused.push(d.tag);
        Verdict::Again("first copies are refused".into())
    }
}

/// What the experiment refuses goes out again; what it finds fatal fails the wait.
pub fn a_refused_episode_goes_out_again_and_a_fatal_one_fails(f: FleetUnderTest) {
    let FleetUnderTest { mut learner, actors, guard } = f;
    let stop = Arc::new(AtomicBool::new(false));
    let threads = start_actors(actors, ActorConfig::default(), &stop);
    let mut d = dispatcher(Duration::from_secs(30));
    let mut check = Picky::default();
    publish(&mut learner, 1);
    d.issue(&mut learner, job(8, 1), 8).expect("issue");
    let done = d.next_done(&mut learner, &stop, &mut check).expect("next").expect("not stopped");
    assert_whole(&done);
    assert_eq!((done.reissued, d.stats.refused), (1, 1));
    d.issue(&mut learner, job(13, 1), 13).expect("issue");
    match d.next_done(&mut learner, &stop, &mut check) {
        Err(DispatchError::Refused(why)) => assert!(why.contains("unlucky"), "{why}"),
        other => panic!("a fatal verdict did not fail the wait: {other:?}"),
    }
    drop(learner);
    drop(guard);
    for t in threads {
        t.join().expect("actor thread");
    }
}

/// An actor that sends a malformed chunk, or only keep-alives, cannot keep a job: it goes to
/// another actor.
pub fn bad_or_idle_actors_cannot_keep_a_job(f: FleetUnderTest) {
    let FleetUnderTest { mut learner, mut actors, guard } = f;
    let stop = Arc::new(AtomicBool::new(false));
    let mut bad = actors.remove(0);
    let mut d = dispatcher(Duration::from_millis(300));
    d.cfg.max_steps = 10;
    let mut check = Picky { refused: vec![9, 10] };
    publish(&mut learner, 1);
    d.issue(&mut learner, job(9, 1), 9).expect("issue");
    d.issue(&mut learner, job(10, 1), 10).expect("issue");
    // The bad actor takes both: a malformed chunk for one, keep-alives for ever for the other.
    let a = next_or_stop(bad.assignments.as_mut(), &stop).expect("receive").expect("an assignment");
    let b = next_or_stop(bad.assignments.as_mut(), &stop).expect("receive").expect("an assignment");
    newest_or_stop(bad.weights.as_mut(), 1, &stop).expect("weights").expect("weights");
    let malformed = ExperienceChunk {
        actor: 50,
        assignment: a.id,
        weights_version: 1,
        first: true,
        obs: vec![0.0; OBS + 1],
        actions: vec![0.0; ACT],
        rewards: vec![1.0],
        next_obs: vec![0.0; OBS],
        terminated: vec![false],
        ..ExperienceChunk::default()
    };
    let _ = bad.experience.send(malformed);
    let idle = std::thread::spawn(move || {
        // 40 keep-alives, 120 ms apart (gRPC passes on at most one per heartbeat): without a
        // bound they would hold the lease for 4.8 s.
        for _ in 0..40 {
            let keep = ExperienceChunk { actor: 50, assignment: b.id, weights_version: 1, ..ExperienceChunk::default() };
            if bad.experience.send(keep).is_err() {
                break;
            }
            std::thread::sleep(Duration::from_millis(120));
        }
        bad
    });
    let healthy = start_actors(actors, ActorConfig::default(), &stop);
    let t = Instant::now();
    let mut back = Vec::new();
    while back.len() < 2 {
        let done = d.next_done(&mut learner, &stop, &mut check).expect("next").expect("not stopped");
        assert_whole(&done);
        assert!(done.reissued >= 1, "episode {} came back from the bad actor", done.tag);
        back.push(done.tag);
    }
    back.sort_unstable();
    assert_eq!(back, [9, 10]);
    // 10 keep-alives (max_steps) at 120 ms, then the lease: well before the 4.8 s of keep-alives.
    assert!(t.elapsed() < Duration::from_millis(3500), "the keep-alives held the job for {:?}", t.elapsed());
    drop(learner);
    drop(guard);
    drop(idle.join().expect("idle thread"));
    for t in healthy {
        t.join().expect("actor thread");
    }
}

/// With no actor at all, the wait ends: on shutdown (`None`), after `silence`, after the
/// deadline, or when `abort` says why.
pub fn a_wait_without_actors_ends(f: FleetUnderTest) {
    // The actors are there but do nothing.
    let FleetUnderTest { mut learner, actors: _idle, guard } = f;
    publish(&mut learner, 1);
    let stop = AtomicBool::new(false);
    let cfg = DispatchConfig { lease: Duration::from_secs(30), silence: Some(Duration::from_millis(300)), ..DispatchConfig::default() };
    let mut d: Dispatcher<u64> = Dispatcher::new("test", cfg);
    d.issue(&mut learner, job(1, 1), 1).expect("issue");
    assert!(matches!(d.next_done(&mut learner, &stop, &mut AcceptAll), Err(DispatchError::Silence { outstanding: 1, .. })));
    d.cfg.silence = None;
    d.cfg.deadline = Some(Duration::from_millis(200));
    match d.next_done(&mut learner, &stop, &mut AcceptAll) {
        Err(DispatchError::Deadline { what, .. }) => assert_eq!(what, "1"),
        other => panic!("no deadline: {other:?}"),
    }
    d.cfg.deadline = None;
    d.abort = Some(Box::new(|| Some("every actor process has ended".into())));
    assert!(matches!(d.next_done(&mut learner, &stop, &mut AcceptAll), Err(DispatchError::Aborted(_))));
    d.abort = None;
    stop.store(true, Ordering::Relaxed);
    assert!(d.next_done(&mut learner, &stop, &mut AcceptAll).expect("shutdown").is_none());
    drop(guard);
}
