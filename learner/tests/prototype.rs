//! The prototype step for real hardware, through the whole learner role: `coadapt::run` over
//! the in-process transport with a real actor (Pendulum, recording the design of every reset),
//! the real design optimiser (PSO over Q, novelty search), and a thread playing the operator
//! with the library functions `coadapt confirm` calls.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use coadapt_actors::{Actor, PolicyKind};
use coadapt_core::{Env, EnvError, EnvSpec, Step};
use coadapt_design_optimizer::role::{ExploitMethod, ExploreMethod, Optimizer, OptimizerConfig, OptimizerSpec};
use coadapt_learner::coadapt::{self, RunEvent, RunOutcome, ScheduleConfig};
use coadapt_learner::fear::{ActingPolicy, FearLearnerConfig};
use coadapt_learner::flow::FlowConfig;
use coadapt_learner::prototype::{
    self, Answer, ConfirmError, PROTOTYPE_DECISION_FILE, PROTOTYPE_FILE, Prototype, PrototypeDecision, RESET_FILE, ResetMode, ResetRequest,
    Status, Verdict,
};
use coadapt_learner::run_dir::RunWriter;
use coadapt_learner::{SacConfig, networks};
use coadapt_transport::{DesignReply, DesignRequest, in_process, newest_or_stop, next_or_stop};

/// Pendulum, noting the design of every reset: what the actors were really handed.
struct Recording {
    inner: Box<dyn Env>,
    resets: Arc<Mutex<Vec<Vec<f32>>>>,
}

impl Env for Recording {
    fn spec(&self) -> &EnvSpec {
        self.inner.spec()
    }
    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.resets.lock().unwrap().push(design.to_vec());
        self.inner.reset(seed, design)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        self.inner.step(action)
    }
}

const HIDDEN: [usize; 1] = [16];

/// Two fixed designs (2 episodes each), then an exploitation and an exploration design (1
/// episode each), every design's prototype confirmed by the operator.
fn schedule() -> ScheduleConfig {
    ScheduleConfig {
        designs: 4,
        initial_designs: vec![vec![1.0, 1.0], vec![1.5, 0.7]],
        initial_episodes: 2,
        episodes_per_design: 1,
        start_state_batch: 4,
        eval_every: 1,
        episode_timeout_secs: 30.0,
        confirm_designs: true,
        confirm_poll_secs: 0.05,
        ..ScheduleConfig::default()
    }
}

fn learner_cfg() -> FearLearnerConfig {
    FearLearnerConfig {
        sac: SacConfig { hidden: HIDDEN.to_vec(), batch_size: 16, ..SacConfig::default() },
        population_batch: 4,
        species_batch: 12,
        individual_updates: 5,
        population_updates: 5,
        population_updates_from_design: 1,
        warmup_episodes: 1,
        ..FearLearnerConfig::default()
    }
}

fn optimizer_cfg() -> OptimizerConfig {
    let mut c = OptimizerConfig { exploit: ExploitMethod::PsoQ, explore: ExploreMethod::Novelty, cores: 1, ..OptimizerConfig::default() };
    c.pso.particles = 30;
    c.pso.iterations = 8;
    c.novelty.pso.particles = 30;
    c.novelty.pso.iterations = 8;
    c
}

/// What a run left, and what its fleet saw.
struct Run {
    outcome: RunOutcome,
    dir: PathBuf,
    /// Every design request, with the optimiser's reply.
    requests: Vec<(DesignRequest, DesignReply)>,
    /// The design of every environment reset, in order.
    resets: Vec<Vec<f32>>,
    /// The prototype and reset events, as text.
    events: Vec<String>,
}

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch("prototype", name)
}

/// What the operator thread gets: the run directory, the resets so far, and whether the run
/// has ended (so a helper waiting for a file gives up instead of hanging a failed test).
struct Bench<'a> {
    dir: &'a Path,
    resets: &'a Mutex<Vec<Vec<f32>>>,
    over: &'a AtomicBool,
    shutdown: &'a AtomicBool,
}

