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
//! [`FleetRunner`], is a [`RolloutRunner`]: it waits for every rollout, hands a rollout that
//! went silent to another actor after a lease, and sums each rollout's cost from its
//! observations.

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step};
use coadapt_transport::messages::{Assignment, EpisodeEnd, EpisodeMode, ExperienceChunk, Weights};
use coadapt_transport::{ActorLinks, LearnerLinks, TransportError, newest_or_stop, next_or_stop};

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
    let err = |e: TransportError| RolloutError(format!("actor {actor_id}: {e}"));
    let (d, s) = (env.spec().act_dim(), env.spec().obs_dim());
    let mut done = 0u64;
    while let Some(a) = next_or_stop(links.assignments.as_mut(), shutdown).map_err(err)? {
        let Some(w) = newest_or_stop(links.weights.as_mut(), a.min_weights_version, shutdown).map_err(err)? else { break };
        if w.version != a.min_weights_version {
            continue;
        }
        let r = usize::try_from(a.seed).unwrap_or(usize::MAX);
        let Some(actions) = r.checked_mul(steps * d).and_then(|at| w.policy.get(at..at + steps * d)) else {
            coadapt_log::logln!(
                "actor {actor_id}: assignment {} names rollout {r}, beyond the {} the iteration holds; skipped",
                a.id,
                w.policy.len() / (steps * d).max(1)
            );
            continue;
        };
        let mut chunk = ExperienceChunk {
            actor: actor_id,
            assignment: a.id,
            design_index: a.design_index,
            weights_version: w.version,
            first: true,
            ..ExperienceChunk::default()
        };
        let mut ret = 0.0f32;
        let obs = env.reset(a.seed, &a.design).map_err(|e| RolloutError(format!("actor {actor_id}: reset: {e}")))?;
        let mut prev = obs.to_vec();
        for t in 0..steps {
            let act = &actions[t * d..(t + 1) * d];
            let step = env.step(act).map_err(|e| RolloutError(format!("actor {actor_id}: step {t}: {e}")))?;
            ret += step.reward;
            chunk.obs.extend_from_slice(&prev);
            chunk.actions.extend_from_slice(act);
            chunk.rewards.push(step.reward);
            chunk.next_obs.extend_from_slice(step.observation);
            chunk.terminated.push(step.terminated);
            prev.clear();
            prev.extend_from_slice(step.observation);
            debug_assert_eq!(prev.len(), s);
            if step.terminated || step.truncated {
                break;
            }
        }
        chunk.end = Some(EpisodeEnd { episode_return: ret, length: chunk.rewards.len() as u64 });
        match links.experience.send(chunk) {
            Ok(()) => done += 1,
            Err(TransportError::Closed) => break,
            Err(e) => return Err(err(e)),
        }
    }
    Ok(done)
}

/// The learner's side of rollouts through a fleet (see the module doc).
pub struct FleetRunner {
    links: Mutex<LearnerLinks>,
    counters: Mutex<(u64, u64)>,
    steps: usize,
    action_dim: usize,
    obs_dim: usize,
    /// A rollout that sent nothing for this long goes out again (to whichever actor is free).
    pub lease: Duration,
    /// An iteration whose rollouts have not all come back by then fails.
    pub deadline: Duration,
    step_cost: fn(&[f32]) -> f64,
    /// Asked while waiting: `Some(why)` gives up on the iteration (every actor process gone).
    pub abort: Option<Box<dyn Fn() -> Option<String> + Send + Sync>>,
}

impl std::fmt::Debug for FleetRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FleetRunner").field("steps", &self.steps).field("action_dim", &self.action_dim).finish_non_exhaustive()
    }
}

impl FleetRunner {
    /// Rollouts of `steps x action_dim` actions on robots with observations of `obs_dim`;
    /// `step_cost` reads a step's cost from its observation.
    pub fn new(links: LearnerLinks, steps: usize, action_dim: usize, obs_dim: usize, step_cost: fn(&[f32]) -> f64) -> Self {
        Self {
            links: Mutex::new(links),
            counters: Mutex::new((0, 0)),
            steps,
            action_dim,
            obs_dim,
            lease: Duration::from_secs(60),
            deadline: Duration::from_secs(3600),
            step_cost,
            abort: None,
        }
    }

    /// The next weights version and `n` fresh assignment ids.
    fn next(&self, n: u64) -> (u64, u64) {
        let mut c = self.counters.lock().unwrap_or_else(|e| e.into_inner());
        c.0 += 1;
        let first = c.1;
        c.1 += n;
        (c.0, first)
    }

    /// A fresh assignment id.
    fn next_id(&self) -> u64 {
        let mut c = self.counters.lock().unwrap_or_else(|e| e.into_inner());
        c.1 += 1;
        c.1 - 1
    }

