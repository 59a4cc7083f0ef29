//! The learner role of a co-adaptation (thesis Algorithm 4): it owns the FEAR schedule. For
//! each design it asks the design optimiser for a body (or takes a fixed initial one), hands
//! the actors one episode at a time, learns from the experience they stream back, evaluates
//! the deterministic policy, and records everything in the run directory.
//!
//! How episodes are spread over the actors is [`crate::flow`]'s business: lock-step (the
//! reference: collect one episode, then train on it, so a seed reproduces a run whatever the
//! number of actors) or a window of episodes in flight; either way each training episode buys
//! the same updates.
//! Designs: `initial-designs` fixed ones with `initial-episodes` each, then
//! `episodes-per-design` for each later one, alternating exploitation and exploration
//! (`alternate = false`: every later design is an exploitation).
//!
//! For real hardware (`confirm-designs`, `reset-needs-confirmation`) the run stops before each
//! design until an operator has built its prototype, and before each episode until the robot
//! has been reset by hand; [`crate::prototype`] has the files they answer through.
//!
//! # Layout
//! - this file: the schedule's config and [`run`], the loop over designs and their episodes;
//! - `error`: [`CoadaptError`], why a run stopped, and its exit code;
//! - `events`: what the learner reports as it goes ([`RunEvent`], [`Stats`]) and what a run
//!   leaves ([`RunOutcome`]);
//! - `driver`: the learner's side of the fleet (weights out, episodes out, experience in,
//!   design requests);
//! - `operator`: choosing a design with the operator's verdict on its prototype, and the
//!   waits for the operator;
//! - `resume`: snapshots of the schedule's position and resuming from one.

mod driver;
mod error;
mod events;
mod operator;
mod resume;

pub use error::CoadaptError;
pub use events::{RunEvent, RunOutcome, Stats};
pub use resume::{Snapshots, Transfer};

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::EnvSpec;
use coadapt_fleet::{DispatchConfig, Dispatcher};
use coadapt_transport::messages::Dims;
use coadapt_transport::{DesignKind, EpisodeMode, LearnerLinks};
use serde::{Deserialize, Serialize};

use crate::ConfigError;
use crate::fear::{FearLearner, FearLearnerConfig};
use crate::flow::{Completed, FlowConfig, LearnerTime};
use crate::prototype::ResetMode;
use crate::run_dir::{EpisodeRow, RunWriter, WrittenSoFar};
use crate::snapshot::{SnapshotError, StateIn};
use driver::Learner;

/// The co-adaptation schedule; defaults are the reference's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct ScheduleConfig {
    /// Designs in the whole run, the initial ones included.
    pub designs: usize,
    /// The fixed designs the run starts with (empty: the robot's reference set; see
    /// `coadapt run --help`).
    pub initial_designs: Vec<Vec<f32>>,
    /// Episodes on each initial design.
    pub initial_episodes: usize,
    /// Episodes on each later design.
    pub episodes_per_design: usize,
    /// Alternate exploitation and exploration after the initial designs (false: exploit only).
    pub alternate: bool,
    /// Start states per design-objective evaluation (n of Eq. 5.6).
    pub start_state_batch: usize,
    /// Evaluate the deterministic policy after every this many episodes of a design (and
    /// always after its last); 0: only after the last.
    pub eval_every: usize,
    /// Fail when no actor has sent anything for this long (seconds): the fleet is gone. Waits
    /// for an operator do not count. 0: never (real robots that pause for minutes or hours).
    pub episode_timeout_secs: f64,
    /// Reject an episode (it is run again, and counted) with an observation entry beyond this
    /// magnitude: a sensor glitch must not poison the replay. 0: no limit.
    pub max_abs_observation: f32,
    /// The same for rewards. 0: no limit.
    pub max_abs_reward: f32,
    /// Real hardware: wait for an operator to build each design's prototype (the initial ones
    /// too) and answer `coadapt confirm RUN_DIR` (built as asked), `--as-built V1,V2,...` (the
    /// measured dimensions replace the requested ones) or `--reject` (the optimiser proposes
    /// its next-best design).
    pub confirm_designs: bool,
    /// Population updates per second of waiting for an operator, on the population buffer
    /// (0: none).
    pub train_while_waiting: usize,
    /// Real hardware that a person resets: wait before every episode (training and evaluation)
    /// until an operator answers `coadapt confirm RUN_DIR --reset`.
    pub reset_needs_confirmation: bool,
    /// How often a waiting run looks for the operator's answer (seconds).
    pub confirm_poll_secs: f64,
    /// Send a design request again when no reply has come for this long (seconds), then after
    /// twice as long each time, up to 16 times this: an optimiser that died with the request is
    /// restarted and answers the copy (one that is only slow answers the copy from its stored
    /// replies, without a second search).
    pub design_request_resend_secs: f64,
    /// Fail the run when a design request has had no reply for this long (seconds).
    pub design_request_timeout_secs: f64,
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        Self {
            designs: 50,
            initial_designs: Vec::new(),
            initial_episodes: 300,
            episodes_per_design: 100,
            alternate: true,
            start_state_batch: 32,
            eval_every: 1,
            episode_timeout_secs: 600.0,
            max_abs_observation: 0.0,
            max_abs_reward: 0.0,
            confirm_designs: false,
            train_while_waiting: 0,
            reset_needs_confirmation: false,
            confirm_poll_secs: 0.5,
            design_request_resend_secs: 60.0,
            design_request_timeout_secs: 7200.0,
        }
    }
}

