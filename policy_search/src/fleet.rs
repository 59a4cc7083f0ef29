//! Rollouts through a fleet of actors: on a real robot the rollouts of an iteration are the
//! expensive part and independent of each other, so they go out over the same transports as a
//! co-adaptation's episodes (in process, shared memory, gRPC).
//!
//! The protocol, on the fleet's existing messages: an iteration publishes one acting-weights
//! version whose `policy` holds every rollout's open-loop actions (`rollouts x steps x
//! action_dim`: the sampled parameters already multiplied out with the time features, which is
//! all an episodic policy is; a few kB, no network), then one assignment per rollout whose
//! `seed` is the rollout's index and whose `min_weights_version` is that version. An actor
//! ([`run_actor`]) plays the rollout's actions on its robot ([`PlanarEnv`] here, any [`Env`]
//! in general) and streams the transitions and the episode's return back. The learner side,
//! [`FleetRunner`], is a [`RolloutRunner`]: it waits for every rollout and sums each rollout's
//! cost from its observations. Leases, reissue and exactly-once are the fleet library's
//! ([`coadapt_fleet`]); this file says only what a rollout is.

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step, Transition};
use coadapt_fleet::{ActorConfig, Check, DispatchConfig, Dispatcher, Done, Failure, Job, Stream, Verdict, Worker};
use coadapt_transport::messages::{Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, Weights};
use coadapt_transport::{ActorLinks, LearnerLinks};

use crate::planar::PlanarReaching;
use crate::{EpisodicTask, RolloutError, RolloutRunner};

/// The planar robot's joint-angle limit (action units: degrees by default); beyond it actions
/// are clipped, as every robot clips.
pub const MAX_ANGLE: f32 = 720.0;

/// The planar benchmark as a robot an actor steps: the action is the twelve joint angles
/// (degrees), the observation `[step / steps, distance of the left end effector to its goal,
/// distance of the right one]` after the step, the reward Eq. 2.31's term of the step. No
/// design (its body is fixed). The same kinematics as [`PlanarReaching`], so a rollout's return
/// through a fleet equals its in-process return (up to the f32 rewards).
#[derive(Debug)]
pub struct PlanarEnv {
    task: PlanarReaching,
    spec: EnvSpec,
    t: Option<usize>,
    obs: [f32; 3],
}

impl Default for PlanarEnv {
    fn default() -> Self {
        Self::new(PlanarReaching::default())
    }
}

impl PlanarEnv {
    /// The robot of `task` (its geometry and units).
    pub fn new(task: PlanarReaching) -> Self {
        let steps = task.steps();
        // Two turns each way: wide enough that the searches never reach it (their angles stay
        // within tens of units), narrow enough that a robot server mapping [-1, 1] onto it
        // (dm_env_rpc's coadapt profile) keeps f32 precision (4e-5 units).
        let action = BoxSpace::new(vec![-MAX_ANGLE; 12], vec![MAX_ANGLE; 12]).unwrap_or_else(|_| unreachable!("a valid box"));
        let design = BoxSpace::new(vec![], vec![]).unwrap_or_else(|_| unreachable!("a valid box"));
        let spec = EnvSpec {
            name: "planar".into(),
            state_dim: 3,
            action,
            design,
            design_names: vec![],
            default_design: vec![],
            max_episode_steps: steps,
        };
        Self { task, spec, t: None, obs: [0.0; 3] }
    }

    /// Each step's cost from its observation: the summed end-effector distance.
    pub fn step_cost(obs: &[f32]) -> f64 {
        obs.get(1..3).map_or(f64::NAN, |d| f64::from(d[0]) + f64::from(d[1]))
    }
}

impl Env for PlanarEnv {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, _seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        // Before the first step: both arms straight up, measured against the first goals.
        let d = self.task.distances(&[0.0; 12]);
        self.obs = [0.0, d[0].0 as f32, d[0].1 as f32];
        self.t = Some(0);
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        let t = self.t.ok_or(EnvError::NotRunning)?;
        if action.len() != 12 {
            return Err(EnvError::Action(coadapt_core::SpaceError::Dim { what: "action", expected: 12, got: action.len() }));
        }
        if let Some(index) = action.iter().position(|a| !a.is_finite()) {
            return Err(EnvError::Action(coadapt_core::SpaceError::NonFinite { what: "action", index, value: action[index] }));
        }
        let mut a = [0.0f32; 12];
        a.iter_mut().zip(action).for_each(|(c, v)| *c = v.clamp(-MAX_ANGLE, MAX_ANGLE));
        let action = &a;
        let steps = self.task.steps();
        let (gl, gr) = self.task.goals(t);
        let (l, r) = (self.task.end_effector(&action[..6]), self.task.end_effector(&action[6..12]));
        let dl = ((l[0] - gl[0]).powi(2) + (l[1] - gl[1]).powi(2)).sqrt();
        let dr = ((r[0] - gr[0]).powi(2) + (r[1] - gr[1]).powi(2)).sqrt();
        self.obs = [(t + 1) as f32 / steps as f32, dl as f32, dr as f32];
        let done = t + 1 >= steps;
        self.t = if done { None } else { Some(t + 1) };
        Ok(Step { observation: &self.obs, reward: ((-dl).exp() + (-dr).exp()) as f32, terminated: false, truncated: done })
    }
}

