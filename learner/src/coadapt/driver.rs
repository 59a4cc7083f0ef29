//! The learner's side of the fleet: publishing weights, handing out episodes, collecting their
//! experience (with leases and restarts), training on it, and asking the optimiser for designs.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::{EnvSpec, Transition};
use coadapt_fleet::{Check, DispatchError, Dispatcher, Done, Job, Verdict};
use coadapt_transport::messages::Dims;
use coadapt_transport::{DesignKind, DesignRequest, EpisodeMode, LearnerLinks, TransportError, Validate, Weights};

use super::{CoadaptError, ScheduleConfig};
use crate::fear::{ActingPolicy, FearLearner};
use crate::flow::{Completed, LearnerTime};
use crate::run_dir::DesignRow;

pub(super) fn mix(seed: u64, i: u64) -> u64 {
    let mut z = seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z ^ (z >> 27)
}

pub(super) const POLL: Duration = Duration::from_millis(100);

/// Episodes rejected in a row for magnitudes before the run stops: the limits, not the sensors,
/// are wrong.
const MAX_REJECTED_IN_A_ROW: u32 = 10;

/// The first observation or reward of an episode beyond the configured magnitudes (0: no
/// limit), named.
fn beyond_limits(chunks: &[coadapt_transport::ExperienceChunk], max_obs: f32, max_rew: f32) -> Option<String> {
    let find = |field: &str, v: &[f32], max: f32| {
        (max > 0.0).then(|| v.iter().position(|x| x.abs() > max).map(|i| format!("{field}[{i}] = {} is beyond {max}", v[i]))).flatten()
    };
    chunks.iter().find_map(|c| {
        find("obs", &c.obs, max_obs).or_else(|| find("next_obs", &c.next_obs, max_obs)).or_else(|| find("rewards", &c.rewards, max_rew))
    })
}

/// An episode of the run, as the fleet's dispatcher names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct EpisodeTag {
    pub(super) design: usize,
    /// Episode within its design.
    pub(super) episode: usize,
    /// Training episodes of the run before this one (seeds derive from it).
    pub(super) global: u64,
}

impl std::fmt::Display for EpisodeTag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "episode {} of design {}", self.episode, self.design)
    }
}

/// What the co-adaptation checks of the experience that comes back: chunks of the robot's
/// widths, training episodes whose length matches what was streamed, and magnitudes within the
/// configured limits (a sensor glitch is run again; ten in a row stop the run).
struct EpisodeCheck<'c> {
    dims: &'c Dims,
    max_obs: f32,
    max_rew: f32,
    rejected_in_a_row: &'c mut u32,
    rejected: &'c mut u64,
}

impl Check<EpisodeTag> for EpisodeCheck<'_> {
    fn chunk(&mut self, c: &coadapt_transport::ExperienceChunk) -> Result<(), String> {
        c.validate(self.dims).map_err(|e| e.to_string())
    }

    fn episode(&mut self, d: &Done<EpisodeTag>) -> Verdict {
        if d.job.mode == EpisodeMode::Train && d.end.length != d.steps as u64 {
            return Verdict::Again(format!("ends with length {} after {} transitions", d.end.length, d.steps));
        }
        if let Some(why) = beyond_limits(&d.chunks, self.max_obs, self.max_rew) {
            *self.rejected += 1;
            *self.rejected_in_a_row += 1;
            if *self.rejected_in_a_row > MAX_REJECTED_IN_A_ROW {
                return Verdict::Fail(format!(
                    "{MAX_REJECTED_IN_A_ROW} episodes in a row rejected (the last: {why}): schedule.max-abs-observation or max-abs-reward is tighter than the robot's normal range"
                ));
            }
            return Verdict::Again(format!("rejected: {why}"));
        }
        *self.rejected_in_a_row = 0;
        Verdict::Accept
    }
}

impl From<DispatchError> for CoadaptError {
    fn from(e: DispatchError) -> Self {
        match e {
            DispatchError::Transport(t) => Self::Transport(t),
            other => Self::Protocol(other.to_string()),
        }
    }
}

