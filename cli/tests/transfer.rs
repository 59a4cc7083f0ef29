//! Transfer (thesis 6.1) through the binary: a run in another world (`--friction`) that starts
//! with a finished run's population networks (`--init-population`) records both in its
//! config.toml and summary; a source that cannot carry over is refused before anything is
//! written, naming what differs, with exit 78.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::{Command, Output};

const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/half-cheetah-tiny.toml");

fn coadapt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

fn summary(o: &Output) -> serde_json::Value {
    serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap()
}

#[test]
fn a_run_in_another_world_starts_from_a_finished_runs_population_networks() {
    let dir = coadapt_test_support::scratch("cli", "transfer");
    let (src, dst) = (dir.join("source"), dir.join("target"));
    let o = coadapt(&["run", "--config", TINY, "--designs", "3", "--transport", "in-process", "--out", src.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(summary(&o).get("init_population").is_none() && summary(&o).get("world").is_none(), "a plain run's summary is as it was");
    let plain = std::fs::read_to_string(src.join("config.toml")).unwrap();
    assert!(!plain.contains("[world]") && !plain.contains("init-population"), "{plain}");

    // Same seed and config as the source but for the networks it starts with: without the
    // transfer its first episode (acting with the population policy in warm-up) would be the
    // source's own, return for return.
    let o = coadapt(&[
        "run",
        "--config",
        TINY,
        "--designs",
        "2",
        "--transport",
        "in-process",
        "--init-population",
        src.to_str().unwrap(),
        "--out",
        dst.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let full = std::fs::canonicalize(&src).unwrap().display().to_string();
    assert!(err.contains(&format!("learner: population networks from {full}/checkpoints/population.safetensors")), "{err}");
    let s = summary(&o);
    assert_eq!(s["init_population"]["from"], full.as_str(), "{s}");
    assert_eq!(s["init_population"]["replay"], false, "{s}");
    let cfg: toml::Value = toml::from_str(&std::fs::read_to_string(dst.join("config.toml")).unwrap()).unwrap();
    assert_eq!(cfg["init-population"]["from"].as_str(), Some(full.as_str()));
    // (return, eval_return) of the first episode.
    let first = |d: &std::path::Path| -> Vec<String> {
        let text = std::fs::read_to_string(d.join("episodes.csv")).unwrap();
        text.lines().nth(1).unwrap().split(',').skip(4).take(2).map(String::from).collect()
    };
    assert_ne!(first(&src), first(&dst), "the target's first episode is the source's own (random networks)");

    // Another world: recorded in config.toml and the summary.
    let world = dir.join("world");
    let o = coadapt(&[
        "run",
        "--config",
        TINY,
        "--designs",
        "1",
        "--transport",
        "in-process",
        "--friction",
        "0.8",
        "--actuator-scale",
        "0.75",
        "--torso-mass-scale",
        "1.5",
        "--out",
        world.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!((summary(&o)["world"]["friction"].as_f64().unwrap() - 0.8).abs() < 1e-6, "{}", summary(&o));
    let cfg: toml::Value = toml::from_str(&std::fs::read_to_string(world.join("config.toml")).unwrap()).unwrap();
    assert!((cfg["world"]["friction"].as_float().unwrap() - 0.8).abs() < 1e-6);
    assert_eq!(cfg["world"]["actuator-scale"].as_float(), Some(0.75));
    assert_eq!(cfg["world"]["torso-mass-scale"].as_float(), Some(1.5));

    // Refusals: nothing written, exit 78, the mismatch named.
    let cases: Vec<(String, Vec<String>, &str)> = vec![
        ("missing".into(), vec!["--init-population".into(), dir.join("nope").display().to_string()], "--init-population"),
        ("friction".into(), vec!["--friction=-1".into()], "world.friction"),
        ("actuators".into(), vec!["--actuator-scale=0".into()], "world.actuator-scale: 0"),
        ("hidden".into(), vec!["--init-population".into(), full.clone()], "learner.sac.hidden"),
    ];
    let small = dir.join("small.toml");
    std::fs::write(&small, std::fs::read_to_string(TINY).unwrap().replace("hidden = [32, 32]", "hidden = [16]")).unwrap();
    for (name, extra, needle) in cases {
        let out = dir.join(format!("refused-{name}"));
        let config = if name == "hidden" { small.to_str().unwrap() } else { TINY };
        let mut args = vec!["run", "--config", config, "--transport", "in-process", "--out", out.to_str().unwrap()];
        args.extend(extra.iter().map(String::as_str));
        let o = coadapt(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(78), "{name}: {err}");
        assert!(err.contains(needle), "{name}: `{err}` does not name {needle}");
        assert!(!out.join("designs.csv").exists(), "{name}: a refused run wrote its directory");
    }
}
