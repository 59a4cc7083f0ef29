//! `coadapt run` end to end: the tiny config through the binary, and every baseline and
//! ablation as a configuration of the same run through the library.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;

use coadapt_coadaptation::config::{RunConfig, check, resolve_initial_designs};
use coadapt_coadaptation::run::run_config;
use coadapt_design_optimizer::role::ExploitMethod;
use coadapt_learner::fear::ActingPolicy;

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch("run", name)
}

fn workspace_file(rel: &str) -> PathBuf {
    coadapt_test_support::workspace_file(rel)
}

fn tiny() -> RunConfig {
    let text = std::fs::read_to_string(workspace_file("configs/half-cheetah-tiny.toml")).unwrap();
    toml::from_str(&text).unwrap()
}

/// Rows of a CSV file as header -> value maps.
fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect::<Vec<_>>();
    let rows = lines.map(|l| l.split(',').map(String::from).collect::<Vec<_>>()).collect::<Vec<_>>();
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), header.len(), "{} row {i} has {} fields: {r:?}", path.display(), r.len());
    }
    (header, rows)
}

fn col<'a>(header: &[String], rows: &'a [Vec<String>], name: &str) -> Vec<&'a str> {
    let i = header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    rows.iter().map(|r| r[i].as_str()).collect()
}

#[test]
fn the_tiny_config_writes_the_whole_run_directory() {
    let out = tmpdir("tiny");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", workspace_file("configs/half-cheetah-tiny.toml").to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "stderr: {stderr}");
    assert!(stderr.contains("design 3/4 [exploit pso-q]"), "progress names design, kind and method: {stderr}");
    assert!(stderr.contains("ETA"), "progress shows an ETA: {stderr}");
    assert!(!stderr.contains("starting it again"), "roles that end with the run are not restarted: {stderr}");
    let summary: serde_json::Value = serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap();
    assert_eq!(summary["designs"], 4);
    assert_eq!(summary["design_rollouts"], 0, "FEAR spends no design rollouts");
    assert_eq!((summary["prototype_waiting_seconds"].as_f64(), summary["prototypes_rejected"].as_u64()), (Some(0.0), Some(0)));

    // The resolved config reads back as the config that ran.
    let mut resolved: RunConfig = toml::from_str(&std::fs::read_to_string(out.join("config.toml")).unwrap()).unwrap();
    assert!(resolved.fleet.name.starts_with("coadapt-"), "the fleet gets a name of its own: {:?}", resolved.fleet.name);
    resolved.fleet.name.clear();
    let mut expected = tiny();
    resolve_initial_designs(&mut expected, &coadapt_robots::make("half-cheetah").unwrap().spec().clone());
    assert_eq!(resolved, expected);

    let (h, rows) = csv(&out.join("designs.csv"));
    assert_eq!(
        h,
        [
            "index",
            "kind",
            "design",
            "episodes",
            "best_eval_return",
            "last_eval_return",
            "predicted_objective",
            "design_rollouts",
            "method",
            "prototype"
        ]
    );
    assert_eq!(col(&h, &rows, "prototype"), ["", "", "", ""], "no prototype step unless schedule.confirm-designs");
    assert_eq!(col(&h, &rows, "index"), ["0", "1", "2", "3"]);
    assert_eq!(col(&h, &rows, "kind"), ["initial", "initial", "exploit", "explore"]);
    assert_eq!(col(&h, &rows, "method"), ["fixed", "fixed", "pso-q", "novelty"]);
    assert_eq!(col(&h, &rows, "episodes"), ["3", "3", "2", "2"]);
    for (i, d) in col(&h, &rows, "design").iter().enumerate() {
        let v: Vec<f32> = d.split(';').map(|x| x.parse().unwrap()).collect();
        assert_eq!(v.len(), 6, "design {i}");
        assert!(v.iter().all(|x| (0.8..=2.0).contains(x)), "design {i} inside the bounds: {v:?}");
    }
    for (i, p) in col(&h, &rows, "predicted_objective").iter().enumerate() {
        assert_eq!(p.is_empty(), i < 2, "only chosen designs carry a predicted objective (row {i}: {p:?})");
    }
    for r in col(&h, &rows, "best_eval_return").iter().chain(&col(&h, &rows, "last_eval_return")) {
        assert!(r.parse::<f32>().unwrap().is_finite());
    }

    let (h, rows) = csv(&out.join("episodes.csv"));
    assert_eq!(
        h,
        ["design", "episode", "global_episode", "steps", "return", "eval_return", "weights_version", "seconds", "actor", "policy_lag"]
    );
    assert_eq!(rows.len(), 10);
    assert_eq!(col(&h, &rows, "design"), ["0", "0", "0", "1", "1", "1", "2", "2", "3", "3"]);
    let steps: Vec<u64> = col(&h, &rows, "steps").iter().map(|s| s.parse().unwrap()).collect();
    assert_eq!(steps.last(), Some(&10_000), "ten 1000-step episodes");
    assert!(col(&h, &rows, "return").iter().all(|r| r.parse::<f32>().unwrap().is_finite()));

    let (h, rows) = csv(&out.join("landscape.csv"));
    assert_eq!(h, ["pc1", "pc2", "objective"]);
    assert_eq!(rows.len(), 12 * 12);
    let (h, rows) = csv(&out.join("landscape_designs.csv"));
    assert_eq!(h, ["index", "kind", "pc1", "pc2"]);
    assert_eq!(rows.len(), 4);

    for f in ["checkpoints/population.safetensors", "checkpoints/individual.safetensors"] {
        assert!(out.join(f).metadata().unwrap().len() > 1000, "{f}");
    }
    for f in ["learning_curves.svg", "best_return.svg", "landscape.svg"] {
        let svg = std::fs::read_to_string(out.join("plots").join(f)).unwrap();
        assert!(svg.contains("<svg"), "{f}");
    }

    // `coadapt plot` redraws them; a second run into the same directory is refused.
    std::fs::remove_dir_all(out.join("plots")).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt")).args(["plot", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("plots/landscape.svg").exists());
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", workspace_file("configs/half-cheetah-tiny.toml").to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("already holds a run"));
}

