//! Flow control between collecting experience and training on it.
//!
//! Every finished training episode buys exactly the reference's updates
//! ([`crate::fear::FearLearner::end_episode`]), so the ratio of updates to collected steps is
//! the reference's whatever the number of actors; what changes with the mode is only how many
//! episodes may run while the learner trains:
//! - `lock-step`: one at a time: collect an episode, train, evaluate, next (the reference
//!   schedule; a seed reproduces a run bit for bit whatever the number of actors);
//! - `async`: up to `max-in-flight` episodes run on the actors while the learner trains on
//!   those already back. Collection can run ahead of training by at most that many episodes
//!   (Reverb's samples-per-insert limiter with a window), so adding actors never skews the
//!   ratio; episodes then act with slightly older weights, which each episode row reports as
//!   its policy lag.
//!
//! An episode is held by the learner until its last chunk arrives and only then enters the
//! replay buffers, so an actor killed mid-episode leaves nothing half-written. An episode
//! whose actor has sent nothing for `assignment-lease-secs` is issued again (same seed) to
//! whichever actor asks next.

use std::time::Duration;

use coadapt_transport::{EpisodeEnd, EpisodeMode, ExperienceChunk};
use serde::{Deserialize, Serialize};

use crate::ConfigError;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FlowMode {
    /// One episode at a time (the reference schedule, reproducible).
    #[default]
    LockStep,
    /// Several episodes in flight while the learner trains.
    Async,
}

/// The `[flow]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct FlowConfig {
    /// `lock-step` (the reference schedule) or `async`.
    pub mode: FlowMode,
    /// Episodes outstanding at once in `async` mode (0: one per actor).
    pub max_in_flight: usize,
    /// Issue an episode again when its actor has sent nothing for this long (seconds).
    /// Actors report at least every `chunk-len` steps, evaluation episodes included.
    pub assignment_lease_secs: f64,
    /// Issue a silent episode again (true: simulated actors, where a re-run costs nothing).
    /// False for real robots: a robot that pauses (a person resetting it, a battery swap) is
    /// waited for and its episode not re-run elsewhere (every re-run costs wear); the silence
    /// is reported once per lease. Pair it with `schedule.episode-timeout-secs = 0`.
    pub reissue_silent_episodes: bool,
}

impl Default for FlowConfig {
    fn default() -> Self {
        Self { mode: FlowMode::LockStep, max_in_flight: 0, assignment_lease_secs: 60.0, reissue_silent_episodes: true }
    }
}

impl FlowConfig {
    /// Episodes that may be outstanding with `actors` actors.
    pub fn in_flight(&self, actors: usize) -> usize {
        match self.mode {
            FlowMode::LockStep => 1,
            FlowMode::Async if self.max_in_flight > 0 => self.max_in_flight,
            FlowMode::Async => actors.max(1),
        }
    }

    /// Checks the fields a user can get wrong.
    pub fn lease(&self) -> Result<Duration, ConfigError> {
        let t = self.assignment_lease_secs;
        match Duration::try_from_secs_f64(t) {
            Ok(d) if t > 0.0 => Ok(d),
            _ => Err(ConfigError::NotPositiveSeconds { key: "flow.assignment-lease-secs", value: t }),
        }
    }
}

/// An episode whose last chunk has arrived.
#[derive(Debug)]
pub struct Completed {
    pub episode: usize,
    pub global: u64,
    pub mode: EpisodeMode,
    pub chunks: Vec<ExperienceChunk>,
    pub end: EpisodeEnd,
    pub actor: u64,
    /// The weights version the actor acted with (the oldest, if its chunks disagree).
    pub weights_version: u64,
    /// Versions published between the one acted with and the newest when it came back.
    pub policy_lag: u64,
}

/// Where the learner's time went (seconds), for the run summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LearnerTime {
    /// Blocked on the transport waiting for experience or design replies.
    pub waiting: f64,
    /// Publishing weights and sending assignments.
    pub sending: f64,
    /// Gradient updates (those made while waiting for an operator too).
    pub training: f64,
    /// Episodes issued again after their actor fell silent.
    pub reissued: u64,
    /// Episodes an actor ran again from the start after its environment failed (the failed
    /// attempt's experience was dropped).
    pub restarted: u64,
    /// Largest policy lag seen (weights versions between acting and the newest).
    pub max_policy_lag: u64,
    /// Waiting for an operator to build (or reject) a prototype (`schedule.confirm-designs`),
    /// population updates made meanwhile included; not counted in `waiting`.
    pub waiting_for_prototype: f64,
    /// Waiting for an operator to reset the robot (`schedule.reset-needs-confirmation`).
    pub waiting_for_reset: f64,
    /// Population updates made while waiting (`schedule.train-while-waiting`).
    pub updates_while_waiting: u64,
    /// Design requests sent again after `schedule.design-request-resend-secs` without a reply.
    #[serde(default)]
    pub design_requests_resent: u64,
    /// Design replies refused: malformed, or outside the design box.
    #[serde(default)]
    pub design_replies_refused: u64,
    /// Episodes rejected for an observation or reward beyond `schedule.max-abs-observation` /
    /// `max-abs-reward` (a sensor glitch) and run again.
    #[serde(default)]
    pub episodes_rejected: u64,
    /// Updates that produced non-finite values and were rolled back
    /// (`learner.on-non-finite = "roll-back"`).
    #[serde(default)]
    pub rollbacks: u64,
}
