//! The learner's side of the fleet: publishing weights, handing out episodes, collecting their
//! experience (with leases and restarts), training on it, and asking the optimiser for designs.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::{EnvSpec, Transition};
use coadapt_transport::messages::Dims;
use coadapt_transport::{Assignment, DesignKind, DesignRequest, EpisodeMode, LearnerLinks, TransportError, Validate, Weights};

use super::{CoadaptError, ScheduleConfig};
use crate::fear::{ActingPolicy, FearLearner};
use crate::flow::{Completed, LearnerTime, Pending};
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

fn chunk_actor(chunks: &[coadapt_transport::ExperienceChunk]) -> u64 {
    chunks.last().map_or(0, |c| c.actor)
}

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
    /// Publish the acting policy again under its version (a resumed run's actors have none).
    pub(super) republish: bool,
    pub(super) acting_which: Option<ActingPolicy>,
    pub(super) population_version: u64,
    pub(super) next_assignment: u64,
    pub(super) seed: u64,
    pub(super) lease: Duration,
    /// No message at all for this long fails the run (every actor gone); `None`: never.
    pub(super) silence: Option<Duration>,
    /// Issue a silent episode again (false: wait for it, reporting the silence).
    pub(super) reissue: bool,
    /// Episodes rejected for magnitudes since the last accepted one.
    pub(super) rejected_in_a_row: u32,
    /// Seconds the last design request took.
    pub(super) last_request_seconds: f64,
    pub(super) pending: Vec<Pending>,
    pub(super) time: LearnerTime,
    /// The run directory (the operator's files live there).
    pub(super) dir: &'a Path,
    /// Designs the operator would not build, in order (`designs.csv` rows).
    pub(super) rejected: Vec<DesignRow>,
}