    fn assignment(&self, id: u64, version: u64, rollout: usize) -> Assignment {
        Assignment {
            id,
            design_index: u32::try_from(version).unwrap_or(u32::MAX),
            design: vec![],
            mode: EpisodeMode::Train,
            seed: rollout as u64,
            min_weights_version: version,
        }
    }
}

/// What the learner knows of one rollout while it is out.
struct Out {
    rollout: usize,
    heard: Instant,
    ret: f64,
    cost: f64,
    steps: usize,
}

impl RolloutRunner for FleetRunner {
    fn run(&self, rollouts: &[Vec<f32>]) -> Result<Vec<(f64, f64)>, RolloutError> {
        let n = rollouts.len();
        let per = self.steps * self.action_dim;
        if let Some(i) = rollouts.iter().position(|a| a.len() != per) {
            return Err(RolloutError(format!("rollout {i} has {} actions, expected {per}", rollouts[i].len())));
        }
        let (version, first_id) = self.next(n as u64);
        let mut links = self.links.lock().unwrap_or_else(|e| e.into_inner());
        let io = |e: TransportError| RolloutError(e.to_string());
        links.acting_weights.publish(Weights { version, policy: rollouts.concat(), q1: vec![], q2: vec![] }).map_err(io)?;
        let mut out: HashMap<u64, Out> = HashMap::new();
        for r in 0..n {
            let id = first_id + r as u64;
            links.assignments.send(self.assignment(id, version, r)).map_err(io)?;
            out.insert(id, Out { rollout: r, heard: Instant::now(), ret: 0.0, cost: 0.0, steps: 0 });
        }
        let mut results: Vec<Option<(f64, f64)>> = vec![None; n];
        let started = Instant::now();
        let mut reissued = 0u64;
        while results.iter().any(Option::is_none) {
            if let Some(why) = self.abort.as_ref().and_then(|f| f()) {
                return Err(RolloutError(why));
            }
            if started.elapsed() > self.deadline {
                let left = results.iter().filter(|r| r.is_none()).count();
                return Err(RolloutError(format!("{left} of {n} rollouts not back after {:?}: are the actors running?", self.deadline)));
            }
            // A silent rollout goes out again under a new id (one copy out per rollout: the
            // silent one's late chunks are ignored).
            let silent: Vec<u64> =
                out.iter().filter(|(_, o)| o.heard.elapsed() > self.lease && results[o.rollout].is_none()).map(|(id, _)| *id).collect();
            for id in silent {
                if let Some(o) = out.remove(&id) {
                    let new_id = self.next_id();
                    links.assignments.send(self.assignment(new_id, version, o.rollout)).map_err(io)?;
                    out.insert(new_id, Out { rollout: o.rollout, heard: Instant::now(), ret: 0.0, cost: 0.0, steps: 0 });
                    reissued += 1;
                }
            }
            let Some(chunk) = links.experience.recv_timeout(Duration::from_millis(100)).map_err(io)? else { continue };
            let Some(o) = out.get_mut(&chunk.assignment) else { continue };
            if results[o.rollout].is_some() {
                continue;
            }
            let k = chunk.rewards.len();
            if chunk.next_obs.len() != k * self.obs_dim || chunk.actions.len() != k * self.action_dim {
                coadapt_log::logln!("search: a malformed chunk of rollout {} from actor {}; it goes out again", o.rollout, chunk.actor);
                o.heard = Instant::now() - self.lease - Duration::from_secs(1);
                continue;
            }
            o.heard = Instant::now();
            o.steps += k;
            o.ret += chunk.rewards.iter().map(|&r| f64::from(r)).sum::<f64>();
            o.cost += chunk.next_obs.chunks_exact(self.obs_dim.max(1)).map(self.step_cost).sum::<f64>();
            if let Some(end) = chunk.end {
                if o.steps != self.steps || end.length != self.steps as u64 {
                    coadapt_log::logln!(
                        "search: rollout {} ended after {} steps, expected {}; it goes out again",
                        o.rollout,
                        o.steps,
                        self.steps
                    );
                    (o.ret, o.cost, o.steps) = (0.0, 0.0, 0);
                    o.heard = Instant::now() - self.lease - Duration::from_secs(1);
                    continue;
                }
                results[o.rollout] = Some((o.ret, o.cost));
            }
        }
        if reissued > 0 {
            coadapt_log::logln!("search: {reissued} rollout(s) of this iteration went out again after {:?} of silence", self.lease);
        }
        Ok(results.into_iter().map(|r| r.unwrap_or((0.0, f64::NAN))).collect())
    }
}