pub(super) struct Learner<'a> {
    pub(super) cfg: &'a ScheduleConfig,
    pub(super) spec: &'a EnvSpec,
    pub(super) dims: Dims,
    pub(super) links: &'a mut LearnerLinks,
    pub(super) shutdown: &'a AtomicBool,
    pub(super) fear: FearLearner,
    pub(super) acting_version: u64,
    /// The acting policy changed since it was last published.
    pub(super) acting_dirty: bool,
    /// The longest time an episode took from its issue to its end (seconds), for how long a
    /// stop waits for what is out.
    pub(super) longest_episode: f64,
    /// Publish the acting policy again under its version (a resumed run's actors have none).
    pub(super) republish: bool,
    pub(super) acting_which: Option<ActingPolicy>,
    pub(super) population_version: u64,
    pub(super) seed: u64,
    /// The episodes out with the actors: leases, reissue, restarts (`coadapt_fleet`).
    pub(super) fleet: Dispatcher<EpisodeTag>,
    /// Episodes rejected for magnitudes since the last accepted one.
    pub(super) rejected_in_a_row: u32,
    /// Seconds the last design request took.
    pub(super) last_request_seconds: f64,
    /// The learner's own times and counts; [`Learner::time`] adds the fleet's.
    pub(super) time: LearnerTime,
    /// The run directory (the operator's files live there).
    pub(super) dir: &'a Path,
    /// Designs the operator would not build, in order (`designs.csv` rows).
    pub(super) rejected: Vec<DesignRow>,
    /// What the last episode's training did and how long it took (for the event file).
    pub(super) last_training: Option<(crate::fear::EpisodeTraining, f64)>,
}