/// A tiny config with the design searches shrunk so rollouts stay cheap.
fn small(exploit: ExploitMethod) -> RunConfig {
    let mut c = tiny();
    c.landscape_grid = 0;
    c.optimizer.exploit = exploit;
    c.optimizer.sim_pso.particles = 3;
    c.optimizer.sim_pso.iterations = 2;
    c.optimizer.sim_cmaes.population = Some(3);
    c.optimizer.sim_cmaes.generations = 2;
    c.optimizer.openai_es.population = 4;
    c.optimizer.cmaes_es.population = Some(3);
    c.optimizer.cmaes.generations = 5;
    resolve_initial_designs(&mut c, &coadapt_robots::make("half-cheetah").unwrap().spec().clone());
    c
}

fn rollouts_and_methods(c: &RunConfig, name: &str) -> Vec<(String, String, u64)> {
    let out = tmpdir(name);
    let outcome = run_config(c, &out, &AtomicBool::new(false), false).unwrap();
    assert!(!outcome.interrupted);
    assert_eq!(outcome.designs.len(), c.schedule.designs);
    outcome.designs.iter().map(|d| (d.kind.clone(), d.method.clone(), d.design_rollouts)).collect()
}

#[test]
fn simulation_baselines_spend_rollouts_and_fear_spends_none() {
    let r = rollouts_and_methods(&small(ExploitMethod::SimPso), "sim-pso");
    assert_eq!(r[2], ("exploit".into(), "sim-pso".into(), 6), "PSO 3 particles x 2 iterations = 6 rollouts");
    assert_eq!(r[3].2, 0, "exploration needs no rollouts");
    let r = rollouts_and_methods(&small(ExploitMethod::SimCmaes), "sim-cmaes");
    assert_eq!(r[2], ("exploit".into(), "sim-cmaes".into(), 6));
    let r = rollouts_and_methods(&small(ExploitMethod::CmaesQ), "cmaes-q");
    assert_eq!(r[2], ("exploit".into(), "cmaes-q".into(), 0));
    // Critic-screened: 3 candidates x 2 short rollouts of the real robot, under a trust region.
    let mut c = small(ExploitMethod::Screened);
    c.optimizer.pso.particles = 20;
    c.optimizer.pso.iterations = 5;
    c.optimizer.screen.candidates = 3;
    c.optimizer.screen.rollouts = 2;
    c.optimizer.screen.steps = 20;
    c.optimizer.screen.separation = 0.01;
    c.optimizer.trust_radius = 0.3;
    let r = rollouts_and_methods(&c, "screened");
    assert_eq!(r[2], ("exploit".into(), "screened".into(), 6));
}