impl ScheduleConfig {
    /// Episodes of design `i`.
    pub fn episodes_of(&self, i: usize) -> usize {
        if i < self.initial_designs.len() { self.initial_episodes } else { self.episodes_per_design }
    }

    pub fn total_episodes(&self) -> usize {
        (0..self.designs).map(|i| self.episodes_of(i)).sum()
    }

    /// `confirm-poll-secs` as a duration, refusing what is not a positive number of seconds.
    pub fn poll_interval(&self) -> Result<Duration, ConfigError> {
        let t = self.confirm_poll_secs;
        match Duration::try_from_secs_f64(t) {
            Ok(d) if t > 0.0 => Ok(d),
            _ => Err(ConfigError::NotPositiveSeconds { key: "schedule.confirm-poll-secs", value: t }),
        }
    }

    /// The kind of design `i` (`None`: a fixed initial design).
    pub fn kind_of(&self, i: usize) -> Option<DesignKind> {
        let n = self.initial_designs.len();
        if i < n {
            None
        } else if self.alternate && (i - n) % 2 == 1 {
            Some(DesignKind::Explore)
        } else {
            Some(DesignKind::Exploit)
        }
    }
}

/// Where the CSV files stood at the snapshot `inp`, to open the run directory with
/// [`RunWriter::resume`] before [`run`] continues from it.
pub fn resume_point(inp: &StateIn) -> Result<WrittenSoFar, SnapshotError> {
    let p: resume::Progress = inp.get("progress")?;
    Ok(p.written)
}

/// The population networks' version at the snapshot `inp` (what the design service reports).
pub fn population_version(inp: &StateIn) -> Result<u64, SnapshotError> {
    let p: resume::Progress = inp.get("progress")?;
    Ok(p.population_version)
}

