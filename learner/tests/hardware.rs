//! Real robots: a sensor glitch (one absurd observation or reward) is rejected and the episode
//! run again instead of ending the run or poisoning the replay; a robot that pauses longer than
//! the lease and the silence limit (a person resetting it) is waited for, its episode never
//! re-run elsewhere. Through the whole learner role over the in-process transport, with a
//! Pendulum wrapped to misbehave.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use coadapt_actors::{Actor, PolicyKind};
use coadapt_core::{Env, EnvError, EnvSpec, Step};
use coadapt_learner::coadapt::{self, RunOutcome, ScheduleConfig};
use coadapt_learner::fear::FearLearnerConfig;
use coadapt_learner::flow::FlowConfig;
use coadapt_learner::run_dir::RunWriter;
use coadapt_learner::{SacConfig, networks};
use coadapt_transport::{DesignReply, in_process, next_or_stop};

const HIDDEN: [usize; 1] = [16];

/// Pendulum that misbehaves once, at step `at` of the run: `glitch` (an absurd observation and
/// reward) or a pause of `pause`.
struct Flaky {
    inner: Box<dyn Env>,
    steps: &'static AtomicUsize,
    at: usize,
    pause: Option<Duration>,
    obs: Vec<f32>,
}

impl Env for Flaky {
    fn spec(&self) -> &EnvSpec {
        self.inner.spec()
    }
    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.inner.reset(seed, design)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        let n = self.steps.fetch_add(1, Ordering::SeqCst);
        let s = self.inner.step(action)?;
        if n != self.at {
            return Ok(s);
        }
        if let Some(p) = self.pause {
            std::thread::sleep(p);
            return Ok(s);
        }
        self.obs = s.observation.to_vec();
        self.obs[0] = 1e30;
        Ok(Step { observation: &self.obs, reward: -1e30, terminated: s.terminated, truncated: s.truncated })
    }
}

fn run(name: &str, schedule: ScheduleConfig, flow: FlowConfig, env: Flaky) -> (RunOutcome, String) {
    let spec = coadapt_robots::make("pendulum").unwrap().spec().clone();
    let dir = std::env::temp_dir().join(format!("coadapt-hardware-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let learner_cfg = FearLearnerConfig {
        sac: SacConfig { hidden: HIDDEN.to_vec(), batch_size: 16, ..SacConfig::default() },
        population_batch: 4,
        species_batch: 12,
        individual_updates: 2,
        population_updates: 2,
        population_updates_from_design: 0,
        warmup_episodes: 0,
        ..FearLearnerConfig::default()
    };
    let (mut learner, mut actors, mut optimizer) = in_process::fleet(1);
    let shutdown = AtomicBool::new(false);
    let centre: Vec<f32> = spec.design.low.iter().zip(&spec.design.high).map(|(l, h)| 0.5 * (l + h)).collect();
    let outcome = std::thread::scope(|s| {
        let (spec, shutdown, centre) = (&spec, &shutdown, &centre);
        let mut links = actors.pop().unwrap();
        s.spawn(move || {
            let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), &HIDDEN).unwrap();
            let mut actor = Actor::new(env, policy, PolicyKind::SquashedGaussian, 3).unwrap();
            coadapt_actors::role::run(&mut actor, 0, &mut links, 50, 0, shutdown).unwrap();
        });
        s.spawn(move || {
            while let Some(req) = next_or_stop(optimizer.requests.as_mut(), shutdown).unwrap() {
                let reply = DesignReply {
                    index: req.index,
                    design: centre.clone(),
                    method: "centre".into(),
                    predicted_objective: None,
                    design_rollouts: 0,
                };
                optimizer.replies.send(reply).unwrap();
            }
        });
        let mut out = RunWriter::create(&dir).unwrap();
        let o = coadapt::run(
            &schedule,
            &learner_cfg,
            spec,
            11,
            &flow,
            1,
            &mut learner,
            &mut out,
            shutdown,
            &mut |_| {},
            &mut coadapt::Snapshots::off(),
        );
        drop(learner);
        o
    });
    (outcome.unwrap(), std::fs::read_to_string(dir.join("episodes.csv")).unwrap())
}

fn schedule() -> ScheduleConfig {
    ScheduleConfig {
        designs: 2,
        initial_designs: vec![vec![1.0, 1.0]],
        initial_episodes: 2,
        episodes_per_design: 1,
        start_state_batch: 4,
        ..ScheduleConfig::default()
    }
}

#[test]
fn a_sensor_glitch_is_rejected_and_the_episode_run_again() {
    static STEPS: AtomicUsize = AtomicUsize::new(0);
    let inner = coadapt_robots::make("pendulum").unwrap();
    // Step 250 of the run: the second training episode (Pendulum episodes are 200 steps, each
    // training episode followed by its evaluation).
    let env = Flaky { inner, steps: &STEPS, at: 450, pause: None, obs: vec![] };
    let s = ScheduleConfig { max_abs_observation: 1e6, max_abs_reward: 1e6, ..schedule() };
    let (o, episodes) = run("glitch", s, FlowConfig::default(), env);
    assert!(!o.interrupted);
    assert_eq!(o.time.episodes_rejected, 1, "{:?}", o.time);
    assert_eq!(o.learner.population_transitions(), 3 * 200, "only whole, sound episodes in the replay");
    assert_eq!(episodes.lines().count(), 1 + 3, "{episodes}");
    assert!(!episodes.contains("e30") && !episodes.contains("e29"), "{episodes}");
}

#[test]
fn a_robot_that_pauses_beyond_the_lease_is_waited_for_not_re_run() {
    static STEPS: AtomicUsize = AtomicUsize::new(0);
    let inner = coadapt_robots::make("pendulum").unwrap();
    let env = Flaky { inner, steps: &STEPS, at: 250, pause: Some(Duration::from_millis(1500)), obs: vec![] };
    // Lease and silence limit both shorter than the pause: configured for hardware, neither
    // applies.
    let s = ScheduleConfig { episode_timeout_secs: 0.0, ..schedule() };
    let flow = FlowConfig { assignment_lease_secs: 0.3, reissue_silent_episodes: false, ..FlowConfig::default() };
    let (o, episodes) = run("pause", s, flow, env);
    assert!(!o.interrupted);
    assert_eq!(o.time.reissued, 0, "{:?}", o.time);
    assert_eq!(episodes.lines().count(), 1 + 3, "{episodes}");
    // The same pause with the simulation defaults re-runs the episode.
    static STEPS2: AtomicUsize = AtomicUsize::new(0);
    let env = Flaky {
        inner: coadapt_robots::make("pendulum").unwrap(),
        steps: &STEPS2,
        at: 250,
        pause: Some(Duration::from_millis(1500)),
        obs: vec![],
    };
    let flow = FlowConfig { assignment_lease_secs: 0.3, ..FlowConfig::default() };
    let (o, _) = run("pause-sim", schedule(), flow, env);
    assert!(o.time.reissued >= 1, "{:?}", o.time);
}