#[test]
fn es_baselines_take_one_generation_per_design() {
    for (m, name, pop) in [(ExploitMethod::OpenaiEs, "openai-es", 4), (ExploitMethod::CmaesEs, "cmaes-es", 3)] {
        let mut c = small(m);
        c.schedule.alternate = false;
        let r = rollouts_and_methods(&c, name);
        assert_eq!(r[2], ("exploit".into(), name.into(), pop));
        assert_eq!(r[3], ("exploit".into(), name.into(), pop), "no exploration when alternate = false");
    }
}

#[test]
fn random_designs_are_a_configuration() {
    let mut c = small(ExploitMethod::Random);
    c.schedule.alternate = false;
    let r = rollouts_and_methods(&c, "random");
    assert!(r[2..].iter().all(|(k, m, n)| k == "exploit" && m == "random" && *n == 0), "{r:?}");
}

/// Runs `c` in-process with a recording optimiser in place of the real one: it notes how many
/// start states each design request carries and answers with the box's centre.
fn run_recording_requests(c: &RunConfig, name: &str) -> (coadapt_learner::coadapt::RunOutcome, Vec<usize>) {
    use coadapt_coadaptation::roles;
    use coadapt_transport::{DesignReply, in_process};
    let spec = coadapt_robots::make(&c.env).unwrap().spec().clone();
    let (mut learner, mut actors, mut optimizer) = in_process::fleet(1);
    let shutdown = AtomicBool::new(false);
    let dir = tmpdir(name);
    std::thread::scope(|s| {
        let (c, spec, shutdown) = (c, &spec, &shutdown);
        let mut actor = actors.pop().unwrap();
        s.spawn(move || roles::actor(c, spec, 0, &mut actor, shutdown).unwrap());
        let recorder = s.spawn(move || {
            let mut states = vec![];
            while let Ok(Some(req)) = coadapt_transport::next_or_stop(optimizer.requests.as_mut(), shutdown) {
                states.push(req.start_states.len() / spec.obs_dim());
                let centre = spec.design.low.iter().zip(&spec.design.high).map(|(l, h)| 0.5 * (l + h)).collect();
                let reply = DesignReply {
                    index: req.index,
                    design: centre,
                    method: "centre".into(),
                    predicted_objective: None,
                    design_rollouts: 0,
                };
                optimizer.replies.send(reply).unwrap();
            }
            states
        });
        let outcome = roles::learner(c, spec, &dir, &mut learner, shutdown, false).unwrap();
        drop(learner);
        (outcome, recorder.join().unwrap())
    })
}

/// The thesis's ablations change what they claim to: population-only trains no individual
/// networks (and acts with the population's), and a start-state batch of 1 gives the design
/// objective exactly one start state per request, where the default gives the configured batch.
#[test]
fn the_ablations_change_what_they_claim_to() {
    let mut c = small(ExploitMethod::PsoQ);
    c.schedule.start_state_batch = 8;
    let (outcome, states) = run_recording_requests(&c, "ablation-default");
    assert_eq!(states, vec![8, 8], "two chosen designs, 8 start states each");
    assert!(outcome.learner.agent(ActingPolicy::Individual).updates() > 0);

    c.learner.population_only = true;
    c.schedule.start_state_batch = 1;
    let (outcome, states) = run_recording_requests(&c, "ablation");
    assert_eq!(states, vec![1, 1], "the objective sees exactly one start state");
    assert_eq!(outcome.learner.agent(ActingPolicy::Individual).updates(), 0, "no individual network is trained");
    let pop = outcome.learner.agent(ActingPolicy::Population).updates();
    // population-only: `individual-updates` (20) population updates per training episode; the
    // tiny schedule has 4 designs x (episodes - 1 warm-up) = 2 + 2 + 1 + 1 training episodes.
    assert_eq!(pop, 20 * 6, "population updates");
}