/// Rollouts on one actor: the iteration's actions, played on its robot.
struct Rollouts<'e> {
    env: &'e mut dyn Env,
    steps: usize,
    actor_id: u64,
    weights: Option<Arc<Weights>>,
    prev: Vec<f32>,
}

impl Worker for Rollouts<'_> {
    type Error = String;

    fn set_weights(&mut self, weights: &Arc<Weights>) -> Result<(), String> {
        self.weights = Some(weights.clone());
        Ok(())
    }

    fn run(&mut self, a: &Assignment, stream: &mut Stream<'_>) -> Result<Option<EpisodeEnd>, Failure<String>> {
        let (id, steps, d) = (self.actor_id, self.steps, self.env.spec().act_dim());
        let Some(w) = self.weights.as_ref() else { return Err(Failure::Fatal("no weights".into())) };
        let r = usize::try_from(a.seed).unwrap_or(usize::MAX);
        let Some(actions) = r.checked_mul(steps * d).and_then(|at| w.policy.get(at..at + steps * d)) else {
            coadapt_log::logln!(
                "actor {id}: assignment {} names rollout {r}, beyond the {} the iteration holds; skipped",
                a.id,
                w.policy.len() / (steps * d).max(1)
            );
            return Ok(None);
        };
        let obs = self.env.reset(a.seed, &a.design).map_err(|e| Failure::Env(format!("actor {id}: reset: {e}")))?;
        self.prev.clear();
        self.prev.extend_from_slice(obs);
        let (mut ret, mut length) = (0.0f32, 0u64);
        for t in 0..steps {
            let act = &actions[t * d..(t + 1) * d];
            let step = self.env.step(act).map_err(|e| Failure::Env(format!("actor {id}: step {t}: {e}")))?;
            ret += step.reward;
            length += 1;
            let last = step.terminated || step.truncated;
            let sent = stream.push(&Transition {
                obs: &self.prev,
                action: act,
                reward: step.reward,
                next_obs: step.observation,
                terminated: step.terminated,
            });
            self.prev.clear();
            self.prev.extend_from_slice(step.observation);
            if last || sent.is_break() {
                break;
            }
        }
        Ok(Some(EpisodeEnd { episode_return: ret, length }))
    }
}

/// Runs the rollouts the learner hands out on `env` until the assignment queue closes or
/// `shutdown` is set; returns how many it ran. Each rollout is `steps` steps (the task's: a
/// remote robot may not say its episode length). A rollout whose weights are not the
/// iteration's any more (the learner moved on) is skipped.
pub fn run_actor(
    env: &mut dyn Env,
    steps: usize,
    actor_id: u64,
    links: &mut ActorLinks,
    shutdown: &AtomicBool,
) -> Result<u64, RolloutError> {
    let mut worker = Rollouts { env, steps, actor_id, weights: None, prev: Vec::new() };
    let cfg = ActorConfig { exact_weights: true, record_eval: true, ..ActorConfig::default() };
    let summary = coadapt_fleet::actor::run(&mut worker, actor_id, links, &cfg, shutdown)
        .map_err(|e| RolloutError(format!("actor {actor_id}: {e}")))?;
    Ok(summary.episodes)
}

/// A rollout of the iteration, as the dispatcher names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Rollout(usize);

impl std::fmt::Display for Rollout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "rollout {}", self.0)
    }
}

/// What a rollout must look like: `steps` transitions of the task's widths.
struct RolloutCheck {
    steps: usize,
    action_dim: usize,
    obs_dim: usize,
}

impl Check<Rollout> for RolloutCheck {
    fn chunk(&mut self, c: &ExperienceChunk) -> Result<(), String> {
        let k = c.len();
        if c.next_obs.len() != k * self.obs_dim || c.actions.len() != k * self.action_dim {
            return Err(format!("{k} rewards, {} observation values, {} actions", c.next_obs.len(), c.actions.len()));
        }
        Ok(())
    }