impl Learner<'_> {
    /// Where the learner's time went, the fleet's waits and reissues included.
    pub(super) fn time(&self) -> LearnerTime {
        let (mut t, f) = (self.time, self.fleet.stats);
        t.waiting += f.waiting;
        t.sending += f.sending;
        t.reissued += f.reissued;
        t.restarted += f.restarted;
        t
    }

    /// Publishes the acting policy if it changed; returns the version actors must act with.
    fn publish_acting(&mut self) -> Result<u64, CoadaptError> {
        let which = self.fear.acting();
        let changed = self.acting_dirty || self.acting_which != Some(which);
        if !changed && !self.republish {
            return Ok(self.acting_version);
        }
        let t = Instant::now();
        if changed {
            self.acting_version += 1;
        }
        self.republish = false;
        let policy = self.fear.agent(which).policy_params().to_vec();
        self.links.acting_weights.publish(Weights { version: self.acting_version, policy, q1: vec![], q2: vec![], heads: vec![] })?;
        self.acting_dirty = false;
        self.acting_which = Some(which);
        self.time.sending += t.elapsed().as_secs_f64();
        Ok(self.acting_version)
    }

    fn publish_population(&mut self) -> Result<u64, CoadaptError> {
        self.population_version += 1;
        let pop = self.fear.agent(ActingPolicy::Population);
        let w = Weights {
            version: self.population_version,
            policy: pop.policy_params().to_vec(),
            q1: pop.critic_params(0).0.to_vec(),
            q2: pop.critic_params(1).0.to_vec(),
            heads: (0..pop.extra_heads()).map(|i| pop.head_params(i).to_vec()).collect(),
        };
        self.links.population_weights.publish(w)?;
        Ok(self.population_version)
    }

    /// Hands episode `episode` of design `design_index` to the actors.
    pub(super) fn issue(
        &mut self,
        design_index: usize,
        design: &[f32],
        episode: usize,
        global: u64,
        mode: EpisodeMode,
    ) -> Result<(), CoadaptError> {
        let version = self.publish_acting()?;
        let seed = mix(self.seed, 2 * global + u64::from(mode == EpisodeMode::Eval));
        let job = Job { design_index: design_index as u32, design: design.to_vec(), mode, seed, min_weights_version: version };
        self.fleet.issue(self.links, job, EpisodeTag { design: design_index, episode, global })?;
        Ok(())
    }

    /// Waits for the next episode to come back; `None` on shutdown, or with `until`, once that
    /// time has passed (shutdown or not: a stopping learner lets what is out come back).
    pub(super) fn next_completed(&mut self, until: Option<Instant>) -> Result<Option<Completed>, CoadaptError> {
        let mut check = EpisodeCheck {
            dims: &self.dims,
            max_obs: self.cfg.max_abs_observation,
            max_rew: self.cfg.max_abs_reward,
            rejected_in_a_row: &mut self.rejected_in_a_row,
            rejected: &mut self.time.episodes_rejected,
        };
        let shutdown = self.shutdown;
        let wait = move || match until {
            Some(t) => Instant::now() < t,
            None => !shutdown.load(Ordering::Relaxed),
        };
        let Some(d) = self.fleet.next_done_while(self.links, &wait, &mut check)? else { return Ok(None) };
        self.longest_episode = self.longest_episode.max(d.seconds);
        let policy_lag = self.acting_version.saturating_sub(d.weights_version);
        self.time.max_policy_lag = self.time.max_policy_lag.max(policy_lag);
        Ok(Some(Completed {
            episode: d.tag.episode,
            global: d.tag.global,
            mode: d.job.mode,
            chunks: d.chunks,
            end: d.end,
            actor: d.actor,
            weights_version: d.weights_version,
            policy_lag,
        }))
    }

    /// Puts a finished training episode into the replay buffers and trains on it.
    pub(super) fn learn_from(&mut self, c: &Completed) -> Result<(), CoadaptError> {
        let (o, a) = (self.dims.obs, self.dims.act);
        for chunk in &c.chunks {
            if chunk.first {
                self.fear.add_start_state(&chunk.obs[..o])?;
            }
            for i in 0..chunk.len() {
                self.fear.add_transition(&Transition {
                    obs: &chunk.obs[i * o..(i + 1) * o],
                    action: &chunk.actions[i * a..(i + 1) * a],
                    reward: chunk.rewards[i],
                    next_obs: &chunk.next_obs[i * o..(i + 1) * o],
                    terminated: chunk.terminated[i],
                })?;
            }
        }
        let t = Instant::now();
        let trained = self.fear.end_episode()?;
        let took = t.elapsed().as_secs_f64();
        self.time.training += took;
        self.last_training = Some((trained.clone(), took));
        if let Some(why) = trained.rolled_back {
            self.time.rollbacks += 1;
            coadapt_log::logln!(
                "learner: {why}; rolled the networks back to before this episode's updates (learner.on-non-finite = \"roll-back\")"
            );
        }
        self.acting_dirty = true;
        Ok(())
    }

    /// The learner's scalars after an episode (TensorBoard's `loss/*`, `train/*`, `time/*`):
    /// the last update's losses and the episode's updates per second when it trained, the
    /// entropy weights, and the time spent so far waiting, training and sending.
    pub(super) fn episode_scalars(&self) -> Vec<(&'static str, f64)> {
        let time = self.time();
        let mut v = vec![
            ("train/alpha_individual", f64::from(self.fear.agent(ActingPolicy::Individual).alpha())),
            ("train/alpha_population", f64::from(self.fear.agent(ActingPolicy::Population).alpha())),
            ("time/waiting_seconds", time.waiting),
            ("time/training_seconds", time.training),
            ("time/sending_seconds", time.sending),
            ("train/replay_population", self.fear.population_transitions() as f64),
        ];
        if let Some((t, took)) = &self.last_training {
            let updates = (t.individual_updates + t.population_updates) as f64;
            if updates > 0.0 && *took > 0.0 {
                v.push(("train/updates_per_second", updates / took));
            }
            if let Some(l) = &t.last {
                v.extend([
                    ("loss/critic1", f64::from(l.q1)),
                    ("loss/critic2", f64::from(l.q2)),
                    ("loss/policy", f64::from(l.policy)),
                    ("loss/alpha", f64::from(l.alpha)),
                    ("train/log_pi", f64::from(l.log_pi)),
                ]);
            }
            // Mean Q at the designs the critic's own ascent reaches minus at the batch's: what
            // the conservative term holds down (COMs watches it).
            if let Some(p) = t.last_population.as_ref().filter(|_| self.fear.cfg.conservative.weight > 0.0) {
                v.push(("train/conservative_gap", f64::from(p.conservative_gap)));
                v.push(("train/conservative_weight", f64::from(p.conservative_weight)));
            }
        }
        v
    }

    /// Asks the optimiser for design `index`, telling it every design chosen and every one
    /// rejected so far; `None` on shutdown.
    pub(super) fn request_design(
        &mut self,
        index: usize,
        kind: DesignKind,
        chosen: &[f32],
    ) -> Result<Option<coadapt_transport::DesignReply>, CoadaptError> {
        let version = self.publish_population()?;
        let start_states = self
            .fear
            .sample_start_states(self.cfg.start_state_batch.max(1))
            .ok_or_else(|| CoadaptError::Protocol("no start states yet: the run needs at least one initial design".into()))?;
        let rejected = self.rejected.iter().flat_map(|r| r.design.iter().copied()).collect();
        let req = DesignRequest { index: index as u32, kind, weights_version: version, start_states, chosen: chosen.to_vec(), rejected };
        self.links.design_requests.send(req.clone())?;
        let t = Instant::now();
        let deadline = Duration::from_secs_f64(self.cfg.design_request_timeout_secs);
        let mut resend = Resend::new(self.cfg.design_request_resend_secs);
        let mut sent = Instant::now();
        // The optimiser's end of the replies closed (it died): a restarted one never saw the
        // request, so it is sent again as soon as the new one is there, not after `resend`.
        let mut optimiser_gone = false;
        // Over shared memory a killed optimiser may be cleaned up only after the supervisor's
        // new one has joined, so the replies never look closed: a sender that left while the
        // request was out says the same.
        let mut departures = self.links.design_replies.departures();
        let result = loop {
            if self.shutdown.load(Ordering::Relaxed) {
                break Ok(None);
            }
            if t.elapsed() > deadline {
                break Err(CoadaptError::Protocol(format!(
                    "no design {index} from the optimiser in {deadline:?} (schedule.design-request-timeout-secs): is it running?"
                )));
            }
            if sent.elapsed() > resend.wait {
                let waited = resend.wait;
                resend.back_off();
                coadapt_log::logln!(
                    "learner: no reply to design request {index} for {waited:?}; sending it again (the next copy after {:?})",
                    resend.wait
                );
                match self.links.design_requests.send(req.clone()) {
                    Ok(()) => self.time.design_requests_resent += 1,
                    // No optimiser listening: sent when one is back (below).
                    Err(TransportError::Closed) => optimiser_gone = true,
                    Err(e) => break Err(e.into()),
                }
                sent = Instant::now();
            }
            let received = self.links.design_replies.recv_timeout(POLL);
            if self.links.design_replies.departures() != departures {
                departures = self.links.design_replies.departures();
                optimiser_gone = true;
            }
            let reply = match received {
                Ok(Some(reply)) => reply,
                Ok(None) if optimiser_gone => {
                    // An optimiser is back (its end of the replies is open again).
                    match self.links.design_requests.send(req.clone()) {
                        Ok(()) => {
                            coadapt_log::logln!("learner: the optimiser is back; sent design request {index} to it again");
                            self.time.design_requests_resent += 1;
                            sent = Instant::now();
                            resend.reset();
                            optimiser_gone = false;
                        }
                        // Not listening for requests yet: the next poll tries again.
                        Err(TransportError::Closed) => {}
                        Err(e) => break Err(e.into()),
                    }
                    continue;
                }
                Ok(None) => continue,
                // The optimiser has gone (over shared memory, with the request it had taken).
                Err(TransportError::Closed) => {
                    optimiser_gone = true;
                    std::thread::sleep(POLL);
                    continue;
                }
                Err(e) => break Err(e.into()),
            };
            if reply.index as usize != index {
                coadapt_log::logln!("learner: ignored a reply for design {} while waiting for {index}", reply.index);
                continue;
            }
            // A reply that is malformed or outside the design box (an actor could not build the
            // body) is refused and counted, as if it had not come: the request is sent again
            // after its deadline, and the run fails only when no good reply comes in time.
            if let Err(e) = reply
                .validate(&self.dims)
                .map_err(|e| e.to_string())
                .and_then(|()| self.spec.design.check("design", &reply.design).map_err(|e| e.to_string()))
            {
                self.time.design_replies_refused += 1;
                coadapt_log::logln!("learner: refused the optimiser's design {index}: {e}");
                // It answers: the copy goes after the configured wait, not a backed-off one.
                resend.reset();
                continue;
            }
            break Ok(Some(reply));
        };
        self.time.waiting += t.elapsed().as_secs_f64();
        self.last_request_seconds = t.elapsed().as_secs_f64();
        result
    }
}