#[test]
fn bad_configs_are_refused_with_the_field_named() {
    let out = tmpdir("bad");
    let mut c = small(ExploitMethod::PsoQ);
    c.schedule.initial_designs[1] = vec![1.0; 5];
    let e = format!("{:#}", run_config(&c, &out, &AtomicBool::new(false), false).unwrap_err());
    assert!(e.contains("schedule.initial-designs[1]"), "{e}");
    let mut c = small(ExploitMethod::PsoQ);
    c.schedule.episode_timeout_secs = f64::INFINITY;
    let e = format!("{:#}", run_config(&c, &tmpdir("bad-timeout"), &AtomicBool::new(false), false).unwrap_err());
    assert!(e.contains("schedule.episode-timeout-secs"), "{e}");
    let mut c = small(ExploitMethod::PsoQ);
    c.actors = 65;
    let e = format!("{:#}", run_config(&c, &tmpdir("bad-actors"), &AtomicBool::new(false), false).unwrap_err());
    assert!(e.contains("fleet.max-actors"), "{e}");
    let e = toml::from_str::<RunConfig>("[schedule]\ndesings = 3\n").unwrap_err().to_string();
    assert!(e.contains("desings"), "{e}");
}

/// Every shipped config parses, passes the run's checks, and the reference and reduced
/// protocols start from the robot's five fixed initial designs (the same in every run, as the
/// thesis fixes them) with the reference's schedule.
#[test]
fn every_shipped_config_is_valid_and_the_protocols_fix_their_initial_designs() {
    let mut seen = 0;
    for entry in std::fs::read_dir(workspace_file("configs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        let mut c: RunConfig = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap_or_else(|e| panic!("{name}: {e}"));
        if coadapt_env_rpc::is_remote(&c.env) {
            // A robot served over dm_env_rpc: the same protocol as the built-in robot it mirrors.
            let built_in = name.strip_prefix("mujoco-").unwrap_or_else(|| panic!("{name}: which robot does it mirror?"));
            let mut same: RunConfig =
                toml::from_str(&std::fs::read_to_string(workspace_file(&format!("configs/{built_in}.toml"))).unwrap()).unwrap();
            same.env = c.env.clone();
            assert_eq!(c, same, "{name}: the protocol of configs/{built_in}.toml");
            seen += 1;
            continue;
        }
        let spec = coadapt_robots::make(&c.env).unwrap().spec().clone();
        let fixed = coadapt_robots::reference_initial_designs(&c.env).unwrap();
        if name.ends_with("-reference") || name.ends_with("-reduced") {
            assert_eq!(c.schedule.initial_designs, fixed, "{name}: the robot's fixed initial designs");
            assert_eq!(c.learner.population_updates_from_design, 3, "{name}: population updates from the fourth design");
            assert_eq!(c.optimizer.pso.bounds, coadapt_design_optimizer::BoundHandling::Periodic, "{name}");
        }
        if name.ends_with("-reference") {
            let per = if c.env == "daisy" { 200 } else { 100 };
            assert_eq!((c.schedule.initial_episodes, c.schedule.episodes_per_design), (300, per), "{name}");
        }
        // Configs without initial designs get the same fixed ones whatever the seed.
        let mut other = c.clone();
        other.schedule.initial_designs.clear();
        other.seed = 99;
        resolve_initial_designs(&mut other, &spec);
        assert_eq!(other.schedule.initial_designs, fixed, "{name}");
        resolve_initial_designs(&mut c, &spec);
        check(&c, &spec).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        seen += 1;
    }
    assert!(seen >= 9, "{seen} configs");
}

/// Learning rates that blow the networks up: the run stops with an error that names the
/// non-finite update (the pair, the update, the design and the episode), exits non-zero, and
/// keeps the rows already written; no NaN weights reach an actor.
#[test]
fn a_diverging_learner_stops_the_run_with_the_update_named() {
    let out = tmpdir("nan");
    let cfg = out.with_extension("toml");
    let mut text = std::fs::read_to_string(workspace_file("configs/half-cheetah-tiny.toml")).unwrap();
    text = text.replace("[learner.sac]\n", "[learner.sac]\ncritic-lr = 1e30\npolicy-lr = 1e30\n");
    assert!(text.contains("critic-lr = 1e30"));
    std::fs::write(&cfg, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{stderr}");
    assert!(stderr.contains("individual networks' update") && stderr.contains("non-finite"), "{stderr}");
    assert_eq!(stderr.matches("non-finite").count(), 1, "said once: {stderr}");
    let (_, rows) = csv(&out.join("episodes.csv"));
    assert!(!rows.is_empty(), "the episodes before the failure are kept");
}