    fn episode(&mut self, d: &Done<Rollout>) -> Verdict {
        if d.steps != self.steps || d.end.length != self.steps as u64 {
            return Verdict::Again(format!("ended after {} steps, expected {}", d.steps, self.steps));
        }
        Verdict::Accept
    }
}

/// The learner's side of rollouts through a fleet (see the module doc).
pub struct FleetRunner {
    links: Mutex<(LearnerLinks, Dispatcher<Rollout>, u64)>,
    steps: usize,
    action_dim: usize,
    obs_dim: usize,
    step_cost: fn(&[f32]) -> f64,
}

impl std::fmt::Debug for FleetRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FleetRunner").field("steps", &self.steps).field("action_dim", &self.action_dim).finish_non_exhaustive()
    }
}

impl FleetRunner {
    /// Rollouts of `steps x action_dim` actions on robots with observations of `obs_dim`;
    /// `step_cost` reads a step's cost from its observation. A rollout that sent nothing for a
    /// minute goes out again; an iteration not back within an hour fails (see the setters).
    pub fn new(links: LearnerLinks, steps: usize, action_dim: usize, obs_dim: usize, step_cost: fn(&[f32]) -> f64) -> Self {
        let cfg = DispatchConfig {
            lease: Duration::from_secs(60),
            deadline: Some(Duration::from_secs(3600)),
            max_steps: steps,
            ..DispatchConfig::default()
        };
        Self { links: Mutex::new((links, Dispatcher::new("search", cfg), 0)), steps, action_dim, obs_dim, step_cost }
    }

    fn dispatcher(&mut self) -> &mut Dispatcher<Rollout> {
        &mut self.links.get_mut().unwrap_or_else(|e| e.into_inner()).1
    }

    /// A rollout that sent nothing for `lease` goes out again (to whichever actor is free).
    pub fn set_lease(&mut self, lease: Duration) {
        self.dispatcher().cfg.lease = lease;
    }

    /// A rollout not back `deadline` after it went out fails the iteration.
    pub fn set_deadline(&mut self, deadline: Duration) {
        self.dispatcher().cfg.deadline = Some(deadline);
    }

    /// Asked while waiting: `Some(why)` gives up on the iteration (every actor process gone).
    pub fn set_abort(&mut self, abort: Box<dyn Fn() -> Option<String> + Send + Sync>) {
        self.dispatcher().abort = Some(abort);
    }
}

impl RolloutRunner for FleetRunner {
    fn run(&self, rollouts: &[Vec<f32>]) -> Result<Vec<(f64, f64)>, RolloutError> {
        let n = rollouts.len();
        let per = self.steps * self.action_dim;
        if let Some(i) = rollouts.iter().position(|a| a.len() != per) {
            return Err(RolloutError(format!("rollout {i} has {} actions, expected {per}", rollouts[i].len())));
        }
        let mut guard = self.links.lock().unwrap_or_else(|e| e.into_inner());
        let (links, dispatcher, version) = &mut *guard;
        let err = |e: coadapt_fleet::DispatchError| RolloutError(e.to_string());
        // What a failed iteration left out is not waited for.
        dispatcher.forget_all();
        *version += 1;
        let version = *version;
        links
            .acting_weights
            .publish(Weights { version, policy: rollouts.concat(), q1: vec![], q2: vec![] })
            .map_err(|e| RolloutError(e.to_string()))?;
        for r in 0..n {
            let job = Job {
                design_index: u32::try_from(version).unwrap_or(u32::MAX),
                design: vec![],
                mode: EpisodeMode::Train,
                seed: r as u64,
                min_weights_version: version,
            };
            dispatcher.issue(links, job, Rollout(r)).map_err(err)?;
        }
        let mut check = RolloutCheck { steps: self.steps, action_dim: self.action_dim, obs_dim: self.obs_dim };
        let mut results: Vec<Option<(f64, f64)>> = vec![None; n];
        let mut reissued = 0u32;
        let never = AtomicBool::new(false);
        while results.iter().any(Option::is_none) {
            let Some(done) = dispatcher.next_done(links, &never, &mut check).map_err(err)? else { break };
            reissued += done.reissued;
            let (mut ret, mut cost) = (0.0f64, 0.0f64);
            for c in &done.chunks {
                ret += c.rewards.iter().map(|&r| f64::from(r)).sum::<f64>();
                cost += c.next_obs.chunks_exact(self.obs_dim.max(1)).map(self.step_cost).sum::<f64>();
            }
            if let Some(slot) = results.get_mut(done.tag.0) {
                *slot = Some((ret, cost));
            }
        }
        if reissued > 0 {
            coadapt_log::logln!("search: {reissued} rollout(s) of this iteration went out again");
        }
        Ok(results.into_iter().map(|r| r.unwrap_or((0.0, f64::NAN))).collect())
    }
}