/// When a design request with no reply is sent again: after `schedule.design-request-resend-secs`,
/// then after twice as long each time, up to [`Resend::MAX_FACTOR`] times the setting. A request
/// lost on the way (a partition) is sent again soon; a search that takes many minutes (a Daisy
/// sim-PSO choice runs about 1,000 rollouts) is not sent again every minute: each copy is
/// answered from the optimiser's stored reply once it is done, so dozens of copies meant dozens
/// of duplicate replies and log lines. An optimiser that died is handled apart (its request goes
/// again as soon as a new one is there).
#[derive(Debug, Clone, Copy)]
struct Resend {
    base: Duration,
    wait: Duration,
}

impl Resend {
    const MAX_FACTOR: u32 = 16;

    fn new(secs: f64) -> Self {
        let base = Duration::from_secs_f64(secs);
        Self { base, wait: base }
    }

    fn back_off(&mut self) {
        // Saturating: a setting of years (a test's, an operator's "never") must not overflow.
        self.wait = self.wait.saturating_mul(2).min(self.base.saturating_mul(Self::MAX_FACTOR));
    }

    fn reset(&mut self) {
        self.wait = self.base;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resends_back_off_to_sixteen_times_the_setting_and_reset() {
        let mut r = Resend::new(60.0);
        let mut waits = vec![r.wait.as_secs()];
        for _ in 0..6 {
            r.back_off();
            waits.push(r.wait.as_secs());
        }
        assert_eq!(waits, [60, 120, 240, 480, 960, 960, 960]);
        r.reset();
        assert_eq!(r.wait, Duration::from_secs(60));
        let mut huge = Resend::new(1.5e19);
        huge.back_off();
        assert_eq!(huge.wait, Duration::MAX, "saturates instead of overflowing");
    }
}