impl Learner<'_> {
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
        self.links.acting_weights.publish(Weights { version: self.acting_version, policy, q1: vec![], q2: vec![] })?;
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
        self.send_assignment(
            design_index,
            design,
            Pending {
                id: 0,
                episode,
                global,
                mode,
                seed,
                min_weights_version: version,
                chunks: Vec::new(),
                last_heard: Instant::now(),
                empties: 0,
            },
        )
    }

    fn send_assignment(&mut self, design_index: usize, design: &[f32], mut p: Pending) -> Result<(), CoadaptError> {
        let t = Instant::now();
        self.next_assignment += 1;
        p.id = self.next_assignment;
        p.last_heard = Instant::now();
        let a = Assignment {
            id: p.id,
            design_index: design_index as u32,
            design: design.to_vec(),
            mode: p.mode,
            seed: p.seed,
            min_weights_version: p.min_weights_version,
        };
        self.links.assignments.send(a)?;
        self.pending.push(p);
        self.time.sending += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Issues again every episode whose actor has fallen silent.
    fn reissue_expired(&mut self, design_index: usize, design: &[f32]) -> Result<(), CoadaptError> {
        if !self.reissue {
            for p in self.pending.iter_mut().filter(|p| p.last_heard.elapsed() > self.lease) {
                coadapt_log::logln!(
                    "learner: assignment {} (design {design_index}) silent for {:?}; waiting for it (flow.reissue-silent-episodes = false)",
                    p.id,
                    self.lease
                );
                // Reported once per lease.
                p.last_heard = Instant::now();
            }
            return Ok(());
        }
        while let Some(i) = self.pending.iter().position(|p| p.last_heard.elapsed() > self.lease) {
            let mut p = self.pending.swap_remove(i);
            let old = p.id;
            p.chunks.clear();
            p.empties = 0;
            self.send_assignment(design_index, design, p)?;
            self.time.reissued += 1;
            coadapt_log::logln!(
                "learner: assignment {old} (design {design_index}) silent for {:?}: issued again as {}",
                self.lease,
                self.next_assignment
            );
        }
        Ok(())
    }

    /// Waits for the next episode to come back; `None` on shutdown.
    pub(super) fn next_completed(&mut self, design_index: usize, design: &[f32]) -> Result<Option<Completed>, CoadaptError> {
        let mut heard = Instant::now();
        loop {
            if self.shutdown.load(Ordering::Relaxed) {
                return Ok(None);
            }
            // Every time round, not only when the queue is quiet: with many actors it rarely is.
            self.reissue_expired(design_index, design)?;
            let t = Instant::now();
            let got = match self.links.experience.recv_timeout(POLL) {
                Ok(got) => got,
                // Every actor has gone for now; restarted or new ones may join.
                Err(TransportError::Closed) => {
                    std::thread::sleep(POLL);
                    None
                }
                Err(e) => return Err(e.into()),
            };
            self.time.waiting += t.elapsed().as_secs_f64();
            let Some(chunk) = got else {
                if let Some(silence) = self.silence
                    && heard.elapsed() > silence
                {
                    return Err(CoadaptError::Protocol(format!(
                        "no actor has sent anything for {silence:?} ({} episodes outstanding): are the actors running?",
                        self.pending.len()
                    )));
                }
                continue;
            };
            heard = Instant::now();
            let Some(i) = self.pending.iter().position(|p| p.id == chunk.assignment) else {
                // A late chunk of an episode already issued again elsewhere.
                continue;
            };
            if let Err(e) = chunk.validate(&self.dims) {
                let p = self.pending.swap_remove(i);
                coadapt_log::logln!(
                    "learner: a malformed chunk of assignment {} from actor {}: {e}; issuing the episode again",
                    p.id,
                    chunk.actor
                );
                self.send_assignment(design_index, design, Pending { chunks: Vec::new(), empties: 0, ..p })?;
                continue;
            }
            let p = &mut self.pending[i];
            let progress = !chunk.is_empty() || chunk.end.is_some();
            // Keep-alives refresh the lease at most once per step of an episode.
            if progress || p.empties < self.spec.max_episode_steps as u64 {
                p.last_heard = Instant::now();
            }
            if !progress {
                p.empties += 1;
            }
            let end = chunk.end;
            if chunk.first && !p.chunks.is_empty() {
                // The actor ran the episode again from its start (the first attempt failed in
                // its environment): what that attempt sent is forgotten.
                coadapt_log::logln!(
                    "learner: actor {} restarted assignment {}: dropping {} chunk(s) of its failed attempt",
                    chunk.actor,
                    p.id,
                    p.chunks.len()
                );
                p.chunks.clear();
                self.time.restarted += 1;
            }
            if !chunk.is_empty() || chunk.end.is_some() {
                p.chunks.push(chunk);
            }
            if let Some(end) = end {
                let p = self.pending.swap_remove(i);
                let streamed: u64 = p.chunks.iter().map(|c| c.len() as u64).sum();
                if p.mode == EpisodeMode::Train && end.length != streamed {
                    coadapt_log::logln!(
                        "learner: episode {} of design {design_index} (assignment {}, actor {}) ends with length {} after {streamed} transitions; issuing it again",
                        p.episode,
                        p.id,
                        chunk_actor(&p.chunks),
                        end.length
                    );
                    self.send_assignment(design_index, design, Pending { chunks: Vec::new(), empties: 0, ..p })?;
                    continue;
                }
                if let Some(why) = beyond_limits(&p.chunks, self.cfg.max_abs_observation, self.cfg.max_abs_reward) {
                    coadapt_log::logln!(
                        "learner: episode {} of design {design_index} (assignment {}, actor {}) rejected: {why}; running it again",
                        p.episode,
                        p.id,
                        chunk_actor(&p.chunks)
                    );
                    self.time.episodes_rejected += 1;
                    self.rejected_in_a_row += 1;
                    if self.rejected_in_a_row > MAX_REJECTED_IN_A_ROW {
                        return Err(CoadaptError::Protocol(format!(
                            "{MAX_REJECTED_IN_A_ROW} episodes in a row rejected (the last: {why}): schedule.max-abs-observation or max-abs-reward is tighter than the robot's normal range"
                        )));
                    }
                    self.send_assignment(design_index, design, Pending { chunks: Vec::new(), empties: 0, ..p })?;
                    continue;
                }
                self.rejected_in_a_row = 0;
                let last = p.chunks.last();
                let actor = last.map_or(0, |c| c.actor);
                let weights_version = p.chunks.iter().map(|c| c.weights_version).min().unwrap_or(p.min_weights_version);
                let policy_lag = self.acting_version.saturating_sub(weights_version);
                self.time.max_policy_lag = self.time.max_policy_lag.max(policy_lag);
                return Ok(Some(Completed {
                    episode: p.episode,
                    global: p.global,
                    mode: p.mode,
                    chunks: p.chunks,
                    end,
                    actor,
                    weights_version,
                    policy_lag,
                }));
            }
        }
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
        self.time.training += t.elapsed().as_secs_f64();
        if let Some(why) = trained.rolled_back {
            self.time.rollbacks += 1;
            coadapt_log::logln!(
                "learner: {why}; rolled the networks back to before this episode's updates (learner.on-non-finite = \"roll-back\")"
            );
        }
        self.acting_dirty = true;
        Ok(())
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
        let resend = Duration::from_secs_f64(self.cfg.design_request_resend_secs);
        let deadline = Duration::from_secs_f64(self.cfg.design_request_timeout_secs);
        let mut sent = Instant::now();
        // The optimiser's end of the replies closed (it died): a restarted one never saw the
        // request, so it is sent again as soon as the new one is there, not after `resend`.
        let mut optimiser_gone = false;
        let result = loop {
            if self.shutdown.load(Ordering::Relaxed) {
                break Ok(None);
            }
            if t.elapsed() > deadline {
                break Err(CoadaptError::Protocol(format!(
                    "no design {index} from the optimiser in {deadline:?} (schedule.design-request-timeout-secs): is it running?"
                )));
            }
            if sent.elapsed() > resend {
                coadapt_log::logln!("learner: no reply to design request {index} for {resend:?}; sending it again");
                match self.links.design_requests.send(req.clone()) {
                    Ok(()) => self.time.design_requests_resent += 1,
                    // No optimiser listening: sent when one is back (below).
                    Err(TransportError::Closed) => optimiser_gone = true,
                    Err(e) => break Err(e.into()),
                }
                sent = Instant::now();
            }
            let reply = match self.links.design_replies.recv_timeout(POLL) {
                Ok(Some(reply)) => reply,
                Ok(None) if optimiser_gone => {
                    // An optimiser is back (its end of the replies is open again).
                    match self.links.design_requests.send(req.clone()) {
                        Ok(()) => {
                            coadapt_log::logln!("learner: the optimiser is back; sent design request {index} to it again");
                            self.time.design_requests_resent += 1;
                            sent = Instant::now();
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
                continue;
            }
            break Ok(Some(reply));
        };
        self.time.waiting += t.elapsed().as_secs_f64();
        self.last_request_seconds = t.elapsed().as_secs_f64();
        result
    }
}