impl Bench<'_> {
    /// Waits until `prototype.json` shows design `index`'s proposal `proposal` awaiting.
    fn awaiting(&self, index: usize, proposal: usize) -> Prototype {
        let t = Instant::now();
        loop {
            if let Ok(Some(p)) = prototype::read_json::<Prototype>(&self.dir.join(PROTOTYPE_FILE))
                && (p.index, p.proposal, p.status) == (index, proposal, Status::Awaiting)
            {
                return p;
            }
            assert!(!self.over.load(Ordering::Relaxed), "the run ended before design {index} proposal {proposal} awaited its prototype");
            assert!(t.elapsed() < Duration::from_secs(120), "design {index} proposal {proposal} never awaited its prototype");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    fn answer(&self, index: usize, proposal: usize, answer: Answer) -> Prototype {
        let p = self.awaiting(index, proposal);
        prototype::confirm_prototype(self.dir, &answer).unwrap();
        p
    }

    fn resets(&self) -> usize {
        self.resets.lock().unwrap().len()
    }
}

/// Runs `schedule` with a thread playing the operator; the operator's result comes back too.
fn run<T: Send>(name: &str, schedule: &ScheduleConfig, operator: impl FnOnce(&Bench<'_>) -> T + Send) -> (Run, T) {
    let spec = coadapt_robots::make("pendulum").unwrap().spec().clone();
    let dir = tmpdir(name);
    let (mut learner, mut actors, mut optimizer) = in_process::fleet(1);
    let (shutdown, over) = (AtomicBool::new(false), AtomicBool::new(false));
    let resets = Arc::new(Mutex::new(Vec::new()));
    let requests = Mutex::new(Vec::new());
    let mut events = Vec::new();
    let (outcome, answer) = std::thread::scope(|s| {
        let (spec, shutdown, over, requests) = (&spec, &shutdown, &over, &requests);
        let mut links = actors.pop().unwrap();
        let env = Recording { inner: coadapt_robots::make("pendulum").unwrap(), resets: resets.clone() };
        s.spawn(move || {
            let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), &HIDDEN).unwrap();
            let mut actor = Actor::new(env, policy, PolicyKind::SquashedGaussian, 3).unwrap();
            coadapt_actors::role::run(&mut actor, 0, &mut links, 50, 0, shutdown).unwrap();
        });
        s.spawn(move || {
            let ospec = OptimizerSpec {
                policy: networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), &HIDDEN).unwrap(),
                critic: networks::critic(spec.obs_dim(), spec.act_dim(), &HIDDEN).unwrap(),
                bounds: spec.design.clone(),
                design_at: spec.state_dim,
                obs_dim: spec.obs_dim(),
                act_dim: spec.act_dim(),
            };
            let mut opt = Optimizer::new(optimizer_cfg(), ospec, None, 5).unwrap();
            while let Some(req) = next_or_stop(optimizer.requests.as_mut(), shutdown).unwrap() {
                let Some(w) = newest_or_stop(optimizer.weights.as_mut(), req.weights_version, shutdown).unwrap() else { break };
                let reply = opt.choose(&req, &w).unwrap();
                requests.lock().unwrap().push((req, reply.clone()));
                optimizer.replies.send(reply).unwrap();
            }
        });
        let bench = Bench { dir: &dir, resets: &resets, over, shutdown };
        let operator = s.spawn(move || operator(&bench));
        let mut out = RunWriter::create(&dir).unwrap();
        let mut on_event = |e: &RunEvent<'_>| match e {
            RunEvent::AwaitingPrototype { index, row, names } => events.push(format!("awaiting {index} {:?} {names:?}", row.design)),
            RunEvent::PrototypeDecided { row, outcome, requested } => {
                events.push(format!("decided {} {outcome:?} requested {requested:?} row {:?} {}", row.index, row.design, row.prototype))
            }
            RunEvent::AwaitingReset { design_index, episode, mode, .. } => events.push(format!("reset? {design_index} {episode} {mode:?}")),
            RunEvent::ResetConfirmed { design_index, episode, mode } => events.push(format!("reset! {design_index} {episode} {mode:?}")),
            _ => {}
        };
        let flow = FlowConfig::default();
        let outcome = coadapt::run(
            schedule,
            &learner_cfg(),
            spec,
            11,
            &flow,
            1,
            &mut learner,
            &mut out,
            shutdown,
            &mut on_event,
            &mut coadapt::Snapshots::off(),
        );
        over.store(true, Ordering::Relaxed);
        // Closing the learner's channels ends the actor and the optimiser.
        drop(learner);
        let answer = operator.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
        (outcome.unwrap(), answer)
    });
    let resets = resets.lock().unwrap().clone();
    (Run { outcome, dir, requests: requests.into_inner().unwrap(), resets, events }, answer)
}

/// `designs.csv` as rows of fields (header first).
fn designs_csv(dir: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(dir.join("designs.csv")).unwrap();
    text.lines().map(|l| l.split(',').map(String::from).collect()).collect()
}