/// Runs the whole co-adaptation, or continues it from `snapshots.resume`. `initial` replaces
/// an empty `initial-designs`.
pub fn run(
    cfg: &ScheduleConfig,
    fear_cfg: &FearLearnerConfig,
    spec: &EnvSpec,
    seed: u64,
    flow: &FlowConfig,
    actors: usize,
    links: &mut LearnerLinks,
    out: &mut RunWriter,
    shutdown: &AtomicBool,
    on_event: &mut dyn FnMut(&RunEvent<'_>),
    snaps: &mut Snapshots,
) -> Result<RunOutcome, CoadaptError> {
    let dims = Dims { obs: spec.obs_dim(), act: spec.act_dim(), design: spec.design_dim() };
    if cfg.initial_designs.is_empty() {
        return Err(CoadaptError::Config("schedule.initial-designs: at least one initial design is needed".into()));
    }
    let t = cfg.episode_timeout_secs;
    if !(t.is_finite() && t >= 0.0 && Duration::try_from_secs_f64(t).is_ok()) {
        return Err(CoadaptError::Config(format!("schedule.episode-timeout-secs: {t} is not a number of seconds >= 0")));
    }
    for (name, v) in [("max-abs-observation", cfg.max_abs_observation), ("max-abs-reward", cfg.max_abs_reward)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(CoadaptError::Config(format!("schedule.{name}: {v} is not a finite number >= 0")));
        }
    }
    for (i, d) in cfg.initial_designs.iter().enumerate() {
        spec.design.check("design", d).map_err(|e| CoadaptError::Config(format!("schedule.initial-designs[{i}]: {e}")))?;
    }
    cfg.poll_interval()?;
    for (name, v) in
        [("design-request-resend-secs", cfg.design_request_resend_secs), ("design-request-timeout-secs", cfg.design_request_timeout_secs)]
    {
        if !(v.is_finite() && v > 0.0 && v < 1e9) {
            return Err(CoadaptError::Config(format!("schedule.{name}: {v} is not a positive number of seconds")));
        }
    }
    snaps.cfg.validate()?;
    fear_cfg.check()?;
    let mut fear = FearLearner::new(dims.obs, dims.act, fear_cfg.clone(), seed).map_err(|e| CoadaptError::Config(e.to_string()))?;
    fear.set_design_box(&spec.design.low, &spec.design.high);
    let lease = flow.lease()?;
    let in_flight = flow.in_flight(actors);
    let dir = out.dir().to_path_buf();
    let mut l = Learner {
        cfg,
        spec,
        dims,
        links,
        shutdown,
        fear,
        acting_version: 0,
        acting_dirty: true,
        longest_episode: 0.0,
        republish: false,
        acting_which: None,
        population_version: 0,
        seed,
        fleet: Dispatcher::new(
            "learner",
            DispatchConfig {
                lease,
                reissue: flow.reissue_silent_episodes,
                silence: (t > 0.0).then(|| Duration::from_secs_f64(t)),
                deadline: None,
                max_steps: spec.max_episode_steps,
            },
        ),
        rejected_in_a_row: 0,
        last_request_seconds: 0.0,
        time: LearnerTime::default(),
        dir: &dir,
        rejected: Vec::new(),
        last_training: None,
    };
    let mut p = match snaps.resume.take() {
        Some(mut inp) => {
            l.fear.load_state(&mut inp)?;
            let mut p: resume::Progress = inp.get("progress")?;
            l.restore(&p);
            l.rejected = p.rebuild(out.read_designs()?);
            p.resumes += 1;
            p
        }
        None => {
            if let Some(t) = snaps.transfer.take() {
                l.fear.init_population(&t.networks).map_err(|e| CoadaptError::Config(format!("init-population.from: {e}")))?;
                if let Some(mut replay) = t.replay {
                    l.fear.load_population_replay(&mut replay).map_err(|e| CoadaptError::Config(format!("init-population.replay: {e}")))?;
                }
            }
            resume::Progress::start()
        }
    };
    let start = Instant::now();
    let seconds_before = p.seconds;
    let mut stopped = false;
    for index in p.design..cfg.designs {
        p.design = index;
        let (mut row, done) = match p.in_design.take() {
            // Resumed in the middle of this design: chosen, begun and partly trained already.
            Some(d) => (d.row, d.episodes),
            None => {
                let Some(row) = l.choose_design(index, &p.chosen, out, on_event)? else { break };
                p.chosen.extend_from_slice(&row.design);
                l.fear.begin_design(index);
                l.acting_dirty = true;
                (row, 0)
            }
        };
        on_event(&RunEvent::DesignStart { index, row: &row });
        let n = cfg.episodes_of(index);
        let design = row.design.clone();
        let base = p.global - done as u64;
        let (mut issued, mut written) = (done, done);
        let mut since_snapshot = 0usize;
        // Training episodes back and trained on, waiting for their evaluation.
        let mut awaiting_eval: Vec<(Completed, u64)> = Vec::new();
        let mut interrupted = false;
        // The learner's counters at the last point where nothing was out (here: nothing is out
        // yet), for a stop that lands while an episode is out: see `snapshot_at_quiet`.
        let mut quiet = Some(l.quiet_point());
        // Stopping with an evaluation out (the training episode before it is learnt): until
        // when the learner waits for what is out to come back, to snapshot with nothing out.
        let mut draining: Option<Instant> = None;
        'episodes: while written < n {
            while draining.is_none() && l.fleet.outstanding() < in_flight && issued < n {
                if !l.reset_before(index, issued, n, ResetMode::Train, on_event)? {
                    interrupted = true;
                    p.seconds = seconds_before + start.elapsed().as_secs_f64();
                    snapshot_at_quiet(&mut l, quiet.take(), &mut p, &row, written, out, snaps)?;
                    break 'episodes;
                }
                l.issue(index, &design, issued, base + issued as u64, EpisodeMode::Train)?;
                issued += 1;
            }
            let Some(c) = l.next_completed(draining)? else {
                if draining.is_none() && quiet.is_none() {
                    // Three times the longest episode so far, at least 1 s, at most STOP_WAIT: an
                    // actor that stopped too (a fleet's roles all get the signal) before taking
                    // the evaluation never sends it, and the learner must not outwait that long.
                    let wait =
                        Duration::try_from_secs_f64(3.0 * l.longest_episode).unwrap_or(STOP_WAIT).clamp(Duration::from_secs(1), STOP_WAIT);
                    draining = Some(Instant::now() + wait);
                    coadapt_log::logln!(
                        "learner: stopping: waiting up to {:.1} s for the episodes out to come back, to snapshot (Ctrl-C again aborts)",
                        wait.as_secs_f64()
                    );
                    continue;
                }
                if draining.is_some() {
                    coadapt_log::logln!("learner: stopping: the episodes out did not come back in time; the last snapshot stands");
                }
                interrupted = true;
                p.seconds = seconds_before + start.elapsed().as_secs_f64();
                snapshot_at_quiet(&mut l, quiet.take(), &mut p, &row, written, out, snaps)?;
                break;
            };
            // The learner changes from here on (it trains, rows are written).
            quiet = None;
            let ((c, steps_then), eval_return) = match c.mode {
                EpisodeMode::Train => {
                    l.learn_from(&c)?;
                    p.steps = p.steps.saturating_add(c.end.length);
                    let e = c.episode;
                    if cfg.eval_every > 0 && (e + 1) % cfg.eval_every == 0 || e + 1 == n {
                        if !l.reset_before(index, e, n, ResetMode::Eval, on_event)? {
                            interrupted = true;
                            break 'episodes;
                        }
                        l.issue(index, &design, e, c.global, EpisodeMode::Eval)?;
                        awaiting_eval.push((c, p.steps));
                        continue;
                    }
                    ((c, p.steps), None)
                }
                EpisodeMode::Eval => {
                    let Some(i) = awaiting_eval.iter().position(|(t, _)| t.episode == c.episode) else {
                        return Err(CoadaptError::Protocol(format!("an evaluation of episode {} nobody asked for", c.episode)));
                    };
                    (awaiting_eval.swap_remove(i), Some(c.end.episode_return))
                }
            };
            row.episodes += 1;
            if let Some(r) = eval_return {
                row.last_eval_return = Some(r);
                row.best_eval_return = Some(row.best_eval_return.map_or(r, |b| b.max(r)));
            }
            let ep = EpisodeRow {
                design: index,
                episode: c.episode,
                global_episode: c.global as usize,
                steps: steps_then,
                train_return: c.end.episode_return,
                eval_return,
                weights_version: c.weights_version,
                actor: c.actor,
                policy_lag: c.policy_lag,
                seconds: seconds_before + start.elapsed().as_secs_f64(),
            };
            out.episode(&ep)?;
            out.events().scalars(ep.global_episode as i64, &l.episode_scalars())?;
            on_event(&RunEvent::Episode { row: &ep, episodes_in_design: n });
            on_event(&RunEvent::Stats(&l.stats(index, p.global + 1, p.steps, c.policy_lag, snaps, p.resumes)));
            written += 1;
            p.global += 1;
            since_snapshot += 1;
            // Nothing out with an actor: the state is whole. A snapshot every `every-episodes`
            // (later while the last one's write time would exceed `max-share` of the time since
            // it) and, on shutdown, one now (the design's end takes its own).
            let is_quiet = l.fleet.outstanding() == 0 && awaiting_eval.is_empty();
            let stopping = draining.is_some() || shutdown.load(Ordering::Relaxed);
            let due = snaps.cfg.periodic_due(since_snapshot, snaps.last_at.map(|t| t.elapsed()), snaps.last_write_seconds);
            if is_quiet {
                quiet = Some(l.quiet_point());
            }
            if is_quiet && written < n && (stopping || due) {
                p.in_design = Some(resume::InDesign { row: row.clone(), episodes: written });
                p.seconds = seconds_before + start.elapsed().as_secs_f64();
                l.snapshot(&mut p, out, snaps, &format!("design {index} episode {written}"))?;
                p.in_design = None;
                since_snapshot = 0;
                if stopping {
                    interrupted = true;
                    break;
                }
            }
        }
        // An interrupted design drops what is still out; the actors' late chunks are ignored.
        l.fleet.forget_all();
        out.design(&row)?;
        out.events().design_ended(&row)?;
        out.checkpoint(index, &l.fear)?;
        on_event(&RunEvent::DesignEnd { row: &row });
        p.rows.push(row);
        if !interrupted {
            p.design = index + 1;
            p.seconds = seconds_before + start.elapsed().as_secs_f64();
            l.snapshot(&mut p, out, snaps, &format!("design {index} end"))?;
            on_event(&RunEvent::Stats(&l.stats(index, p.global, p.steps, 0, snaps, p.resumes)));
        }
        if interrupted || shutdown.load(Ordering::Relaxed) {
            stopped = true;
            break;
        }
    }
    let interrupted = stopped || p.rows.len() < cfg.designs;
    let time = l.time();
    Ok(RunOutcome { learner: l.fear, designs: p.rows, rejected: l.rejected, interrupted, time })
}

