//! A broken or hostile design optimiser cannot hurt the run: a reply outside the design box
//! (which would make every actor fail at reset) or with a method that would forge rows of
//! `designs.csv` is refused and counted, the request is sent again after its deadline, and the
//! run goes on with the next good reply. Through the whole learner role over the in-process
//! transport with a real actor (Pendulum).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::Mutex;
use std::sync::atomic::AtomicBool;

use coadapt_actors::{Actor, PolicyKind};
use coadapt_learner::coadapt::{self, ScheduleConfig};
use coadapt_learner::fear::FearLearnerConfig;
use coadapt_learner::flow::FlowConfig;
use coadapt_learner::run_dir::RunWriter;
use coadapt_learner::{SacConfig, networks};
use coadapt_transport::{DesignReply, in_process, next_or_stop};

const HIDDEN: [usize; 1] = [16];

/// The optimiser's reply (design, method) to copy `n` of the request, given the design box's
/// low and high corners.
type Answer = dyn Fn(usize, &[f32], &[f32]) -> (Vec<f32>, String) + Sync;

/// Runs a 2-design Pendulum co-adaptation whose design requests are answered by `answer`
/// with `resend_secs` as the resend setting; gives the outcome, the run's directory and the
/// copies of the request the optimiser received.
fn run_against(name: &str, resend_secs: f64, answer: &Answer) -> (coadapt::RunOutcome, std::path::PathBuf, usize) {
    let spec = coadapt_robots::make("pendulum").unwrap().spec().clone();
    let dir = std::env::temp_dir().join(format!("coadapt-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let schedule = ScheduleConfig {
        designs: 2,
        initial_designs: vec![vec![1.0, 1.0]],
        initial_episodes: 1,
        episodes_per_design: 1,
        start_state_batch: 4,
        episode_timeout_secs: 30.0,
        design_request_resend_secs: resend_secs,
        design_request_timeout_secs: 30.0,
        ..ScheduleConfig::default()
    };
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
    let requests = Mutex::new(0usize);
    let outcome = std::thread::scope(|s| {
        let (spec, shutdown, requests) = (&spec, &shutdown, &requests);
        let mut links = actors.pop().unwrap();
        s.spawn(move || {
            let policy = networks::gaussian_policy(spec.obs_dim(), spec.act_dim(), &HIDDEN).unwrap();
            let mut actor = Actor::new(coadapt_robots::make("pendulum").unwrap(), policy, PolicyKind::SquashedGaussian, 3).unwrap();
            coadapt_actors::role::run(&mut actor, 0, &mut links, 50, 0, shutdown).unwrap();
        });
        s.spawn(move || {
            while let Some(req) = next_or_stop(optimizer.requests.as_mut(), shutdown).unwrap() {
                let n = {
                    let mut n = requests.lock().unwrap();
                    *n += 1;
                    *n - 1
                };
                let (design, method) = answer(n, &spec.design.low, &spec.design.high);
                optimizer
                    .replies
                    .send(DesignReply { index: req.index, design, method, predicted_objective: None, design_rollouts: 0 })
                    .unwrap();
            }
        });
        let mut out = RunWriter::create(&dir).unwrap();
        let outcome = coadapt::run(
            &schedule,
            &learner_cfg,
            spec,
            11,
            &FlowConfig::default(),
            1,
            &mut learner,
            &mut out,
            shutdown,
            &mut |_| {},
            &mut coadapt::Snapshots::off(),
        );
        drop(learner);
        outcome
    })
    .unwrap();
    let n = *requests.lock().unwrap();
    (outcome, dir, n)
}

fn good(low: &[f32], high: &[f32]) -> Vec<f32> {
    vec![low[0] + 0.1, high[1] - 0.1]
}

#[test]
fn out_of_box_and_row_forging_replies_are_refused_and_the_run_goes_on() {
    // Every copy of the request gets the next reply of this list.
    let answer = |n: usize, low: &[f32], high: &[f32]| {
        let good = good(low, high);
        let mut outside = good.clone();
        outside[0] = high[0] * 10.0;
        let replies = [
            (outside, "pso-q".to_string()),
            (good.clone(), "pso-q\n7,exploit,1;1,999,1e9,1e9,,0,forged,".to_string()),
            (good.clone(), "pso-q,extra".to_string()),
            (good, "pso-q".to_string()),
        ];
        replies[n.min(3)].clone()
    };
    let (outcome, dir, _) = run_against("hostile-opt", 0.2, &answer);
    let spec = coadapt_robots::make("pendulum").unwrap().spec().clone();
    assert!(!outcome.interrupted);
    assert_eq!(outcome.designs.len(), 2);
    assert_eq!(outcome.designs[1].design, good(&spec.design.low, &spec.design.high), "the run trained on the good reply");
    assert_eq!(outcome.designs[1].method, "pso-q");
    assert_eq!(outcome.time.design_replies_refused, 3, "{:?}", outcome.time);
    assert_eq!(outcome.time.design_requests_resent, 3, "{:?}", outcome.time);
    let csv = std::fs::read_to_string(dir.join("designs.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "header and two designs, nothing forged:\n{csv}");
    assert!(!csv.contains("forged"), "{csv}");
}

#[test]
fn a_slow_optimiser_is_sent_few_copies_of_its_request() {
    // The first copy takes 2.5 s to answer (a long search), answered once; the copies that came
    // meanwhile get the stored reply, as the real optimiser's do. With a 0.1 s setting, copies
    // every 0.1 s would be about 24; backing off (0.1, 0.2, 0.4, 0.8, then 1.6 s apart) sends 4
    // or 5 before the reply.
    let answer = |n: usize, low: &[f32], high: &[f32]| {
        if n == 0 {
            std::thread::sleep(std::time::Duration::from_millis(2500));
        }
        (good(low, high), "pso-q".to_string())
    };
    let (outcome, _, requests) = run_against("slow-opt", 0.1, &answer);
    assert!(!outcome.interrupted);
    assert_eq!(outcome.designs.len(), 2);
    let resent = outcome.time.design_requests_resent;
    assert!((2..=6).contains(&resent), "{resent} copies sent for a 2.5 s search with a 0.1 s setting: {:?}", outcome.time);
    assert_eq!(requests as u64, 1 + resent, "every copy reached the optimiser");
}

#[test]
fn designs_csv_quotes_text_so_no_value_forges_a_row() {
    let dir = std::env::temp_dir().join(format!("coadapt-csv-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut out = RunWriter::create(&dir).unwrap();
    let row = coadapt_learner::run_dir::DesignRow {
        index: 0,
        kind: "initial".into(),
        design: vec![1.0, 2.5],
        episodes: 3,
        best_eval_return: Some(1.5),
        last_eval_return: None,
        predicted_objective: None,
        design_rollouts: 0,
        method: "fixed".into(),
        prototype: "as-built \"a\",\n1,exploit".into(),
    };
    out.design(&row).unwrap();
    let text = std::fs::read_to_string(dir.join("designs.csv")).unwrap();
    let mut r = csv::Reader::from_reader(text.as_bytes());
    let records: Vec<csv::StringRecord> = r.records().map(|r| r.unwrap()).collect();
    assert_eq!(records.len(), 1, "{text}");
    assert_eq!(&records[0][9], "as-built \"a\",\n1,exploit");
    // Plain rows are written as before the writer: no quotes.
    assert!(text.starts_with(&format!("{}\n0,initial,1;2.5,3,1.5,,,0,fixed,\"", coadapt_learner::run_dir::DESIGNS_HEADER)), "{text}");
}