fn col(rows: &[Vec<String>], name: &str) -> Vec<String> {
    let i = rows[0].iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name}"));
    rows[1..].iter().map(|r| r[i].clone()).collect()
}

/// Every design waits for its prototype, the fixed ones included, longer than the silence
/// limit without failing the run; nothing runs on a design before its prototype is confirmed,
/// and designs.csv shows the waiting design meanwhile.
#[test]
fn every_design_waits_for_its_prototype_longer_than_the_silence_limit() {
    let mut s = schedule();
    s.episode_timeout_secs = 0.5;
    let (r, (seen_csv, resets_while_waiting, fixed_reject)) = run("confirm", &s, |b| {
        let p = b.awaiting(0, 1);
        assert_eq!(p.dimensions, [("pole length".to_string(), 1.0), ("pole mass".to_string(), 1.0)]);
        assert_eq!((p.kind.as_str(), p.method.as_str(), p.low.clone(), p.high.clone()), ("initial", "fixed", vec![0.5; 2], vec![2.0; 2]));
        // Three times the silence limit at the workbench.
        std::thread::sleep(Duration::from_millis(1500));
        let seen_csv = designs_csv(b.dir);
        let resets_while_waiting = b.resets();
        let fixed_reject = prototype::confirm_prototype(b.dir, &Answer::Reject).unwrap_err();
        prototype::confirm_prototype(b.dir, &Answer::Confirm).unwrap();
        for i in 1..4 {
            b.answer(i, 1, Answer::Confirm);
        }
        (seen_csv, resets_while_waiting, fixed_reject)
    });
    assert!(!r.outcome.interrupted);
    assert_eq!(r.outcome.designs.len(), 4);
    assert_eq!(resets_while_waiting, 0, "no episode before the prototype is confirmed");
    assert!(matches!(fixed_reject, ConfirmError::FixedDesign { index: 0 }), "{fixed_reject}");
    assert_eq!(seen_csv.len(), 2, "the header and the waiting design: {seen_csv:?}");
    assert_eq!(seen_csv[1].join(","), "0,initial,1;1,0,,,,0,fixed,awaiting");
    assert!(r.outcome.time.waiting_for_prototype >= 1.5, "{:?}", r.outcome.time);

    let csv = designs_csv(&r.dir);
    assert_eq!(*csv[0].last().unwrap(), "prototype");
    assert_eq!(col(&csv, "index"), ["0", "1", "2", "3"]);
    assert_eq!(col(&csv, "prototype"), ["confirmed"; 4]);
    assert_eq!(col(&csv, "episodes"), ["2", "2", "1", "1"]);
    let p: Prototype = prototype::read_json(&r.dir.join(PROTOTYPE_FILE)).unwrap().unwrap();
    assert_eq!((p.index, p.status), (3, Status::Confirmed));
    assert!(!r.dir.join(PROTOTYPE_DECISION_FILE).exists(), "the learner deletes a decision once read");
    let e = prototype::confirm_prototype(&r.dir, &Answer::Confirm).unwrap_err().to_string();
    assert!(e.contains("nothing in") && e.contains("awaits a prototype"), "{e}");
    assert_eq!(r.events.iter().filter(|e| e.starts_with("awaiting")).count(), 4);
    assert!(r.events[0].contains(r#"["pole length", "pole mass"]"#), "{:?}", r.events);
}

/// Built with other dimensions than asked for: the measured design is what every later
/// episode runs with, what designs.csv and the outcome hold, and what the optimiser is told
/// was chosen.
#[test]
fn as_built_dimensions_replace_the_requested_ones() {
    let (r, exploit_requested) = run("as-built", &schedule(), |b| {
        b.answer(0, 1, Answer::Confirm);
        b.answer(1, 1, Answer::AsBuilt(vec![1.45, 0.72]));
        let p = b.awaiting(2, 1);
        let built: Vec<f32> = p.design.iter().zip(&p.low).map(|(x, lo)| (x - 0.1).max(*lo)).collect();
        b.answer(2, 1, Answer::AsBuilt(built));
        b.answer(3, 1, Answer::Confirm);
        p.design
    });
    assert!(!r.outcome.interrupted);
    let exploit_built: Vec<f32> = exploit_requested.iter().map(|x| (x - 0.1).max(0.5)).collect();
    assert_eq!(r.outcome.designs[1].design, [1.45, 0.72]);
    assert_eq!(r.outcome.designs[2].design, exploit_built);
    // Design 0: 2 episodes + 2 evaluations, then design 1's four resets, then design 2's two.
    assert_eq!(r.resets.len(), 4 + 4 + 2 + 2);
    assert!(r.resets[4..8].iter().all(|d| d == &[1.45, 0.72]), "design 1 ran as built: {:?}", &r.resets[4..8]);
    assert!(r.resets[8..10].iter().all(|d| d == &exploit_built), "design 2 ran as built: {:?}", &r.resets[8..10]);
    assert!(!r.resets.iter().any(|d| d == &[1.5, 0.7] || d == &exploit_requested), "a requested design never ran");
    // The optimiser hears of the designs as built.
    let (last, _) = r.requests.last().unwrap();
    assert_eq!(last.index, 3);
    assert_eq!(last.chosen, [&[1.0, 1.0][..], &[1.45, 0.72], &exploit_built].concat());

    let csv = designs_csv(&r.dir);
    assert_eq!(col(&csv, "design")[1], "1.45;0.72");
    assert_eq!(col(&csv, "prototype")[..2], ["confirmed", "as-built (requested 1.5;0.7)"]);
    assert!(col(&csv, "prototype")[2].starts_with("as-built (requested "), "{csv:?}");
    let p: Prototype = prototype::read_json(&r.dir.join(PROTOTYPE_FILE)).unwrap().unwrap();
    assert_eq!(p.status, Status::Confirmed);
    assert!(r.events.iter().any(|e| e.starts_with("decided 1 AsBuilt([1.45, 0.72]) requested [1.5, 0.7]")), "{:?}", r.events);
}

/// A rejected proposal: the optimiser is asked again for the same index with the design in
/// `rejected` (and every later request keeps it), proposes a design outside the reject radius,
/// and designs.csv keeps the rejected proposal as a row of its own.
#[test]
fn a_rejected_design_makes_the_optimiser_propose_its_next_best() {
    let (r, first) = run("reject", &schedule(), |b| {
        b.answer(0, 1, Answer::Confirm);
        b.answer(1, 1, Answer::Confirm);
        let first = b.answer(2, 1, Answer::Reject);
        b.answer(2, 2, Answer::Confirm);
        b.answer(3, 1, Answer::Confirm);
        first.design
    });
    assert!(!r.outcome.interrupted);
    let asked: Vec<(u32, Vec<f32>)> = r.requests.iter().map(|(q, _)| (q.index, q.rejected.clone())).collect();
    assert_eq!(asked, [(2, vec![]), (2, first.clone()), (3, first.clone())], "asked again, then every rejection goes along");
    let second = &r.requests[1].1.design;
    let scaled = ((second[0] - first[0]).powi(2) + (second[1] - first[1]).powi(2)).sqrt() / 1.5;
    assert!(scaled > OptimizerConfig::default().reject_radius, "{first:?} then {second:?}");
    assert_eq!(r.outcome.designs[2].design, *second);
    assert_eq!(r.outcome.rejected.len(), 1);
    assert_eq!(r.outcome.rejected[0].design, first);
    assert!(!r.resets.contains(&first), "the rejected design never ran");

    let csv = designs_csv(&r.dir);
    assert_eq!(col(&csv, "index"), ["0", "1", "2", "2", "3"]);
    assert_eq!(col(&csv, "prototype"), ["confirmed", "confirmed", "rejected", "confirmed", "confirmed"]);
    assert_eq!(col(&csv, "episodes"), ["2", "2", "0", "1", "1"]);
    assert_eq!(col(&csv, "best_eval_return")[2], "", "a rejected design has no returns");
    assert!(r.events.iter().any(|e| e.starts_with("decided 2 Rejected")), "{:?}", r.events);
}

/// A robot reset by hand: every episode, evaluations included, waits for the operator, and
/// starts only after the reset is confirmed.
#[test]
fn resets_wait_for_the_operator_before_every_episode() {
    let mut s = schedule();
    s.designs = 2;
    s.confirm_designs = false;
    s.reset_needs_confirmation = true;
    let (r, seen) = run("reset", &s, |b| {
        let mut seen = Vec::new();
        let t = Instant::now();
        while seen.len() < 8 {
            assert!(t.elapsed() < Duration::from_secs(120) && !b.over.load(Ordering::Relaxed), "resets seen: {seen:?}");
            if let Ok(Some(q)) = prototype::read_json::<ResetRequest>(&b.dir.join(RESET_FILE))
                && q.status == Status::Awaiting
                && seen.last().is_none_or(|&(d, e, m, _)| (d, e, m) != (q.design_index, q.episode, q.mode))
            {
                seen.push((q.design_index, q.episode, q.mode, b.resets()));
                prototype::confirm_reset(b.dir).unwrap();
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        seen
    });
    assert!(!r.outcome.interrupted);
    let (t, e) = (ResetMode::Train, ResetMode::Eval);
    let expected = [(0, 0, t), (0, 0, e), (0, 1, t), (0, 1, e), (1, 0, t), (1, 0, e), (1, 1, t), (1, 1, e)];
    assert_eq!(seen.iter().map(|&(d, e, m, _)| (d, e, m)).collect::<Vec<_>>(), expected);
    // When each reset was asked for, exactly the episodes confirmed before it had started.
    assert_eq!(seen.iter().map(|s| s.3).collect::<Vec<_>>(), (0..8).collect::<Vec<_>>());
    assert_eq!(r.resets.len(), 8);
    assert!(r.outcome.time.waiting_for_reset > 0.0);
    assert_eq!(r.events.iter().filter(|e| e.starts_with("reset!")).count(), 8);
    assert!(!r.dir.join(PROTOTYPE_FILE).exists(), "designs were not confirmed");
}

/// Ctrl-C while a prototype is awaited ends the run at once, interrupted, and marks the wait
/// moot so `coadapt confirm` says nothing awaits.
#[test]
fn shutdown_while_waiting_interrupts_the_run() {
    let (r, ()) = run("shutdown", &schedule(), |b| {
        b.answer(0, 1, Answer::Confirm);
        b.awaiting(1, 1);
        b.shutdown.store(true, Ordering::Relaxed);
    });
    assert!(r.outcome.interrupted);
    assert_eq!(r.outcome.designs.len(), 1);
    let p: Prototype = prototype::read_json(&r.dir.join(PROTOTYPE_FILE)).unwrap().unwrap();
    assert_eq!((p.index, p.status), (1, Status::Interrupted));
    let e = prototype::confirm_prototype(&r.dir, &Answer::Confirm).unwrap_err();
    assert!(matches!(e, ConfirmError::NothingAwaits { .. }), "{e}");
    assert_eq!(col(&designs_csv(&r.dir), "prototype"), ["confirmed", "awaiting"]);
}

/// While it waits the learner trains the population networks at the configured rate, and a
/// decision that does not answer the awaiting prototype (another proposal, measurements
/// outside the box) is read, deleted and ignored.
#[test]
fn waiting_trains_the_population_and_ignores_decisions_for_something_else() {
    let mut s = schedule();
    s.train_while_waiting = 40;
    let (r, still_awaiting) = run("train-while-waiting", &s, |b| {
        b.answer(0, 1, Answer::Confirm);
        let p = b.awaiting(1, 1);
        let path = b.dir.join(PROTOTYPE_DECISION_FILE);
        let mut still_awaiting = Vec::new();
        for bad in [
            PrototypeDecision { index: 1, proposal: 7, decision: Verdict::Confirm, as_built: None },
            PrototypeDecision { index: 1, proposal: 1, decision: Verdict::Confirm, as_built: Some(vec![9.0, 1.0]) },
        ] {
            prototype::write_json(&path, &bad).unwrap();
            let t = Instant::now();
            while path.exists() {
                assert!(t.elapsed() < Duration::from_secs(30), "the learner never read the decision");
                std::thread::sleep(Duration::from_millis(10));
            }
            std::thread::sleep(Duration::from_millis(200));
            let now: Prototype = prototype::read_json(&b.dir.join(PROTOTYPE_FILE)).unwrap().unwrap();
            still_awaiting.push(now == p);
        }
        std::thread::sleep(Duration::from_millis(500));
        prototype::confirm_prototype(b.dir, &Answer::Confirm).unwrap();
        b.answer(2, 1, Answer::Confirm);
        b.answer(3, 1, Answer::Confirm);
        still_awaiting
    });
    assert_eq!(still_awaiting, [true, true], "ignored decisions leave the prototype awaiting");
    assert!(!r.outcome.interrupted);
    let (made, waited) = (r.outcome.time.updates_while_waiting, r.outcome.time.waiting_for_prototype);
    assert!(made >= 20, "{made} population updates in {waited:.2} s of waiting at 40/s");
    assert!(made as f64 <= 40.0 * waited + 10.0, "{made} updates in {waited:.2} s: more than 40/s");
    assert!(r.outcome.learner.agent(ActingPolicy::Population).updates() >= made);
    assert_eq!(col(&designs_csv(&r.dir), "prototype"), ["confirmed"; 4]);
}