/// The most a stop that lands while an evaluation is out waits for it (and anything else out)
/// to come back, so the run can snapshot with nothing out (it waits three times the longest
/// episode so far, at least 1 s): an episode of the robots here takes a second or two; the
/// bound stays inside the grace the deploy scripts give before SIGTERM (30 s), and a second
/// Ctrl-C aborts at once.
pub const STOP_WAIT: Duration = Duration::from_secs(20);

/// A stop (Ctrl-C, SIGTERM) that lands while an episode is out: the snapshot a stop at the
/// last quiet point `at` would have taken, so a stop never costs more than the episodes out
/// (before, a stop before a design's first periodic snapshot left none, and a stop in the
/// first design lost the whole run so far). Nothing was learnt or written since `at` (the loop
/// forgets it when an episode comes back), so the networks, the rows and `p` are as they were
/// then; only the counters that handing out the episode moved are put back, so the resumed run
/// hands it out again under the same weights version, to the rows of a run never stopped.
/// `None` (an episode came back since, and no quiet point followed) takes no snapshot: the
/// last one stands.
/// (`p.seconds` is the caller's: the time now.)
fn snapshot_at_quiet(
    l: &mut Learner<'_>,
    at: Option<resume::QuietPoint>,
    p: &mut resume::Progress,
    row: &crate::run_dir::DesignRow,
    written: usize,
    out: &mut RunWriter,
    snaps: &mut Snapshots,
) -> Result<(), CoadaptError> {
    let Some(at) = at else { return Ok(()) };
    if !l.shutdown.load(Ordering::Relaxed) {
        return Ok(());
    }
    // A stop during an operator's reset wait has nothing out.
    let why = if l.fleet.outstanding() > 0 { "stopped with an episode out" } else { "stopped" };
    l.back_to(&at);
    p.in_design = Some(resume::InDesign { row: row.clone(), episodes: written });
    let label = format!("design {} episode {written} ({why})", row.index);
    l.snapshot(p, out, snaps, &label)?;
    p.in_design = None;
    Ok(())
}
